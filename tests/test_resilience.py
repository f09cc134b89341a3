"""Chapter 7 (resilience to sub-optimal experts): the expert levels, level-aware demonstrations and
references, Tables 7.1-7.6, the shipped results, and the app's page (AppTest)."""
import json
from pathlib import Path

import numpy as np
import pytest
from streamlit.testing.v1 import AppTest

from ifo.envs import get_env
from ifo.experts import check_level, level_info, load_expert
from ifo.experts.train import LEVEL_TARGETS, parse_levels, select_levels
from ifo.reproduce import TABLES, reproduce
from ifo.reproduce import chapter7 as ch7

ROOT = Path(__file__).resolve().parents[1]
PAGE = "views/resilience.py"


# ----------------------------------------------------------------------------- choosing the levels
def test_a_level_keeps_the_check_that_meets_its_threshold_most_closely():
    checks = [{"aer": a} for a in (-186.6, -164.7, -132.8, -130.9, -136.1, -158.9, -149.1, -148.2, -111.8, -99.9)]
    chosen = select_levels(checks, {2: -129.0, 3: -137.0, 4: -149.0, 5: -156.0}, tolerance=5.0)
    picked = {level: checks[k]["aer"] for level, k in chosen.items()}
    # -136.1 and -148.2 meet their thresholds within 5; for -129 the lowest check above is -111.8 (18 away):
    # the closest one (-130.9, 1.9 below) is kept instead; likewise -158.9 for -156
    assert picked == {2: -130.9, 3: -136.1, 4: -148.2, 5: -158.9}
    assert select_levels(checks, {2: -129.0}, tolerance=100.0) == {2: 8}  # meets the threshold if near enough
    assert select_levels([], {2: 1.0}) == {}


def test_level_arguments_are_checked():
    assert parse_levels("3") == [3] and parse_levels("2-5") == [2, 3, 4, 5] and parse_levels("4,2") == [2, 4]
    assert parse_levels("all") == [1, 2, 3, 4, 5]
    for bad in ("0", "6", "x", "2-9"):
        with pytest.raises(ValueError):
            parse_levels(bad)
    with pytest.raises(ValueError):
        check_level(True)
    with pytest.raises(ValueError, match="one expert"):
        load_expert("maze5", level=2)


# ----------------------------------------------------------------------------- the shipped levels
SHIPPED_LEVELS = [env for env in ch7.ENVS_7 if all(level_info(env, k) for k in (1, 2, 3, 4, 5))]


def test_levels_are_shipped_for_cartpole_and_mountaincar_at_least():
    assert {"cartpole", "mountaincar"} <= set(SHIPPED_LEVELS)


@pytest.mark.parametrize("env", SHIPPED_LEVELS)
def test_the_shipped_levels_match_the_thesis_and_get_worse_level_by_level(env):
    from ifo.experts.train import LEVEL_TOLERANCE

    infos = [level_info(env, k) for k in (1, 2, 3, 4, 5)]
    aers = [i["aer"] for i in infos]
    assert aers == sorted(aers, reverse=True)  # Expert¹ is the best, Expert⁵ the worst
    span = abs(LEVEL_TARGETS[env][0] - get_env(env).references()["random_aer"])
    targets = LEVEL_TARGETS[env]
    for k, info in enumerate(infos[1:], start=2):  # level 1 is the shipped expert, not chosen by this rule
        # each level is nearer its own Table 7.1 threshold than any other level's ...
        nearest = min(range(5), key=lambda j: abs(info["aer"] - targets[j]))
        assert nearest == k - 1, (k, info["aer"])
        # ... and within twice the selection tolerance (LunarLander is checked every 16,384 steps and moves fast:
        # its level 3 lands 20.1 above 98 against a tolerance of 19.9; docs/CHOICES.md says so)
        assert abs(info["aer"] - targets[k - 1]) <= 2 * LEVEL_TOLERANCE * span + 1e-9, (k, info["aer"])
    for k in (1, 2, 3, 4, 5):
        assert (ROOT / "assets" / "experts" / f"{env}-level{k}.npz").exists()
        assert (ROOT / "assets" / "demos" / (f"{env}.npz" if k == 1 else f"{env}-level{k}.npz")).exists()
    expert = load_expert(env, level=5)  # a level's weights reproduce its AER on the evaluation seeds ...
    from ifo.experts.train import _reference_aer

    # ... to 1 % of the expert-random span, not to the digit: float32 kernels differ between CPUs, a near-tie
    # argmax flips and Acrobot's chaos carries it through the episode (level 5: -240.17 where it was made,
    # -240.68 and -240.99 on two other machines, -239.06 in float64); a wrong file is off by a gap between
    # levels, 7 or more times this
    assert _reference_aer(get_env(env), expert).mean() == pytest.approx(infos[4]["aer"], abs=0.01 * span)


