"""What one Step of a lesson costs the server, without any browser: Streamlit's AppTest runs the step
page's script as the server would, for a teacher and then a student following the same lesson.

    PYTHONPATH=. .venv/bin/python scripts/page_bench.py [--steps 3] [--full] [--repeats 3]

The teacher's session presses Step `--steps` times (each iteration trained, and stored in the iteration
cache); then a student's session on the same configuration and seed presses Step as many times (each
iteration taken from the cache: no training), scrubs back one iteration and forward again. Each action is timed from
the click to the end of the script run (median over `--repeats` fresh pairs of sessions). The same is
measured twice: with the figures shared across sessions (`ifo.ui.panels.shared_figure`, how the app
runs) and with that turned off, so the table shows what the sharing saves. In a class the students'
browsers run elsewhere; what is left for the server is this, once per student per Step.
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


def one_pair(steps: int) -> tuple[dict[str, list[float]], str]:
    from streamlit.testing.v1 import AppTest

    def open_page() -> AppTest:
        at = AppTest.from_file(str(ROOT / "app.py"), default_timeout=600)
        at.run()
        at.switch_page("views/step_through.py").run()
        return at

    def timed(action) -> float:
        start = time.perf_counter()
        action()
        return time.perf_counter() - start

    times: dict[str, list[float]] = {"teacher Step (trains)": [], "student Step (from the cache)": [],
                                     "student scrub back one iteration": [],
                                     "student scrub forward again": []}
    teacher = open_page()
    for _ in range(steps):
        times["teacher Step (trains)"].append(timed(lambda: teacher.button(key="step").click().run()))
    student = open_page()
    for _ in range(steps):
        times["student Step (from the cache)"].append(timed(lambda: student.button(key="step").click().run()))
    assert student.session_state["ifo.slot.step"].run.last_step_cached, "the student's Step trained"
    slider = student.slider(key="step.view")
    times["student scrub back one iteration"].append(timed(lambda: slider.set_value(steps - 1).run()))
    slider = student.slider(key="step.view")
    times["student scrub forward again"].append(timed(lambda: slider.set_value(steps).run()))
    for at in (teacher, student):
        assert not at.exception, at.exception
    cfg = teacher.session_state["ifo.slot.step"].run.config
    return times, f"{cfg.method} on {cfg.env}, seed {cfg.seed}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=3)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--full", action="store_true", help="the real sizes (default: IFO_LAB_FAST's tiny runs)")
    a = parser.parse_args()
    if a.steps < 2:
        parser.error("--steps must be at least 2 (the scrub goes back one iteration)")
    if not a.full:
        os.environ["IFO_LAB_FAST"] = "1"
    os.environ["IFO_LAB_AHEAD"] = "0"  # the teacher's Steps train on the click (scripts/ahead_bench.py: the other way)
    from ifo.runtime import limit_threads
    from ifo.ui import panels

    limit_threads()
    shared = panels._figures.limit
    rows = {}
    for label, size in (("figures shared", shared), ("figures built per session", 0)):
        panels._figures.limit = size  # 0: only the figure last built is kept, so each session builds its own
        collected: dict[str, list[float]] = {}
        for _ in range(a.repeats):
            panels._figures.clear()
            with tempfile.TemporaryDirectory(prefix="ifo-page-bench-") as runs:
                os.environ["IFO_LAB_RUNS"] = runs  # a fresh cache: the teacher trains every iteration
                times, what = one_pair(a.steps)
                for name, values in times.items():
                    collected.setdefault(name, []).extend(values)
        rows[label] = {name: statistics.median(values) for name, values in collected.items()}
    panels._figures.limit = shared
    names = list(next(iter(rows.values())))
    load = os.getloadavg()[0]
    print(f"### Server time per action ({'real sizes' if a.full else 'IFO_LAB_FAST=1'}; the step page's default "
          f"run, {what}; {a.steps} Steps, median of {a.repeats} pairs of sessions; 1-minute load average "
          f"{load:.1f} on {os.cpu_count()} cores)\n")
    print("| action (seconds) | " + " | ".join(rows) + " |")
    print("|---|" + "---|" * len(rows))
    for name in names:
        print(f"| {name} | " + " | ".join(f"{rows[label][name]:.2f}" for label in rows) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
