"""The app as a person uses it, through Streamlit's AppTest (no browser, no JavaScript).

Runs are tiny (IFO_LAB_FAST=1) and always on CartPole, whose demonstrations are shipped.
AppTest never ticks a fragment's `run_every`; a plain `at.run()` stands in for one tick.
"""
from pathlib import Path

import pytest
from streamlit.testing.v1 import AppTest

ROOT = Path(__file__).resolve().parents[1]
STEP_PAGE = "pages/step_through.py"


@pytest.fixture(autouse=True)
def fast_runs(monkeypatch):
    monkeypatch.setenv("IFO_LAB_FAST", "1")


def open_app() -> AppTest:
    at = AppTest.from_file(str(ROOT / "app.py"), default_timeout=60)
    at.run()
    assert not at.exception
    return at


def open_step_page() -> AppTest:
    at = open_app()
    at.switch_page(STEP_PAGE).run()
    assert not at.exception
    return at


def counter(at: AppTest) -> str:
    texts = [m.value for m in at.markdown if "Iteration " in m.value and " of " in m.value]
    assert len(texts) == 1, texts
    return texts[0].strip("# ")


def records(at: AppTest) -> list[dict]:
    return at.session_state["ifo.slot.step"].run.records


def test_landing_page_explains_ifo_and_links_to_the_step_page():
    at = open_app()
    assert at.title[0].value == "IfO Lab"
    text = " ".join(m.value for m in at.markdown)
    assert "BCO loop" in text and "inverse dynamics model" in text and "IUPE" in text
    assert not at.error
    at.button(key="open_step").click().run()
    assert not at.exception
    assert counter(at) == "Iteration 0 of 10"


def test_step_page_loads_ready_to_step():
    at = open_step_page()
    assert not at.error
    assert counter(at) == "Iteration 0 of 10"
    assert {b.key for b in at.button} >= {"step", "run", "reset"}
    assert len(at.get("plotly_chart")) == 0
    assert "Press **Step**" in at.info[0].value


def test_step_step_reset():
    at = open_step_page()
    at.button(key="step").click().run()
    assert not at.exception and not at.error
    assert len(records(at)) == 1
    assert counter(at) == "Iteration 1 of 10"
    charts = at.get("plotly_chart")
    # AER, Performance, IDM predictions, accuracy, win probability, IDM predictions through time
    assert len(charts) == 6
    assert {m.label for m in at.metric} == {"AER", "Performance P", "Goal rate", "Seconds per iteration"}

    at.button(key="step").click().run()
    assert len(records(at)) == 2
    assert counter(at) == "Iteration 2 of 10"
    assert [r["iteration"] for r in records(at)] == [1, 2]

    at.button(key="reset").click().run()
    assert not at.exception
    assert records(at) == []
    assert counter(at) == "Iteration 0 of 10"
    assert len(at.get("plotly_chart")) == 0


def test_run_n_trains_one_iteration_per_rerun_and_can_pause():
    at = open_step_page()
    at.number_input(key="run_n").set_value(3)
    at.button(key="run").click().run()
    assert counter(at) == "Iteration 1 of 10"  # the first iteration right away
    assert "pause" in {b.key for b in at.button}  # playing: Run N became Pause
    at.run()  # one tick of the fragment's timer
    assert counter(at) == "Iteration 2 of 10"
    at.button(key="pause").click().run()
    assert counter(at) == "Iteration 2 of 10"  # paused: nothing more trains
    at.run()
    assert counter(at) == "Iteration 2 of 10"
    assert "run" in {b.key for b in at.button}

    at.button(key="run").click().run()  # N=3 more, but stop at the end of the run
    for _ in range(5):
        at.run()
    assert counter(at) == "Iteration 5 of 10"
    assert "run" in {b.key for b in at.button} and not at.exception


def test_changing_the_seed_starts_a_new_run_and_says_so():
    at = open_step_page()
    at.button(key="step").click().run()
    assert counter(at) == "Iteration 1 of 10"
    at.number_input(key="step.seed").set_value(1).run()
    assert not at.exception
    assert counter(at) == "Iteration 0 of 10"
    assert "seed 1" in " ".join(m.value for m in at.markdown)
    assert any("previous run" in t.value for t in at.toast)


def test_changing_only_the_iterations_keeps_the_run():
    at = open_step_page()
    at.button(key="step").click().run()
    at.number_input(key="step.iterations.cartpole.bco-alpha").set_value(12).run()
    assert counter(at) == "Iteration 1 of 12"
    assert len(records(at)) == 1


def test_a_single_pass_method_finishes_after_one_step():
    at = open_step_page()
    at.selectbox(key="step.method").select("bco").run()
    assert counter(at) == "Iteration 0 of 1"
    at.button(key="step").click().run()
    assert counter(at) == "Iteration 1 of 1"
    assert at.button(key="step").disabled
    assert "all 1 iterations" in at.success[0].value
    assert not at.exception


def test_bc_has_no_idm_panel():
    at = open_step_page()
    at.selectbox(key="step.method").select("bc").run()
    at.button(key="step").click().run()
    assert not at.exception and not at.error
    assert any("no IDM" in i.value for i in at.info)
    assert len(at.get("plotly_chart")) == 3  # AER, Performance, accuracy


def test_missing_demonstrations_show_an_error_not_a_traceback(monkeypatch, tmp_path):
    import ifo.data.demos

    monkeypatch.setattr(ifo.data.demos, "DEMOS_DIR", tmp_path)  # as if nothing were shipped yet
    at = open_step_page()
    assert not at.exception
    assert len(at.error) == 1
    message = at.error[0].value
    assert "no shipped demonstrations" in message and "CartPole" in message
    assert len(at.get("plotly_chart")) == 0
    assert "step" not in {b.key for b in at.button}

    monkeypatch.setattr(ifo.data.demos, "DEMOS_DIR", ROOT / "assets" / "demos")  # they arrive
    at.button(key="retry").click().run()
    assert not at.error and counter(at) == "Iteration 0 of 10"