def test_level_demonstrations_load_with_their_actions_and_their_reference():
    from ifo.data.demos import DemoError
    from ifo.data.shipped import level_demos_path, level_references, load_shipped_demonstrations

    spec = get_env("cartpole")
    demos = load_shipped_demonstrations(spec, level=3)
    info = level_info(spec, 3)
    assert demos.n_episodes == info["demos_episodes"] == 100
    assert float(np.mean(demos.episode_returns)) == pytest.approx(info["demos_mean_return"], abs=1e-3)
    assert demos.hidden_actions is not None and len(demos.hidden_actions) == len(demos.transitions)
    assert level_demos_path(spec, 3).name == "cartpole-level3.npz" and level_demos_path(spec, 1).name == "cartpole.npz"
    assert level_references(spec, 3)["expert_aer"] == info["aer"]
    assert level_references(spec, 1)["expert_aer"] == spec.references()["expert_aer"]
    with pytest.raises(DemoError, match="one expert"):
        load_shipped_demonstrations(get_env("maze5"), level=2)


def test_a_level_run_measures_performance_against_that_expert():
    from ifo.config import RunConfig

    cfg = RunConfig.from_dict({"env": "cartpole", "method": "bc", "iterations": 1, "eval_episodes": 5,
                               "expert_episodes": 3, "expert_level": 4})
    run = ch7.level_run(cfg)
    assert run.references["expert"] == level_info("cartpole", 4)["aer"]
    assert run.demos.n_episodes == 3 and np.mean(run.demos.episode_returns) < 400  # Expert⁴'s, not Expert¹'s
    ev = run.step()["evaluation"]
    assert ev["performance"] == pytest.approx(ch7.performance_against(ev["aer"], "cartpole", 4))
    assert ev["expert_reference"] == level_info("cartpole", 4)["aer"]


# ----------------------------------------------------------------------------- the tables
def test_table_7_1_shows_each_level_beside_the_thesis_without_training():
    text = reproduce("7.1", seeds=3, envs=["cartpole"], log=lambda m: None, progress=False)
    lines = [line for line in text.splitlines() if line.startswith("| Expert")]
    assert len(lines) == 5  # one row per level: a reference row runs once, whatever the seeds
    assert f"| {level_info('cartpole', 2)['aer']:.3f} | — | 435.000 |" in lines[1]  # one run: no interval
    assert "| 70.51 |" in lines[1]  # the thesis's sd


def test_tables_7_2_to_7_6_hold_the_four_methods_and_the_thesis_numbers():
    for level in (1, 2, 3, 4, 5):
        table = TABLES[f"7.{level + 1}"]
        assert [r.label for r in table.rows] == ["Random", ch7.expert_label(level), "BC", "GAIL", "ILPO", "IUPE"]
        assert table.settings["expert_level"] == level and table.envs == ch7.ENVS_7
    assert TABLES["7.6"].thesis["GAIL"]["cartpole"] == (5.11, 484.22, 40.29, 0.31)
    assert TABLES["7.5"].thesis["IUPE"]["mountaincar"] == (0.8, -161.05, 20.11, 0.51)
    assert ch7.thesis_curves("mountaincar", ["IUPE"])["IUPE"][0] == (-99, -166.97)
    titles = [c.title for c in TABLES["7.3"].columns]
    assert "trajectory fidelity (0 = the expert's states)" in titles and "P against Expert¹" in titles


