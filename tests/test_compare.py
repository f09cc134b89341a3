"""The compare page (views/compare.py) and its helpers: configurations, thesis numbers, summary table.

The page test trains two tiny CartPole configurations through the real background queue
(IFO_LAB_FAST=1, 2 iterations each) and checks the summary table beside the thesis's numbers.
"""
from pathlib import Path

import pytest
from streamlit.testing.v1 import AppTest

from ifo.config import RunConfig
from ifo.reproduce import TABLES
from ifo.ui import compare_page as cp
from ifo.ui import storage
from ifo.ui.queue import get_queue

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(autouse=True)
def env(tmp_path, monkeypatch):
    monkeypatch.setenv("IFO_LAB_FAST", "1")
    monkeypatch.setenv("IFO_LAB_RUNS", str(tmp_path / "runs"))


def test_thesis_numbers_follow_the_configuration_not_its_name():
    assert cp.thesis_numbers(RunConfig(env="maze10", method="iupe")) == (1.0, 0.981, "Table 6.1: IUPE")
    assert cp.thesis_numbers(RunConfig(env="cartpole", method="bco-alpha"))[:2] == (1.135, 500.0)
    # the loop with ABCO's switches is ABCO
    abco = cp.switch_config("maze5", attention=True, sampling="abco", exploration=False)
    assert abco.thesis[:2] == (0.960, 0.932) and abco.group.startswith("ABCO")  # named by what it is
    mixed = cp.switch_config("maze5", attention=False, sampling="iupe", exploration=True)
    assert mixed.group.startswith("BCO(α) + sampling iupe + explore labels + explore rollouts")
    # a combination the thesis never ran, or an environment it has no column for
    assert cp.thesis_numbers(RunConfig.from_dict(dict(env="cartpole", method="bco-alpha", sampling="iupe"))) is None
    assert cp.thesis_numbers(RunConfig(env="maze3", method="gaifo")) is None


def test_presets_are_the_ablation_rows_with_their_numbers():
    for table_id in cp.PRESET_TABLES:
        table = TABLES[table_id]
        planned = cp.preset_configs(table_id)
        assert [p.group.split(" · ")[0] for p in planned] == [r.label for r in table.rows]
        for p, row in zip(planned, table.rows):
            assert p.config.env == table.envs[0]
            if row.label in table.thesis:  # (our extra rows, such as appending BCO(α), have no thesis number)
                assert p.thesis[:2] == table.thesis[row.label][table.envs[0]]
            else:
                assert p.thesis is None
    on_maze3 = cp.preset_configs("6.2", "maze3", iterations=2)
    assert {p.config.env for p in on_maze3} == {"maze3"} and {p.config.iterations for p in on_maze3} == {2}


def test_summary_rows_mean_and_sd_over_seeds():
    rec = lambda aer, p: {"iteration": 1, "evaluation": {"aer": aer, "performance": p}}  # noqa: E731
    entries = [
        {"group": "A", "records": [rec(100, 0.2)], "total": 1, "state": "done", "thesis": (1.0, 500.0, "Table 6.1")},
        {"group": "A", "records": [rec(300, 0.6)], "total": 1, "state": "done", "thesis": (1.0, 500.0, "Table 6.1")},
        {"group": "B", "records": [], "total": 3, "state": "queued", "thesis": None},
    ]
    a, b = cp.summary_rows(entries)
    assert a["P (ours)"] == "0.400 ± 0.283" and a["AER (ours)"] == "200.000 ± 141.421"  # the sample sd (n - 1)
    assert a["P (thesis)"] == "1.000" and a["AER (thesis)"] == "500.000" and a["seeds"] == "2/2 finished"
    assert b["P (ours)"] == "—" and b["P (thesis)"] == "—" and b["seeds"] == "0/1 finished"


def test_queue_two_configurations_and_read_the_summary():
    user = "comparetest01"
    at = AppTest.from_file(str(ROOT / "app.py"), default_timeout=60)
    at.query_params["user"] = user
    at.run()
    at.switch_page("views/compare.py").run()
    assert not at.exception, at.exception
    assert at.title[0].value == "Compare and ablate"
    at.number_input(key="compare.iterations.cartpole").set_value(2)
    at.multiselect(key="compare.methods").set_value(["bco-alpha", "iupe"])
    at.button(key="compare.queue_methods").click().run()
    assert not at.exception and not at.error
    assert any("Queued 2 runs" in s.value for s in at.success)
    lines = " ".join(m.value for m in at.markdown)
    assert "BCO(α) · CartPole · 2 it., seed 0" in lines and "IUPE · CartPole · 2 it., seed 0" in lines

    assert get_queue().wait_idle(180)
    assert [j.state for j in get_queue().jobs(user)] == ["done", "done"]
    at.run()  # what the fragment's next tick shows
    assert not at.exception
    assert len(at.get("plotly_chart")) == 2
    table = at.dataframe[0].value
    rows = {r["configuration"]: r for r in table.to_dict("records")}
    assert set(rows) == {"BCO(α) · CartPole · 2 it.", "IUPE · CartPole · 2 it."}
    for row in rows.values():
        assert row["seeds"] == "1/1 finished" and row["P (ours)"] != "—"
        assert row["P (thesis)"] == "1.135" and row["AER (thesis)"] == "500.000"
    # the runs were saved to the user's folder after each iteration
    assert sorted(r.iterations_done for r in storage.list_runs(user)) == [2, 2]


def test_another_user_does_not_see_those_jobs():
    at = AppTest.from_file(str(ROOT / "app.py"), default_timeout=60)
    at.query_params["user"] = "someoneelse1"
    at.run()
    at.switch_page("views/compare.py").run()
    assert "Nothing queued yet" in " ".join(i.value for i in at.info)


def test_copies_get_distinct_labels_and_one_environment_gets_its_reference_lines():
    rec = [{"iteration": 1, "evaluation": {"aer": 100.0, "performance": 0.2}}]
    labels = [label for label, _ in cp.distinct_labels([("BC", rec), ("BC", rec), ("IUPE", rec), ("BC", rec)])]
    assert labels == ["BC", "BC (2)", "IUPE", "BC (3)"]
    refs = cp.common_references([{"env": "cartpole"}, {"env": "cartpole"}])
    assert refs["expert"] == pytest.approx(500.0) and refs["random"] < 30
    assert cp.common_references([{"env": "cartpole"}, {"env": "acrobot"}]) is None  # no one line fits both

    # the references each run's records say it measured against: a user's demonstrations are their own expert
    def measured(expert: float) -> dict:
        return {"env": "cartpole", "records": [{"evaluation": {"expert_reference": expert, "random_reference": 22.0}}]}

    assert cp.common_references([measured(431.5), measured(431.5)]) == {"expert": 431.5, "random": 22.0}
    assert cp.common_references([measured(431.5), measured(500.0)]) is None


def test_the_comparison_pack_holds_tables_without_a_browser():
    import io
    import zipfile

    rec = [{"iteration": 1, "evaluation": {"aer": 100.0, "aer_std": 1.0, "performance": 0.2}, "seconds": {}}]
    data = cp.compare_pack([("BC", rec), ("BC (2)", rec)], [{"configuration": "BC", "P (ours)": "0.2"}], None,
                           formats=())
    with zipfile.ZipFile(io.BytesIO(data)) as z:
        assert set(z.namelist()) == {"summary.csv", "runs/BC.csv", "runs/BC--2-.csv"}
        assert "configuration" in z.read("summary.csv").decode()
