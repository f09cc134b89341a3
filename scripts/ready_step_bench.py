"""What a student waits for when the teacher's iteration is ready: one teacher Steps, then each student
opens the same run and Steps (taken from the iteration cache, nothing trained), timed in AppTest; and
what the Step's autosave costs: the run's state deflated at each zlib level (seconds, MiB), and how many
distinct frames a maze's I_s holds.

    PYTHONPATH=. .venv/bin/python scripts/ready_step_bench.py [--env maze10] [--students 4]
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def students(env: str, n: int) -> list[tuple[float, bool]]:
    """Seconds of each student's Step, and whether it was taken ready-made."""
    from streamlit.testing.v1 import AppTest

    def session() -> AppTest:
        at = AppTest.from_file(str(ROOT / "app.py"), default_timeout=900)
        at.query_params.update({"step.env": env, "step.method": "iupe"})
        at.run()
        at.switch_page("views/step_through.py").run()
        return at

    session().button(key="step").click().run()  # the teacher: trains iteration 1 into the cache
    out = []
    for _ in range(n):
        at = session()
        start = time.perf_counter()
        at.button(key="step").click().run()
        out.append((time.perf_counter() - start, at.session_state["ifo.slot.step"].run.last_step_cached))
    return out


def autosave(env: str) -> None:
    import numpy as np

    from ifo.config import RunConfig
    from ifo.io import npz_bytes
    from ifo.run import Run

    run = Run(RunConfig(env=env, method="iupe"))
    run.step()
    arrays, _ = run.learner.state()
    for level in (1, 3, 6):
        best, size = float("inf"), 0
        for _ in range(3):
            start = time.perf_counter()
            size = len(npz_bytes(arrays, level))
            best = min(best, time.perf_counter() - start)
        print(f"deflate level {level}: {best:.3f} s, {size / 2**20:.2f} MiB")
    images = [a for k, a in arrays.items() if a.dtype == np.uint8 and a.ndim == 4]
    if images:
        frames = np.concatenate(images).reshape(sum(len(a) for a in images), -1)
        distinct = len(np.unique(frames.view(np.dtype((np.void, frames.shape[1]))).ravel()))
        print(f"distinct frames: {distinct:,} of {len(frames):,}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="maze10")
    parser.add_argument("--students", type=int, default=4)
    a = parser.parse_args()
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
    os.environ.pop("IFO_LAB_FAST", None)
    os.environ["IFO_LAB_RUNS"], os.environ["IFO_LAB_AHEAD"] = tempfile.mkdtemp(prefix="ifo-ready-"), "0"
    for k, (seconds, ready) in enumerate(students(a.env, a.students)):
        print(f"student {k}: {seconds:.2f} s{'' if ready else ' (trained, not ready-made)'}")
    autosave(a.env)
    return 0


if __name__ == "__main__":
    sys.exit(main())