def _store_rows():
    """Rows as the sweep store keeps them, for two levels of CartPole."""
    rows = []
    for level, expert in ((1, 500.0), (4, 228.0)):
        table = f"7.{level + 1}"
        rows.append({"key": f"r{level}", "status": "done", "spec": {"table": table, "row": "Random", "env": "cartpole",
                                                                     "seed": 0, "settings": {"expert_level": level}},
                     "result": {"aer": 20.0, "performance": 0.0}})
        rows.append({"key": f"e{level}", "status": "done", "spec": {"table": table, "row": ch7.expert_label(level),
                                                                     "env": "cartpole", "seed": 0,
                                                                     "settings": {"expert_level": level}},
                     "result": {"aer": expert, "performance": 1.0, "expert_aer": expert, "level": level}})
        for method, aer in (("BC", expert - 20), ("IUPE", 480.0)):
            for seed in (0, 1):
                rows.append({"key": f"{method}{level}{seed}", "status": "done",
                             "spec": {"table": table, "row": method, "env": "cartpole", "seed": seed, "iterations": 5,
                                      "settings": {"expert_level": level}},
                             "result": {"aer": aer + seed, "performance": (aer - 20) / (expert - 20),
                                        "performance_expert1": (aer - 20) / 480, "fidelity": 0.1 * level,
                                        "expert_aer": expert, "level": level, "seconds": 3.0}})
    rows.append({"key": "bad", "status": "failed", "spec": {"table": "7.2", "row": "BC", "env": "cartpole", "seed": 9},
                 "error": "x"})
    return rows


def test_results_from_the_store_feed_the_figure_and_the_page_tables(tmp_path):
    from ifo import figures

    results = ch7.results_from_rows(_store_rows())
    assert len(results) == 12  # the failure is left out
    fig = figures.resilience_curves(results, "cartpole")
    assert [t.name for t in fig.data] == ["expert", "BC", "IUPE"]
    assert list(fig.data[1].x) == [228.0, 500.0] and list(fig.data[1].y) == pytest.approx([208.5, 480.5])
    rows = ch7.summary_rows(results, "cartpole", ["BC", "IUPE", "Expert⁴"])
    iupe4 = next(r for r in rows if r["method"] == "IUPE" and r["expert"] == "Expert⁴")
    assert iupe4["AER (thesis)"] == "357.6" and iupe4["trajectory fidelity (ours)"] == "0.400 ± 0.000"
    assert iupe4["P (thesis)"] == "1.840"
    written = ch7.ship_results(_store_rows(), tmp_path)
    assert written == {"cartpole": 12}
    assert len(ch7.results_from_rows(json.loads(line) for line in (tmp_path / "cartpole.jsonl").read_text().splitlines())) == 12


def _longer_budget_rows():
    """GAIL again on CartPole's Expert¹, with 40 rounds and 100 demonstrations, and that sweep's Random row."""
    spec = {"table": "7.2", "env": "cartpole", "iterations": 40, "settings": {"expert_level": 1}}
    rows = [{"key": "r1-40", "status": "done", "spec": {**spec, "row": "Random", "seed": 0},
             "result": {"aer": 20.0, "performance": 0.0}}]
    for seed in (0, 1):
        rows.append({"key": f"GAIL1{seed}-40", "status": "done", "spec": {**spec, "row": "GAIL", "seed": seed},
                     "result": {"aer": 490.0 + seed, "performance": 0.98, "expert_aer": 500.0, "level": 1,
                                "expert_episodes": 100, "fidelity": 0.5}})
    return rows


