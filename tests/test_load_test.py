"""The class benchmark's watch mode (scripts/load_test.py --mode watch), which docs/BENCH.md quotes: it
serves the app, a teacher Steps and shares, the other sessions follow on the watch page as browsers would."""
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_sessions_watching_a_shared_run_see_every_step_of_the_teacher():
    res = subprocess.run([sys.executable, "scripts/load_test.py", "--client", "protocol", "--mode", "watch",
                          "--sessions", "3", "--steps", "2", "--think", "1", "--timeout", "240", "--step-timeout", "60"],
                         cwd=ROOT, capture_output=True, text=True, timeout=400, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert res.returncode == 0, res.stderr[-2000:]
    assert "| 4 / 4 |" in res.stdout, res.stdout  # two watchers saw both of the teacher's Steps
    assert "Errors:" not in res.stdout
    assert "The teacher's own Steps" in res.stdout and "2 sessions watch its shared run" in res.stdout
