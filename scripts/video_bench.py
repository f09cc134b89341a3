"""What a class opening rollout videos at once waits for, with frames drawn one at a time in a process.

    python scripts/video_bench.py [--envs cartpole,acrobot,mountaincar] [--sessions 10] [--frames 300] [--repeats 3]

gymnasium draws the classic-control tasks with pygame.gfxdraw, which is not safe from two threads at once, so
`ifo.envs.drawing.render_frame` draws one frame at a time in the app's process (docs/BENCH.md). For each
environment this prints the seconds one session's video takes alone (the expert's episode drawn, then encoded
as the app's MP4), and the p50 / max seconds per session and the wall time when `--sessions` sessions ask at
the same moment, each its own seed: with the lock, and with the lock taken out (frames then may come out
smudged: this arm only prices the lock, its videos are thrown away). Arms alternate `--repeats` times in one
process so a noisy machine slows both alike; the medians are printed.
"""
from __future__ import annotations

import argparse
import contextlib
import os
import statistics
import sys
import threading
import time
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ifo.envs import drawing  # noqa: E402
from ifo.runtime import limit_threads  # noqa: E402
from ifo.video import expert_rollout_frames, frames_to_mp4  # noqa: E402


def one_video(env: str, seed: int, frames: int) -> float:
    start = time.perf_counter()
    frames_to_mp4(expert_rollout_frames(env, seed=seed, max_frames=frames)[0])
    return time.perf_counter() - start


def class_at_once(env: str, sessions: int, frames: int) -> tuple[list[float], float]:
    """Per-session seconds and the wall time when `sessions` threads each make a video at the same moment."""
    start, seconds = threading.Barrier(sessions + 1), [0.0] * sessions

    def session(k: int) -> None:
        start.wait()
        seconds[k] = one_video(env, k, frames)

    threads = [threading.Thread(target=session, args=(k,)) for k in range(sessions)]
    for t in threads:
        t.start()
    start.wait()
    t0 = time.perf_counter()
    for t in threads:
        t.join()
    return seconds, time.perf_counter() - t0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--envs", default="cartpole,acrobot,mountaincar")
    ap.add_argument("--sessions", type=int, default=10)
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    if a.sessions < 1 or a.frames < 2 or a.repeats < 1:
        ap.error("--sessions and --repeats must be at least 1, --frames at least 2")
    limit_threads()
    locked = drawing._DRAW_LOCK
    print(f"{a.sessions} sessions, {a.frames} frames each, median of {a.repeats} alternating repeats\n")
    print("| environment | one video alone s | at once, with the lock: p50 / max / wall s "
          "| at once, without it: p50 / max / wall s |")
    print("|---|---|---|---|")
    for env in a.envs.split(","):
        one_video(env, 0, 2)  # the expert and pygame loaded before anything is timed
        alone, arms = [], {"lock": [], "none": []}
        for _ in range(a.repeats):
            alone.append(one_video(env, 0, a.frames))
            for arm in ("lock", "none"):
                drawing._DRAW_LOCK = locked if arm == "lock" else contextlib.nullcontext()
                try:
                    seconds, wall = class_at_once(env, a.sessions, a.frames)
                finally:
                    drawing._DRAW_LOCK = locked
                arms[arm].append((statistics.median(seconds), max(seconds), wall))
        cells = [" / ".join(f"{statistics.median(r[i] for r in arms[arm]):.2f}" for i in range(3))
                 for arm in ("lock", "none")]
        print(f"| {env} | {statistics.median(alone):.2f} | {cells[0]} | {cells[1]} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