def test_a_second_sweep_ships_beside_the_first_and_each_budget_reads_alone(tmp_path):
    """Shipping another sweep's cells (GAIL with a longer budget) keeps the file's other cells; the page
    reads one budget at a time, the one with every method first, each with its own Random and Expert rows."""
    first = [dict(r, spec={**r["spec"], "iterations": 5,
                           "settings": {**r["spec"].get("settings", {}), "expert_episodes": 20}})
             for r in _store_rows()]
    ch7.ship_results(first, tmp_path)
    assert ch7.ship_results(_longer_budget_rows(), tmp_path) == {"cartpole": 15}
    again = [dict(r, result={**r["result"], "aer": 499.0}) if r["key"] == "GAIL10-40" else r
             for r in _longer_budget_rows()]
    assert ch7.ship_results(again, tmp_path) == {"cartpole": 15}  # the same training is replaced, not added
    results = ch7.results_from_rows(json.loads(line) for line in (tmp_path / "cartpole.jsonl").read_text().splitlines())
    assert ch7.budgets(results) == [(5, 20), (40, None)]  # CartPole's Expert¹ ships 100 episodes: all of them
    assert ch7.budget_label(results, (40, None)) == "40 iterations, all demonstrations: GAIL"
    short, longer = ch7.in_budget(results, (5, 20)), ch7.in_budget(results, (40, None))
    assert {r["method"] for r in short} == {"Random", "Expert¹", "Expert⁴", "BC", "IUPE"} and len(short) == 12
    assert sorted((r["method"], r["aer"]) for r in longer) == [("GAIL", 491.0), ("GAIL", 499.0), ("Random", 20.0)]


def test_a_method_with_every_expert_trained_is_no_gap():
    full = [{"method": m, "level": k, "seed": 0, "reference": False, "iterations": 40, "expert_episodes": None,
             "env": "cartpole"} for m in ch7.LABELS_7 for k in ch7.LEVELS]
    assert ch7.missing_cells(full) == {} and ch7.missing_cells_text(full, "cartpole") is None
    short = [r for r in full if not (r["method"] == "ILPO" and r["level"] >= 3)]
    assert ch7.missing_cells(short) == {"ILPO": [3, 4, 5]}
    assert ch7.missing_cells(short, ["BC", "IUPE"]) == {}  # only the methods the page shows
    assert "ILPO on Expert³, Expert⁴, Expert⁵" in ch7.missing_cells_text(short, "cartpole")


def test_all_of_each_levels_demonstrations_is_one_budget_though_levels_ship_different_numbers():
    """LunarLander's Expert¹ ships 100 episodes, its Experts 2-5 ship 50: trainings on all of each level's
    episodes are one budget on the page (one curve across the levels), not one budget per level; 20 of them
    is another."""
    def row(level, episodes, seed=0):
        return {"key": f"IUPE{level}{seed}{episodes}", "status": "done",
                "spec": {"table": f"7.{level + 1}", "env": "lunarlander", "row": "IUPE", "seed": seed, "iterations": 40,
                         "settings": {"expert_level": level}},
                "result": {"aer": 100.0, "performance": 0.9, "expert_aer": 120.0, "level": level,
                           "expert_episodes": episodes}}

    results = ch7.results_from_rows([row(1, 100), row(2, 50), row(3, 50), row(2, 20)])
    assert ch7.budgets(results) == [(40, None), (40, 20)]
    assert ch7.budget_label(results, (40, None)) == "40 iterations, all demonstrations: IUPE"
    assert sorted(r["level"] for r in ch7.in_budget(results, (40, None))) == [1, 2, 3]


def test_two_shippers_at_once_keep_each_others_cells(tmp_path, monkeypatch):
    """Two sweeps shipping into one file at the same time: the second waits for the first, so neither's
    cells are lost (without the lock, the one that read first wrote last and dropped the other's)."""
    import threading

    import ifo.sweep as sweep_mod

    real, reading, go, calls = sweep_mod.read_rows, threading.Event(), threading.Event(), []

    def slow_first_read(path):
        calls.append(path)
        rows = real(path)
        if len(calls) == 1:  # the first shipper has read the file and is about to write it
            reading.set()
            go.wait(10)
        return rows

    ch7.ship_results(_store_rows(), tmp_path)  # the file exists: both shippers read it
    monkeypatch.setattr(sweep_mod, "read_rows", slow_first_read)
    first = threading.Thread(target=ch7.ship_results, args=(_longer_budget_rows(), tmp_path))
    first.start()
    assert reading.wait(10)
    extra = [dict(r, key=r["key"] + "-b", spec={**r["spec"], "seed": r["spec"]["seed"] + 10})
             for r in _longer_budget_rows() if r["spec"]["row"] == "GAIL"]
    second = threading.Thread(target=ch7.ship_results, args=(extra, tmp_path))
    second.start()
    second.join(1)  # with the lock it waits here for the first
    go.set()
    first.join(10)
    second.join(10)
    keys = {json.loads(line)["key"] for line in (tmp_path / "cartpole.jsonl").read_text().splitlines()}
    assert {r["key"] for r in _longer_budget_rows() + extra} <= keys and len(keys) == 12 + 3 + 2


