"""Seconds for the same episodes through gymnasium's environments and through the repo's steppers.

    python scripts/stepper_bench.py [--env lunarlander] [--episodes 100] [--repeats 4]

Runs the environment's level-1 expert on the same seeds through `EnvPool(spec, batched=False)`
(one gymnasium environment per episode, every wrapper) and through `EnvPool(spec)` (the batched
numpy dynamics for the classic-control tasks, `ifo.envs.lunar` for LunarLander), alternating the
two `--repeats` times in one process so that a noisy machine slows both alike, and prints the
median seconds and microseconds per environment step of each. The episodes are the same bit for
bit (tests/test_batched.py); only the time differs.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from ifo.envs import get_env  # noqa: E402
from ifo.envs.rollout import EnvPool, run_episodes  # noqa: E402
from ifo.experts import load_expert  # noqa: E402
from ifo.runtime import limit_threads  # noqa: E402


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--env", default="lunarlander")
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--repeats", type=int, default=4)
    a = p.parse_args()
    limit_threads()
    spec = get_env(a.env)
    if spec.is_maze:
        raise SystemExit("mazes step one way only (ifo.envs.maze); choose a vector task")
    expert = load_expert(spec)

    def act(obs):
        actions = expert.act(obs)
        return actions, actions

    pools = {"gymnasium": EnvPool(spec, batched=False), "ifo stepper": EnvPool(spec)}
    seeds = list(range(5000, 5000 + a.episodes))
    seconds: dict[str, list[float]] = {name: [] for name in pools}
    for _ in range(a.repeats):
        for name, pool in pools.items():
            start = time.perf_counter()
            rollouts = run_episodes(pool, act, seeds)
            seconds[name].append(time.perf_counter() - start)
    steps = len(rollouts.states)
    print(f"{a.env}: {a.episodes} expert episodes, {steps} steps, {a.repeats} repeats each (alternating)")
    print("| stepping | median s | µs per step | every repeat (s) |\n|---|---|---|---|")
    for name, times in seconds.items():
        median = float(np.median(times))
        print(f"| {name} | {median:.3f} | {median / steps * 1e6:.1f} | {', '.join(f'{t:.2f}' for t in times)} |")
    ratio = np.median(seconds["ifo stepper"]) / np.median(seconds["gymnasium"])
    print(f"\nifo stepper / gymnasium: {ratio:.2f}")


if __name__ == "__main__":
    main()
