"""How long a teacher waits for a Step when the class looks at each iteration for a while: the next
iteration computed ahead (ifo.ahead, the app's default) against trained on the click (IFO_LAB_AHEAD=0).

    PYTHONPATH=. .venv/bin/python scripts/ahead_bench.py [--envs cartpole,lunarlander,maze5,maze10]
                                                          [--method iupe] [--steps 3] [--talk 10]

Streamlit's AppTest runs the step page as the server would, at the real sizes: one teacher presses Step
`--steps` times and talks `--talk` seconds over each iteration; each Step is timed from the click to the
end of the script run (the page drawn). The first Step of a run always trains (nothing was asked for
before it), so it is left out of the median. Each way uses a fresh runs folder (an empty cache).
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def teacher_steps(env: str, method: str, steps: int, talk: float) -> tuple[list[float], int]:
    """Seconds of each Step after the first, and how many of them took the iteration ready-made."""
    from streamlit.testing.v1 import AppTest

    at = AppTest.from_file(str(ROOT / "app.py"), default_timeout=900)
    at.query_params.update({"step.env": env, "step.method": method})
    at.run()
    at.switch_page("views/step_through.py").run()
    assert not at.exception, at.exception
    seconds, ready = [], 0
    for k in range(steps):
        start = time.perf_counter()
        at.button(key="step").click().run()
        took = time.perf_counter() - start
        assert not at.exception and not at.error, (at.exception, [e.value for e in at.error])
        run = at.session_state["ifo.slot.step"].run
        assert run.iteration == k + 1, run.iteration
        if k:
            seconds.append(took)
            ready += run.last_step_cached
        time.sleep(talk)  # the class looks at the iteration; the next one may train meanwhile
    return seconds, ready


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", default="cartpole,lunarlander,maze5,maze10")
    parser.add_argument("--method", default="iupe")
    parser.add_argument("--steps", type=int, default=3)
    parser.add_argument("--talk", type=float, default=10.0, help="seconds the teacher talks over each iteration")
    a = parser.parse_args()
    if a.steps < 2:
        parser.error("--steps must be at least 2 (the first Step always trains)")
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
    os.environ.pop("IFO_LAB_FAST", None)
    from ifo.runtime import limit_threads

    limit_threads()
    rows = []
    for env in a.envs.split(","):
        row = [env]
        for ahead in ("1", "0"):
            os.environ["IFO_LAB_AHEAD"] = ahead
            with tempfile.TemporaryDirectory(prefix="ifo-ahead-bench-") as runs:
                os.environ["IFO_LAB_RUNS"] = runs
                seconds, ready = teacher_steps(env, a.method, a.steps, a.talk)
                from ifo.ui.session import server_ahead

                if ahead == "1":
                    server_ahead().close()  # nothing left training into the next measurement
            row += [statistics.median(seconds), max(seconds), f"{ready}/{len(seconds)}"]
        rows.append(row)
    load = os.getloadavg()[0]
    print(f"### A Step while the class looks ({a.method}, real sizes; {a.steps - 1} timed Steps each after the "
          f"first, {a.talk:g} s of talk over each iteration; 1-minute load average {load:.1f} on "
          f"{os.cpu_count()} cores)\n")
    print("| environment | computed ahead: median s | max s | ready-made | trained on the click: median s | max s "
          "| ready-made |")
    print("|---|---|---|---|---|---|---|")
    for env, *cells in rows:
        print(f"| {env} | " + " | ".join(f"{c:.2f}" if isinstance(c, float) else str(c) for c in cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