def test_the_shipped_results_are_read_again_when_the_file_changes(tmp_path, monkeypatch):
    path = tmp_path / "cartpole.jsonl"
    monkeypatch.setattr(ch7, "shipped_results_paths", lambda env: [path])
    assert ch7.load_shipped_results("cartpole") == []
    ch7.ship_results(_store_rows(), tmp_path)
    first = ch7.load_shipped_results("cartpole")
    first[0]["aer"] = -1e9  # a caller's own dicts: the next caller does not see this
    assert -1e9 not in [r["aer"] for r in ch7.load_shipped_results("cartpole")]
    ch7.ship_results(_longer_budget_rows(), tmp_path)
    assert len(ch7.load_shipped_results("cartpole")) == len(first) + 3


def test_the_thesis_budget_ships_beside_its_tables_and_a_training_in_two_files_counts_once(tmp_path, monkeypatch):
    """The 100-round trainings ship beside their tables in docs/reproduction/, one file per method, and the
    page reads them with its own file as one more budget. A training shipped to both (the same method, level,
    seed and budget) is drawn once, from the page's own file, and every result names the file it came from."""
    paths = ch7.shipped_results_paths("mountaincar")
    assert paths[0] == ch7.shipped_results_path("mountaincar")
    assert [p.name for p in paths[1:]] == [f"tables-7.2-7.6-mountaincar-{m}-100-iterations.jsonl"
                                           for m in ("bc", "gail", "iupe")]
    own, longer = tmp_path / "own.jsonl", tmp_path / "longer.jsonl"
    rows = _longer_budget_rows()  # GAIL, 40 rounds
    longer.write_text("".join(json.dumps(r) + "\n" for r in rows))
    twice = {**rows[-1], "result": {**rows[-1]["result"], "aer": 123.0}}  # shipped to the page's file as well
    own.write_text(json.dumps(twice) + "\n")
    monkeypatch.setattr(ch7, "shipped_results_paths", lambda env: [own, longer])
    results = ch7.load_shipped_results("cartpole")
    assert len(results) == len(ch7.results_from_rows(rows))
    mine = [r for r in results if r["source"] == str(own)]
    assert len(mine) == 1 and mine[0]["aer"] == 123.0
    assert {r["source"] for r in results} == {str(own), str(longer)}


def test_a_live_cell_is_a_plain_run_config_on_that_levels_demonstrations():
    cfg = ch7.live_config("cartpole", "ilpo", 3, seed=2, iterations=4, overrides={"pre_size": 2000, "nope": 1})
    assert cfg.expert_level == 3 and cfg.demos.endswith("cartpole-level3.npz") and cfg.seed == 2
    assert cfg.learner.pre_size == 2000 and cfg.iterations == 4
    assert ch7.live_config("cartpole", "bc", 1).demos is None
    m = ch7.live_metrics([{"iteration": 1, "evaluation": {"aer": 228.0, "fidelity": 0.3}}], "cartpole", 4)
    assert m["performance"] == pytest.approx(ch7.performance_against(228.0, "cartpole", 4))
    assert ch7.live_metrics([], "cartpole", 4) is None


# ----------------------------------------------------------------------------- the page
@pytest.fixture
def app_env(monkeypatch, tmp_path):
    monkeypatch.setenv("IFO_LAB_FAST", "1")
    monkeypatch.setenv("IFO_LAB_RUNS", str(tmp_path / "runs"))
    return tmp_path


