"""How many bytes of figures the step page sends a session for one Step (what each student's browser
receives, thirty times over in a class).

    PYTHONPATH=. .venv/bin/python scripts/page_bytes.py [--steps N]

Opens the step page with Streamlit's AppTest (the default lesson: IUPE on CartPole, real sizes, a
temporary runs folder), presses Step `--steps` times and prints the number of charts and the bytes of
their plotly JSON after each Step.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
sys.path.insert(0, str(ROOT))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, default=1)
    a = p.parse_args()
    os.environ["IFO_LAB_RUNS"] = tempfile.mkdtemp(prefix="ifo-page-bytes-")
    from streamlit.testing.v1 import AppTest

    at = AppTest.from_file(str(ROOT / "app.py"), default_timeout=300)
    at.run()
    at.switch_page("views/step_through.py").run()
    for step in range(1, a.steps + 1):
        at.button("step").click().run()
        if at.exception:
            raise SystemExit(f"the page failed: {at.exception[0].message}")
        sizes = [len(chart.proto.spec) for chart in at.get("plotly_chart")]
        print(f"after Step {step}: {len(sizes)} charts, {sum(sizes)} bytes of figure JSON")


if __name__ == "__main__":
    main()