def open_page(user: str) -> AppTest:
    at = AppTest.from_file(str(ROOT / "app.py"), default_timeout=60)
    at.query_params["user"] = user
    at.run()
    at.switch_page(PAGE).run()
    assert not at.exception, at.exception
    return at


def frame(at: AppTest, column: str):
    """The dataframe (AppTest gives dataframes no key) that has `column`."""
    return next(d.value for d in at.dataframe if column in d.value.columns)


def chart_names(at: AppTest, key: str) -> list[str]:
    chart = next(c for c in at.get("plotly_chart") if c.key == key)
    return [t.get("name") for t in json.loads(chart.proto.spec)["data"]]


def test_the_page_draws_fig_7_1_with_fidelity_beside_it(app_env, monkeypatch):
    path = app_env / "cartpole.jsonl"
    path.write_text("".join(json.dumps(r) + "\n" for r in _store_rows()))
    monkeypatch.setattr(ch7, "shipped_results_paths", lambda env: [path if env == "cartpole" else app_env / "none.jsonl"])
    at = open_page("resiltest01")
    assert at.title[0].value == "Resilience to sub-optimal experts"
    assert chart_names(at, "resilience.aer") == ["expert", "BC", "IUPE"]
    assert chart_names(at, "resilience.other") == ["BC", "IUPE"]  # fidelity by default
    table = frame(at, "P (ours)")
    assert {"P (ours)", "P against Expert¹ (ours)", "trajectory fidelity (ours)"} <= set(table.columns)
    at.toggle(key="resilience.thesis").set_value(True).run()
    assert "BC (thesis)" in chart_names(at, "resilience.aer")
    at.multiselect(key="resilience.methods").set_value(["IUPE"]).run()
    assert chart_names(at, "resilience.aer")[1] == "IUPE"
    at.radio(key="resilience.metric").set_value("performance").run()
    assert not at.exception
    from ifo.export import find_chromium

    if find_chromium():  # SVG, PNG and PDF of both figures, drawn in the slide theme when clicked
        keys = {b.proto.id for b in at.get("download_button")}
        assert {k for k in keys if "resilience" in k} and len(at.get("download_button")) == 6
    at.selectbox(key="resilience.env").set_value("acrobot").run()
    assert any("No shipped results for Acrobot" in i.value for i in at.info)


def test_the_page_offers_each_shipped_budget_and_draws_one_at_a_time(app_env, monkeypatch):
    path = app_env / "cartpole.jsonl"
    ch7.ship_results(_store_rows() + _longer_budget_rows(), app_env)
    monkeypatch.setattr(ch7, "shipped_results_paths", lambda env: [path if env == "cartpole" else app_env / "none.jsonl"])
    at = open_page("resiltest03")
    budget = at.radio(key="resilience.budget.cartpole")
    assert budget.options == ["5 iterations, all demonstrations: BC, IUPE", "40 iterations, all demonstrations: GAIL"]
    assert chart_names(at, "resilience.aer") == ["expert", "BC", "IUPE"]  # the budget with every method first
    short_gaps = [i.value for i in at.info if i.value.startswith("Not trained with this budget yet")]
    assert len(short_gaps) == 1 and "GAIL on every expert" in short_gaps[0]
    assert "BC on Expert², Expert³, Expert⁵" in short_gaps[0] and "--seeds 2 --iterations 5 --store" in short_gaps[0]
    budget.set_value((40, None)).run()
    assert chart_names(at, "resilience.aer") == ["expert", "GAIL"]
    gaps = [i.value for i in at.info if i.value.startswith("Not trained with this budget yet")]
    # a line that stops short is a gap in the sweep, and the page names it and the command that fills it
    assert gaps == [ch7.missing_cells_text(ch7.in_budget(ch7.load_shipped_results("cartpole"), (40, None)), "cartpole")]
    assert "GAIL on Expert², Expert³, Expert⁴, Expert⁵" in gaps[0] and "ILPO on every expert" in gaps[0]
    assert "--rows BC,GAIL,ILPO,IUPE --levels 1,2,3,4,5 --seeds 2 --iterations 40 --store" in gaps[0]
    assert "--expert-episodes" not in gaps[0]  # all of each level's demonstrations is the default
    assert set(frame(at, "P (ours)")["method"]) == {"GAIL"}
    at.multiselect(key="resilience.methods").set_value(["BC"]).run()
    assert any("None of the chosen methods was trained with this budget" in i.value for i in at.info)
    at.selectbox(key="resilience.env").set_value("acrobot").run()
    assert not at.exception and [r.key for r in at.radio] == ["resilience.metric"]  # no budget to choose


def test_the_page_offers_the_thesis_100_rounds_from_the_files_beside_the_tables(app_env):
    """MountainCar's GAIL fails with 40 rounds and learns with the thesis's 100: a teacher shows both on the
    page, from the shipped files, with every seed of every cell, and the page says which files it drew."""
    at = open_page("resiltest05")
    at.selectbox(key="resilience.env").set_value("mountaincar").run()
    budget = at.radio(key="resilience.budget.mountaincar")
    assert budget.options[-1] == "100 iterations, all demonstrations: BC, GAIL, IUPE"
    budget.set_value((100, None)).run()
    assert not at.exception
    assert chart_names(at, "resilience.aer") == ["expert", "BC", "GAIL", "IUPE"]
    caption = next(c.value for c in at.caption if "trainings from" in c.value)
    files = ", ".join(f"`docs/reproduction/tables-7.2-7.6-mountaincar-{m}-100-iterations.jsonl`"
                      for m in ("bc", "gail", "iupe"))
    assert caption.startswith(f"150 trainings from {files}") and "iterations per run: 100." in caption
    shown = ch7.in_budget(ch7.load_shipped_results("mountaincar"), (100, None))
    cells = {(s["method"], s["level"]): s for s in ch7.summary(shown, "mountaincar")}
    assert cells[("GAIL", 1)]["aer"][0] > -150  # learns with Expert¹ (40 rounds: about -198)
    gaps = [i.value for i in at.info if i.value.startswith("Not trained with this budget yet")]
    assert len(gaps) == 1 and "ILPO on every expert" in gaps[0] and "BC" not in gaps[0]


def test_a_link_opens_the_study_on_the_environment_it_names(app_env):
    for named in ("acrobot", "Acrobot"):  # the configuration's name, or the label the widget writes
        at = AppTest.from_file(str(ROOT / "app.py"), default_timeout=60)
        at.query_params.update({"user": "resiltest04", "resilience.env": named})
        at.run()
        at.switch_page(PAGE).run()
        assert not at.exception, at.exception
        assert at.selectbox(key="resilience.env").value == "acrobot", named


def test_the_page_shows_the_shipped_results_and_the_expert_levels(app_env):
    at = open_page("resiltest02")
    assert not at.exception
    assert "BC" in chart_names(at, "resilience.aer")  # assets/resilience/cartpole.jsonl
    levels = frame(at, "checkpoint (training steps)")
    assert list(levels["expert"]) == ["Expert¹", "Expert²", "Expert³", "Expert⁴", "Expert⁵"]
    assert levels["AER (thesis)"][1] == "435.0 ± 70.51"


def test_a_cell_queued_from_the_page_trains_on_that_experts_demonstrations(app_env):
    from ifo.ui.queue import get_queue

    user = "resiltest03"
    at = open_page(user)
    at.selectbox(key="resilience.live.method").set_value("BC")
    at.selectbox(key="resilience.live.level").set_value(5)
    at.number_input(key="resilience.live.iterations").set_value(1)
    at.button(key="resilience.live.queue").click().run()
    assert not at.exception and not at.error
    assert any("Queued BC on Expert⁵" in s.value for s in at.success)
    job = get_queue().jobs(user)[0]
    assert job.config.expert_level == 5 and job.config.demos.endswith("cartpole-level5.npz")
    assert job.thesis == (1.46, 155.96)
    assert get_queue().wait_idle(240)
    at.run()
    assert not at.exception
    live = frame(at, "cell")
    assert live["state"][0] == "finished" and live["AER"][0] != "—" and live["trajectory fidelity"][0] != "—"
    aer = float(live["AER"][0])
    assert float(live["P (against this expert)"][0]) == pytest.approx(ch7.performance_against(aer, "cartpole", 5),
                                                                      abs=1e-3)


def test_the_experts_command_takes_a_level(capsys):
    from ifo.cli import main

    assert main(["experts", "evaluate", "--env", "cartpole", "--level", "2,5", "--episodes", "5", "--json"]) == 0
    out = [json.loads(line) for line in capsys.readouterr().out.strip().splitlines()]
    assert [o["level"] for o in out] == [2, 5] and out[0]["aer"] > out[1]["aer"]
    assert main(["experts", "demos", "--env", "maze5", "--level", "3"]) == 2
    assert "one expert" in capsys.readouterr().err
    assert main(["experts", "train", "--env", "cartpole", "--level", "9"]) == 2


def test_the_resilience_command_draws_fig_7_1_into_the_figures_folder(monkeypatch, tmp_path):
    """`bench resilience --figures DIR` hands DIR to the study, which draws Fig 7.1 (AER and fidelity) there
    from the store's rows: SVG with a Chromium, else self-contained HTML."""
    from ifo.cli import main
    from ifo.export import find_chromium

    seen = {}
    monkeypatch.setattr(ch7, "resilience_study", lambda *a, **k: seen.update(k) or "(tables)")
    assert main(["bench", "resilience", "--envs", "cartpole", "--local", "--figures", str(tmp_path / "figs")]) == 0
    assert seen["figures_dir"] == str(tmp_path / "figs")

    paths = ch7.write_figures(ch7.results_from_rows(_store_rows()), ["cartpole"], tmp_path / "figs", log=lambda m: None)
    suffix = ".svg" if find_chromium() else ".html"
    assert [p.name for p in paths] == [f"fig-7-1-cartpole{suffix}", f"fig-7-1-cartpole-fidelity{suffix}"]
    body = paths[0].read_text()
    assert "IUPE" in body and "BC" in body  # the methods' lines, by name


def test_a_cell_ships_only_with_every_seed_its_tables_show(tmp_path):
    """A sweep stopped within a cell (here IUPE with Expert⁴: 1 seed of 2) ships the finished cells and leaves
    that one out, so the page never draws a curve from fewer runs than its tables say; the Random and Expert
    rows take one training each."""
    rows = [r for r in _store_rows() if r["key"] != "IUPE41"]
    assert ch7.ship_results(rows, tmp_path, seeds=2) == {"cartpole": 10}
    shipped = {json.loads(line)["key"] for line in (tmp_path / "cartpole.jsonl").read_text().splitlines()}
    assert "IUPE40" not in shipped and {"BC40", "BC41", "r4", "e4", "IUPE10", "IUPE11"} <= shipped


@pytest.mark.parametrize("env", ["cartpole", "lunarlander"])
def test_the_page_and_the_tables_give_each_cell_the_same_spread_over_seeds(env):
    """A teacher reads '± sd' on the page, on its figure's bars and in docs/REPRODUCTION.md's tables: for
    the same shipped trainings it is the same number everywhere (the sample sd over seeds, n − 1)."""
    from ifo import figures
    from ifo.reproduce import mean_sd

    results = ch7.in_budget(ch7.load_shipped_results(env), (40, None))
    summary = {(s["method"], s["level"]): s for s in ch7.summary(results, env)}
    fig = figures.resilience_curves(results, env)
    for method in ch7.LABELS_7:
        trace = next(t for t in fig.data if t.name == method)
        for level in ch7.LEVELS:
            seeds = [r for r in results if r["method"] == method and r["level"] == level]
            assert len(seeds) == 10  # every cell of the 40-round budget shipped with its ten seeds
            table = mean_sd([r["aer"] for r in seeds])  # as the tables print it
            mean, sd = summary[(method, level)]["aer"]
            assert f"{mean:.3f} ± {sd:.3f}" == table
            bar = trace.error_y.array[[c[0] for c in trace.customdata].index(f"Expert level {level}")]
            assert f"{bar:.3f}" == table.split(" ± ")[1]
