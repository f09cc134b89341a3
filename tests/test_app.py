"""The app as a person uses it, through Streamlit's AppTest (no browser, no JavaScript).

Runs are tiny (IFO_LAB_FAST=1) and always on CartPole, whose demonstrations are shipped.
AppTest never ticks a fragment's `run_every`; a plain `at.run()` stands in for one tick.
Autosaves go to a temporary IFO_LAB_RUNS.
"""
from pathlib import Path

import pytest
from method_charts import METHOD_CHARTS
from streamlit.testing.v1 import AppTest

ROOT = Path(__file__).resolve().parents[1]
STEP_PAGE = "views/step_through.py"
DIAGRAM = "step.diagram"


@pytest.fixture(autouse=True)
def fast_runs(monkeypatch, tmp_path):
    monkeypatch.setenv("IFO_LAB_FAST", "1")
    monkeypatch.setenv("IFO_LAB_RUNS", str(tmp_path / "runs"))


def open_app(**query) -> AppTest:
    at = AppTest.from_file(str(ROOT / "app.py"), default_timeout=60)
    at.query_params.update(query)
    at.run()
    assert not at.exception
    return at


def open_step_page(**query) -> AppTest:
    at = open_app(**query)
    at.switch_page(STEP_PAGE).run()
    assert not at.exception
    return at


def chart_keys(at: AppTest) -> list[str]:
    return [c.key for c in at.get("plotly_chart")]


def chart(at: AppTest, key: str):
    return next(c for c in at.get("plotly_chart") if c.key == key)


def chart_title(at: AppTest, key: str) -> str:
    import json

    return json.loads(chart(at, key).proto.spec)["layout"]["title"]["text"]


def slot(at: AppTest):
    return at.session_state["ifo.slot.step"]


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
    assert {b.key for b in at.button} >= {"step", "run", "run_all", "reset"}
    assert chart_keys(at) == [DIAGRAM]  # the loop diagram, before any chart of results
    assert "before the first iteration" in chart_title(at, DIAGRAM)
    assert "Press **Step**" in at.info[0].value


def test_step_step_reset():
    at = open_step_page()
    at.button(key="step").click().run()
    assert not at.exception and not at.error
    assert len(records(at)) == 1
    assert counter(at) == "Iteration 1 of 10"
    # the diagram, then the registry's panels that BCO(α)'s records have: no exploration, no attention
    assert chart_keys(at) == [DIAGRAM] + [f"panel.{k}" for k in (
        "aer", "performance", "idm", "idm_over_time", "idm_confusion", "idm_confidence", "accuracy", "sampling",
        "sampling_share", "win")]
    assert {m.label for m in at.metric} == {"AER", "Performance P", "Goal rate", "Seconds per iteration"}
    captions = " ".join(c.value for c in at.caption)
    assert "Thesis Fig 5.2/6.2a" in captions and "hidden" in captions  # each panel: explanation + figure

    at.button(key="step").click().run()
    assert len(records(at)) == 2
    assert counter(at) == "Iteration 2 of 10"
    assert [r["iteration"] for r in records(at)] == [1, 2]

    at.button(key="reset").click().run()
    assert not at.exception
    assert records(at) == []
    assert counter(at) == "Iteration 0 of 10"
    assert chart_keys(at) == [DIAGRAM]


def test_the_next_iteration_is_ready_when_the_teacher_presses_step_again():
    """After a Step the next iteration trains in the background while the class looks (ifo.ahead): the next
    Step takes it ready-made, and its records are those training it then would give."""
    from ifo.run import Run
    from ifo.ui.session import server_ahead

    at = open_step_page()
    at.button(key="step").click().run()
    ahead = server_ahead()
    assert ahead is not None and ahead.wait_idle(120) and ahead.computed == 1
    at.button(key="step").click().run()
    assert not at.exception and not at.error and counter(at) == "Iteration 2 of 10"
    run = slot(at).run
    assert run.last_step_cached  # taken, not trained
    assert any("Iteration 2 was ready when Step was pressed" in c.value for c in at.caption)  # and the page says so
    alone = Run(run.config)
    alone.run()
    strip = lambda rs: [{k: v for k, v in r.items() if k != "seconds"} for r in rs]  # noqa: E731
    assert strip(records(at)) == strip(alone.records[:2])


def test_with_ifo_lab_ahead_0_every_step_trains_then(monkeypatch):
    from ifo.ui.session import server_ahead

    monkeypatch.setenv("IFO_LAB_AHEAD", "0")
    at = open_step_page()
    at.button(key="step").click().run()
    assert server_ahead() is None
    at.button(key="step").click().run()
    assert counter(at) == "Iteration 2 of 10" and not slot(at).run.last_step_cached
    assert not any("was ready when Step was pressed" in c.value for c in at.caption)


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
    assert any("no IDM to show" in i.value for i in at.info)
    assert chart_keys(at) == [DIAGRAM, "panel.aer", "panel.performance", "panel.accuracy"]
    assert any("expert's true actions" in i.value for i in at.info)


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


def test_run_to_the_end_plays_every_remaining_iteration():
    at = open_step_page()
    at.number_input(key="step.iterations.cartpole.bco-alpha").set_value(3).run()
    at.button(key="run_all").click().run()
    assert "pause" in {b.key for b in at.button}
    for _ in range(3):
        at.run()
    assert counter(at) == "Iteration 3 of 3"
    assert at.button(key="run_all").disabled and not at.exception


def test_scrubbing_shows_a_past_iteration_everywhere():
    at = open_step_page()
    for _ in range(2):
        at.button(key="step").click().run()
    assert "iteration 2" in chart_title(at, "panel.idm")
    at.slider(key="step.view").set_value(1).run()
    assert not at.exception
    assert "iteration 1" in chart_title(at, "panel.idm")
    assert "iteration 1" in chart_title(at, DIAGRAM)
    assert "after iteration 1" in chart_title(at, "panel.sampling")
    assert len(records(at)) == 2  # scrubbing trains nothing


def test_toggling_exploration_asks_then_starts_a_new_run_with_it():
    at = open_step_page()
    at.button(key="step").click().run()
    assert "panel.exploration" not in chart_keys(at)
    at.toggle(key="step.bco-alpha.explore_labels").set_value(True).run()
    assert not at.exception
    assert counter(at) == "Iteration 1 of 10" and at.button(key="step").disabled  # asked first
    at.button(key="branch_new").click().run()
    assert counter(at) == "Iteration 0 of 10"  # a new run
    run = slot(at).run
    assert run.config.learner.explore_labels is True and run.config.learner.explore_rollouts is False
    at.button(key="step").click().run()
    assert "panel.exploration" in chart_keys(at)  # a panel that now applies
    assert len(chart_keys(at)) == 12


def test_choosing_a_method_sets_its_switches():
    at = open_step_page()
    at.selectbox(key="step.method").select("iupe").run()
    assert at.selectbox(key="step.iupe.attention").value == "gated"
    assert at.selectbox(key="step.iupe.sampling").value == "iupe"
    assert at.toggle(key="step.iupe.explore_labels").value and at.toggle(key="step.iupe.explore_rollouts").value
    assert slot(at).run.config.method == "iupe"


def test_each_method_keeps_its_own_switches():
    """A switch changed for one method is that method's: BCO(α) starts with its own preset beside it, and
    IUPE has the change again when the teacher comes back to it."""
    at = open_step_page()
    at.selectbox(key="step.method").select("iupe").run()
    at.toggle(key="step.iupe.explore_rollouts").set_value(False).run()
    at.selectbox(key="step.method").select("bco-alpha").run()
    assert at.selectbox(key="step.bco-alpha.sampling").value == "none"  # BCO(α)'s own
    assert not at.toggle(key="step.bco-alpha.explore_labels").value
    at.selectbox(key="step.method").select("iupe").run()
    assert not at.exception
    assert at.toggle(key="step.iupe.explore_labels").value is True  # IUPE's preset
    assert at.toggle(key="step.iupe.explore_rollouts").value is False  # and the teacher's change
    cfg = slot(at).run.config
    assert (cfg.method, cfg.learner.explore_labels, cfg.learner.explore_rollouts) == ("iupe", True, False)


def test_a_preset_applies_its_components():
    at = open_step_page()
    at.selectbox(key="step.preset").select("t6.2:Sampling + Exploration").run()
    assert not at.exception
    assert at.selectbox(key="step.preset").value is None  # it applies, then waits for the next choice
    assert at.selectbox(key="step.method").value == "bco-alpha"
    assert at.selectbox(key="step.bco-alpha.attention").value == "none"
    assert at.selectbox(key="step.bco-alpha.sampling").value == "iupe"
    assert at.toggle(key="step.bco-alpha.explore_labels").value and at.toggle(key="step.bco-alpha.explore_rollouts").value
    cfg = slot(at).run.config
    assert (cfg.learner.attention, cfg.learner.sampling, cfg.learner.explore_labels, cfg.learner.explore_rollouts) == ("none", "iupe", True, True)
    captions = " ".join(c.value for c in at.sidebar.caption)
    assert "Table 6.2: Sampling + Exploration" in captions
    assert "P = 0.943" not in captions  # the thesis's numbers for this row are the 10×10 maze's, not CartPole's
    at.selectbox(key="step.env").select("maze10").run()
    captions = " ".join(c.value for c in at.sidebar.caption)
    assert "Table 6.2 reports for this row on Maze 10x10: P = 0.943" in captions


def test_url_params_set_the_widgets():
    at = open_step_page(**{"step.method": "IUPE", "step.seed": "3", "step.iupe.explore_rollouts": "false",
                           "step.eval_explore": "actions sampled from π"})
    assert at.selectbox(key="step.method").value == "iupe"
    assert at.number_input(key="step.seed").value == 3
    assert at.toggle(key="step.iupe.explore_labels").value is True  # IUPE's own choice
    assert at.toggle(key="step.iupe.explore_rollouts").value is False  # the link's
    cfg = slot(at).run.config
    assert (cfg.method, cfg.seed, cfg.learner.explore_rollouts, cfg.eval_explore) == ("iupe", 3, False, True)


@pytest.mark.parametrize("hide", [None, "settings"])
def test_a_link_from_before_each_method_kept_its_switches_still_sets_them(hide):
    """`?step.explore_rollouts=false` (a switch named without its method, as links were made before) still
    turns IUPE's switch off, with the settings shown or hidden; shown, the URL takes the new name."""
    query = {"step.method": "IUPE", "step.explore_rollouts": "false", "step.sampling": "none"}
    at = open_step_page(**(query if hide is None else {**query, "hide": hide}))
    assert not at.exception
    cfg = slot(at).run.config
    assert (cfg.method, cfg.learner.explore_labels, cfg.learner.explore_rollouts, cfg.learner.sampling) == \
        ("iupe", True, False, "none")
    if hide is None:
        assert at.toggle(key="step.iupe.explore_rollouts").value is False
        assert "step.explore_rollouts" not in at.query_params and at.query_params["step.iupe.explore_rollouts"] == ["false"]


def test_hide_removes_settings_and_panels_for_a_lesson():
    at = open_step_page(hide="settings,diagram,idm", **{"step.method": "IUPE"})
    assert not at.sidebar.selectbox and not at.sidebar.toggle  # no settings widgets
    assert slot(at).run.config.method == "iupe"  # the link's settings still hold
    at.button(key="step").click().run()
    keys = chart_keys(at)
    assert DIAGRAM not in keys and "panel.idm" not in keys and "panel.aer" in keys


def test_autosave_writes_the_run_and_run_param_reopens_it(tmp_path):
    from ifo.ui import storage

    at = open_step_page()
    user = at.query_params[storage.USER_PARAM]
    user = user[0] if isinstance(user, list) else user
    assert storage.valid_user(user)  # made and put in the URL
    for _ in range(2):
        at.button(key="step").click().run()
    run_id = slot(at).run_id
    saved = storage.list_runs(user)
    assert [(r.run_id, r.iterations_done) for r in saved] == [(run_id, 2)]
    assert str(saved[0].path).startswith(str(tmp_path / "runs"))
    assert "BCO(α) on CartPole" in saved[0].label

    again = open_step_page(user=user, run=run_id)  # as the run list opens it
    assert not again.exception
    assert counter(again) == "Iteration 2 of 10"
    assert slot(again).run_id == run_id and len(records(again)) == 2
    again.button(key="step").click().run()
    assert counter(again) == "Iteration 3 of 10"
    assert storage.list_runs(user)[0].iterations_done == 3


def test_an_unknown_run_param_says_so_and_starts_fresh():
    at = open_step_page(user="abcdef123456", run="cartpole-nope")
    assert not at.exception
    assert counter(at) == "Iteration 0 of 10"
    assert any("Could not open" in t.value for t in at.toast)


def test_rollout_video_on_demand(monkeypatch):
    import ifo.video

    monkeypatch.setattr(ifo.video, "MAX_FRAMES", 20)  # a short clip: this checks the wiring, not the film
    at = open_step_page()
    at.button(key="step").click().run()
    assert len(at.get("video")) == 0  # nothing is rendered until asked
    at.button(key="rollout").click().run()
    assert not at.exception and not at.error
    # the learner and the expert side by side (one film when they played frame for frame alike)
    assert len(at.get("video")) == 2 or any("exactly as the expert" in s.value for s in at.success)
    assert 1 in slot(at).videos  # cached for (this run, iteration 1)
    at.run()
    assert at.button(key="rollout").disabled and len(at.get("video")) >= 1


# --------------------------------------------------------------------------- registry and diagram (no app)
SYNTHETIC = {
    "iteration": 3,
    "idm": {"loss": 0.5, "train_accuracy": 0.8, "val_accuracy": 0.7, "train_size": 1400,
            "prediction_counts": [30, 10, 40, 20], "mean_probabilities": [0.3, 0.1, 0.4, 0.2],
            "true_counts": [25, 15, 35, 25], "expert_accuracy": 0.81},
    "labels": {"counts": [28, 12, 40, 20], "sampled": True, "exploration_rate": 0.12, "accuracy": 0.75},
    "policy": {"loss": 0.3, "agreement": 0.9, "expert_accuracy": 0.7},
    "attention": {"grad_cam": {"maps": [[[0.0, 0.5], [1.0, 0.2]]] * 6, "actions": [0, 1, 2, 3, 0, 1],
                               "probabilities": [[0.7, 0.1, 0.1, 0.1]] * 6, "raw_max": [1.0] * 6},
                  "mean_image_distance": {"distance": [0.5, 0.4, 0.3, 0.2]}},
    "rollouts": {"returns": [1.0] * 6 + [-1.0] * 4, "lengths": [9] * 10, "goals": [1] * 6 + [0] * 4,
                 "win_probability": 0.6, "exploration_rate": 0.2, "transitions": 90},
    "sampling": {"mode": "iupe", "from_pre": [100, 200, 50, 210], "from_pos": [10, 20, 30, 30], "size": 650},
    "evaluation": {"aer": 0.42, "aer_std": 0.1, "performance": 0.5, "returns": [0.42], "goal_rate": 0.6,
                   "mean_length": 9.0, "sampled_actions": False, "fidelity": 0.5, "random_reference": 0.1,
                   "expert_reference": 0.97},
    "seconds": {"idm": 0.1, "total": 0.5},
}


def _texts(fig) -> str:
    return " ".join(a.text or "" for a in fig.layout.annotations) + " " + (fig.layout.title.text or "")


def test_diagram_shows_the_sizes_and_highlights_a_phase():
    from ifo.learners.bco import BCOLearner
    from ifo.ui.diagram import ACTIVE, BOXES, loop_diagram

    boxes = {p.name: p.box for p in BCOLearner.phases}
    fig = loop_diagram(SYNTHETIC, "sampling", pre_size=1400, expert_size=100, phase_boxes=boxes)
    text = _texts(fig)
    for expected in ("|I_pre| = 1,400", "|I_s| = 1,400", "|T_e| = 100", "|E| = 10 runs", "P(g|E) = 60%",
                     "I_pre 560 + I_pos 90", "next |I_s| = 650", "I_pos 90", "now: sampling"):
        assert expected in text, expected
    filled = [s for s in fig.layout.shapes if s.fillcolor == ACTIVE]
    assert len(filled) == 1 and len(fig.layout.shapes) == len(BOXES)
    x, y, _ = BOXES["sampling"]
    assert filled[0].x0 < x < filled[0].x1 and filled[0].y0 < y < filled[0].y1
    assert not any(s.fillcolor == ACTIVE for s in loop_diagram(SYNTHETIC).layout.shapes)  # idle: no highlight
    assert "before the first iteration" in _texts(loop_diagram(None))


def test_registry_has_unique_keys_and_every_panel_draws():
    from ifo.figure_registry import EnvView
    from ifo.ui.registry import PANELS, active_panels

    keys = [p.key for p in PANELS]
    assert len(keys) == len(set(keys))
    assert all(p.title and p.explanation and p.thesis_figure and (p.draw or p.render) for p in PANELS)
    maze = EnvView.of({"env": "maze3", "obs_mode": "image", "image_size": 32})
    shown = {p.key for p in active_panels([SYNTHETIC])}  # chosen by the sections the records have
    assert {"grad_cam", "action_distance", "exploration", "sampling", "win", "idm"} <= shown
    assert not {"td", "discriminator", "latent", "policy_map"} & shown
    assert active_panels([]) == []
    for p in PANELS:
        if p.draw is None:
            continue
        for records, it in (([SYNTHETIC], None), ([SYNTHETIC], 3)):
            fig = p.draw(records, maze, it)
            assert fig is None or fig.layout.title.text, p.key


def test_every_panel_draws_on_real_records(tiny_config):
    from ifo.run import Run
    from ifo.ui.registry import PANELS, active_panels, env_view

    run = Run(tiny_config(method="iupe", attention="features"))
    run.run(2)
    shown = {p.key for p in active_panels(run.records)}
    assert {"exploration", "state_attention", "sampling", "win"} <= shown and "grad_cam" not in shown
    for p in PANELS:
        if p.draw is not None and p.applies(run.records):
            for it in (None, 1):
                assert p.draw(run.records, env_view(run), it) is not None, p.key


def test_maze_runs_can_be_judged_as_the_thesis_did():
    at = open_step_page()
    assert not [r for r in at.sidebar.radio if r.key == "step.maze_eval_layouts"]  # CartPole: no maze options
    at = open_step_page(**{"step.env": "Maze 3x3", "step.maze_eval_layouts": "the demonstrations' layouts (thesis)",
                           "step.deadlock_guard": "true"})
    assert at.radio(key="step.maze_eval_layouts").value == "demonstration"
    assert at.toggle(key="step.deadlock_guard").value is True
    cfg = slot(at).run.config
    assert (cfg.env, cfg.maze_eval_layouts, cfg.deadlock_guard) == ("maze3", "demonstration", True)
    at.radio(key="step.maze_eval_layouts").set_value("held-out").run()  # a new run, judged on held-out layouts
    assert not at.exception
    assert slot(at).run.config.maze_eval_layouts == "held-out"


def test_a_setting_that_multiplies_the_work_warns_before_the_step():
    """A 256-pixel maze image is 64x the networks' work per image, and building the run renders every
    frame at that size before the first Step: the sidebar says so as the setting changes, and says nothing
    at the defaults, nor for a setting that only lightens the work. 64 pixels (x4) keeps this test short."""
    at = open_step_page(**{"step.env": "Maze 5x5"})
    assert not at.sidebar.warning
    at.number_input(key="step.image_size").set_value(16).run()  # smaller: lighter, no warning
    assert not at.exception and not at.sidebar.warning
    at.number_input(key="step.image_size").set_value(64).run()
    at.number_input(key="step.eval_episodes").set_value(1000).run()
    assert not at.exception
    [warning] = [w.value for w in at.sidebar.warning]
    assert "Image size 64 against the default 32 (up to ×4 the work" in warning
    assert "against the default 100 (up to ×10 the work" in warning
    assert "each Step may take minutes" in warning


# --------------------------------------------------------------------------- journeys that broke a class
VECTOR_ONLY = ("sail", "gail", "gaifo", "ilpo")  # their networks read state vectors: on a maze, its vector observations


@pytest.mark.parametrize("method", sorted(METHOD_CHARTS))
def test_every_method_steps_on_the_maze_or_says_which_setting_it_needs(method):
    """Every method on Maze 3x3. Those that read images step twice without an error (image runs report a
    phase twice per iteration, and the live loop diagram drawn at each phase once gave two charts the same
    id; CRIL once crashed at its first Step: its replay memory stored the images as floats). Those that read
    state vectors say so and name the setting that gives them one; chosen, that run steps."""
    from ifo.methods import get_method

    at = open_step_page(**{"step.env": "Maze 3x3", "step.method": get_method(method).title})
    if method in VECTOR_ONLY:
        assert slot(at).run is None and not at.exception
        [error] = [e.value for e in at.error]
        assert f"Could not start a run of {get_method(method).title} on Maze 3x3" in error
        assert 'the setting "Maze observations": vector' in error
        at.selectbox(key="step.obs_mode").select("vector").run()
        assert not at.error, [e.value for e in at.error]
    assert slot(at).run.config.method == method
    total = slot(at).run.config.iterations  # 15, the maze's default; BC and BCO are one pass
    for k in range(1, min(2, total) + 1):
        at.button(key="step").click().run()
        assert not at.exception and not at.error, [e.value for e in at.error]
        assert counter(at) == f"Iteration {k} of {total}"


# What each method shows after its first Step on CartPole, beyond the AER and Performance every run has: tests/method_charts.py.
def test_every_method_is_in_the_list_of_charts():
    from ifo.methods import METHODS

    assert sorted(METHOD_CHARTS) == sorted(METHODS)


@pytest.mark.parametrize("method", sorted(METHOD_CHARTS))
def test_every_method_opens_and_steps_on_cartpole(method):
    """Choosing a method draws its settings (More settings included) and a Step draws its panels. Choosing
    CRIL once raised StreamlitMixedNumericTypesError (a float setting bounded by an int) before any Step."""
    from ifo.methods import get_method

    at = open_step_page()
    at.selectbox(key="step.method").select(method).run()
    assert not at.exception, at.exception
    assert slot(at).run.config.method == method
    assert "More settings" in [e.label for e in at.sidebar.expander]
    at.button(key="step").click().run()
    assert not at.exception and not at.error, [e.value for e in at.error]
    assert counter(at).startswith("Iteration 1 of ")
    keys = chart_keys(at)
    own = {f"panel.{key}" for key in METHOD_CHARTS[method]}
    assert {"panel.aer", "panel.performance", *own} <= set(keys), (get_method(method).title, keys)


def test_the_user_stays_the_same_across_pages():
    from ifo.ui import storage

    def user_of(at):
        value = at.query_params[storage.USER_PARAM]
        return value[0] if isinstance(value, list) else value

    at = open_app()
    user = user_of(at)
    assert storage.valid_user(user)  # every page, the landing page too, knows who this is
    at.switch_page(STEP_PAGE).run()
    at.button(key="step").click().run()
    assert user_of(at) == user
    at.query_params.pop(storage.USER_PARAM)  # a sidebar link carries no ?user=
    at.switch_page("views/runs.py").run()
    assert not at.exception
    assert user_of(at) == user
    assert [r.iterations_done for r in storage.list_runs(user)] == [1]  # the autosave is where the list looks
    assert any("1 of 10 iterations" in c.value for c in at.caption)
    at.query_params.pop(storage.USER_PARAM)
    at.switch_page(STEP_PAGE).run()
    assert user_of(at) == user and counter(at) == "Iteration 1 of 10"  # the same run, not a new user


def test_toggling_a_switch_mid_run_can_branch_from_this_iteration():
    at = open_step_page()
    for _ in range(2):
        at.button(key="step").click().run()
    parent = slot(at).run
    at.selectbox(key="step.bco-alpha.sampling").select("iupe").run()
    assert any("as a branch" in m.value for m in at.markdown)
    at.button(key="branch").click().run()
    assert not at.exception and not at.error
    branch = slot(at).run
    assert branch is not parent and branch.config.learner.sampling == "iupe"
    assert counter(at) == "Iteration 2 of 10" and branch.records == parent.records  # from the same point
    at.button(key="step").click().run()
    assert counter(at) == "Iteration 3 of 10" and parent.iteration == 2
    from ifo.ui import storage

    user = at.query_params[storage.USER_PARAM]
    labels = [r.label for r in storage.list_runs(user[0] if isinstance(user, list) else user)]
    assert any("branched from" in label and "at iteration 2" in label for label in labels)
    assert len(labels) == 2  # the run before the change is kept too


def test_a_read_only_share_shows_the_run_and_a_copy_to_play_with():
    from ifo.ui import storage

    teacher = open_step_page()
    for _ in range(2):
        teacher.button(key="step").click().run()
    link = next(c.value for c in teacher.code if "/watch?share=" in c.value)  # in the "Share read-only" popover
    assert link and "/watch?share=" in link and "user=" not in link  # never the teacher's id
    token = link.rsplit("=", 1)[1]
    owner = teacher.query_params[storage.USER_PARAM]
    owner = owner[0] if isinstance(owner, list) else owner

    student = open_app(share=token)
    student.switch_page("views/watch.py").run()
    assert not student.exception and not student.error
    assert any("read-only" in m.value for m in student.markdown)
    assert counter(student) == "Iteration 2 of 10" and "watch.diagram" in chart_keys(student)
    assert not [b for b in student.button if b.key in ("step", "reset", "run")]  # nothing to change it with
    student.button(key="watch.copy").click().run()
    mine = student.query_params[storage.USER_PARAM]
    mine = mine[0] if isinstance(mine, list) else mine
    assert mine != owner and [r.iterations_done for r in storage.list_runs(mine)] == [2]
    assert [r.iterations_done for r in storage.list_runs(owner)] == [2]  # the teacher's run is untouched


def test_a_student_who_looks_elsewhere_finds_the_watched_run_again():
    """The sidebar's link and the browser's Back button reach /watch without `?share=`: the page
    shows the run this session watched, and puts the token back in the address bar."""
    from ifo.ui import storage

    teacher = open_step_page()
    teacher.button(key="step").click().run()
    token = next(c.value for c in teacher.code if "/watch?share=" in c.value).rsplit("=", 1)[1]
    student = open_app(share=token)
    student.switch_page("views/watch.py").run()
    assert counter(student) == "Iteration 1 of 10"

    student.query_params.pop(storage.SHARE_PARAM)  # navigation drops the link's query
    student.switch_page("views/runs.py").run()
    student.switch_page("views/watch.py").run()
    assert not student.exception and not student.error
    assert counter(student) == "Iteration 1 of 10"
    assert student.query_params[storage.SHARE_PARAM] in (token, [token])

    student.query_params[storage.SHARE_PARAM] = "0" * 32  # a stale link the student opens on purpose
    student.run()
    assert "Could not open this shared run" in student.error[0].value  # not silently the old run


def test_the_first_page_of_a_server_process_pays_the_first_steps_one_time_costs(tmp_path):
    """After the first page of a fresh process is drawn, the training library is imported and torch's
    first-Adam-step cost is paid, so the class's first Step does not wait for them."""
    import subprocess
    import sys

    probe = ("import sys; from streamlit.testing.v1 import AppTest; "
             f"at = AppTest.from_file({str(ROOT / 'app.py')!r}, default_timeout=120); at.run(); "
             "assert not at.exception, at.exception; "
             "print('torch._dynamo' in sys.modules, 'ifo.run' in sys.modules, 'ifo.ui.panels' in sys.modules)")
    env = {**__import__("os").environ, "IFO_LAB_RUNS": str(tmp_path / "runs"), "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, env=env, timeout=300)
    assert out.stdout.split()[-3:] == ["True", "True", "True"], out.stdout + out.stderr


def test_a_bad_share_link_says_so():
    at = open_app(share="0" * 32)
    at.switch_page("views/watch.py").run()
    assert not at.exception and "Could not open this shared run" in at.error[0].value


def test_a_lesson_opens_the_step_page_with_its_settings():
    at = open_app()
    assert any("Vanishing actions" in m.value for m in at.markdown)
    at.button(key="lesson.0.bco-alpha.cartpole").click().run()
    assert not at.exception and not at.error
    cfg = slot(at).run.config
    assert (cfg.method, cfg.seed, cfg.learner.pre_size, cfg.iterations) == ("bco-alpha", 5, 300, 5)
    at.switch_page(STEP_PAGE)  # (AppTest does not follow st.switch_page from one run to the next)
    at.button(key="step").click().run()
    assert counter(at) == "Iteration 1 of 5"


def test_the_lesson_builder_makes_a_link_without_the_user():
    at = open_step_page(**{"step.method": "IUPE"})
    at.multiselect(key="lesson.hide").select("settings").select("idm").run()
    link = next(c.value for c in at.code if "hide=" in c.value)
    assert "hide=settings%2Cidm" in link and "step.method=IUPE" in link and "user=" not in link
    hidden = open_step_page(hide="settings,idm", **{"step.method": "IUPE"})
    hidden.button(key="step").click().run()
    assert "panel.idm" not in chart_keys(hidden) and not hidden.sidebar.selectbox


def test_each_learner_family_draws_its_own_loop():
    from ifo.learners import LEARNERS
    from ifo.ui.diagram import LAYOUTS, loop_diagram

    for learner in LEARNERS.values():  # every phase lights a box of its learner's own diagram
        boxes = LAYOUTS[learner.diagram].boxes
        assert all(p.box in boxes for p in learner.phases), learner.key
    gaifo = {"iteration": 2, "discriminator": {"accuracy_expert": 0.6, "accuracy_agent": 0.55, "mean_reward": 0.3},
             "generator": {"loss": 0.01}, "evaluation": {"aer": 200.0, "performance": 0.4},
             "samples": {"environment_steps": 4096}}
    text = _texts(loop_diagram(gaifo, "discriminator", expert_size=500, layout="adversarial",
                               phase_boxes={"discriminator": "discriminator"}))
    assert "expert 60%, agent 55%" in text and "4,096 steps so far" in text and "The adversarial round" in text


def test_a_figure_is_built_once_per_content_and_shared_across_sessions():
    """Thirty students on one lesson draw the same figures: built once per server, rebuilt when the
    records, the iteration shown or the environment differ."""
    import copy

    import plotly.graph_objects as go

    from ifo.ui import panels

    class Counting:
        key = "test.counting"
        calls = 0

        def draw(self, records, env, iteration):
            self.calls += 1
            return go.Figure(go.Scatter(y=[r["evaluation"]["aer"] for r in records]))

    records = [{"iteration": k, "evaluation": {"aer": 10.0 * k}} for k in (1, 2, 3)]
    panel = Counting()

    def draw(recs, shown=None, env="cartpole"):
        return panels.shared_figure(panel, panels.PanelContext(None, None, recs, shown, {"env": env}))

    first = draw(records)
    assert draw(copy.deepcopy(records)) is first and panel.calls == 1  # another session's equal records
    draw(records, shown=2)
    draw(records, env="acrobot")
    changed = copy.deepcopy(records)
    changed[-1]["evaluation"]["aer"] = 31.0
    assert draw(changed) is not first and panel.calls == 4


def test_the_pages_folder_is_not_called_pages():
    """With a pages/ folder beside app.py, Streamlit runs a deep link in a server's first session (a shared
    /watch link, /runs) as a v1 multipage app: the page alone, without app.py and its navigation."""
    assert not (ROOT / "pages").exists() and (ROOT / "views" / "step_through.py").exists()


def test_the_server_skips_streamlits_full_garbage_collection_after_every_page_run():
    """`streamlit run` in the repo (make run, the browser tests) reads .streamlit/config.toml: Streamlit's
    gc.collect(2) after every script run held the GIL for a fifth of a class's server time. The option
    must still exist under that name in the Streamlit we pin, or the file silently does nothing."""
    import tomllib

    from streamlit import config

    settings = tomllib.loads((ROOT / ".streamlit" / "config.toml").read_text())
    for section, values in settings.items():
        for name in values:
            assert f"{section}.{name}" in config.get_config_options(), f"Streamlit has no option {section}.{name}"
    assert settings["runner"]["postScriptGC"] is False


def test_the_server_compiles_its_pages_without_building_python_syntax_trees(monkeypatch):
    """Streamlit's "magic" builds each page's syntax tree with ast.parse, which CPython 3.11 cannot do in one
    thread while another (a training reading a .npy header with ast.literal_eval) does the same (gh-106905).
    With the repo's config.toml every page script, app.py and views/, compiles without ast.parse."""
    import ast
    import tomllib

    from streamlit import config
    from streamlit.runtime.scriptrunner.script_cache import ScriptCache

    settings = tomllib.loads((ROOT / ".streamlit" / "config.toml").read_text())
    built = []
    real_parse = ast.parse
    monkeypatch.setattr(ast, "parse", lambda *a, **k: built.append(a[1:2]) or real_parse(*a, **k))
    before = config.get_option("runner.magicEnabled")
    config.set_option("runner.magicEnabled", settings["runner"]["magicEnabled"])
    try:
        cache = ScriptCache()
        for script in [ROOT / "app.py", *sorted((ROOT / "views").glob("*.py"))]:
            assert cache.get_bytecode(str(script)) is not None
    finally:
        config.set_option("runner.magicEnabled", before)
    assert built == []


def test_a_link_may_name_choices_as_the_configuration_does():
    """`?step.env=maze3&step.method=iupe` (the names of the CLI and the configuration) opens that run, as
    the labels the page itself writes into its links (`Maze 3x3`, `IUPE`) do; it was once ignored."""
    at = open_step_page(**{"step.env": "maze3", "step.method": "iupe", "step.maze_eval_layouts": "demonstration"})
    cfg = slot(at).run.config
    assert (cfg.env, cfg.method, cfg.maze_eval_layouts) == ("maze3", "iupe", "demonstration")
    at.run()
    assert not at.exception and slot(at).run.config.env == "maze3"  # and it stays so


def test_slide_downloads_under_each_chart_appear_when_asked_for():
    """Under the charts, the SVG/PNG/PDF buttons appear once the teacher turns them on (the slide pack, with
    every chart, is there either way); a class's pages stay light until then."""
    from ifo import export

    if export.export_problem() is not None:
        pytest.skip(export.export_problem())
    at = open_step_page()
    at.button("step").click().run()
    labels = lambda: [b.proto.label for b in at.get("download_button")]  # noqa: E731
    assert labels() == ["Slide pack (ZIP)"]
    at.toggle("export.per_chart").set_value(True).run()
    assert not at.exception
    charts = [k for k in chart_keys(at) if k.startswith("panel.")]
    assert charts and labels().count("SVG") == labels().count("PNG") == labels().count("PDF") == len(charts)
    assert labels()[-1] == "Slide pack (ZIP)"


def test_charts_reach_the_page_without_plotly_template_and_slides_keep_theirs():
    """Streamlit's theme draws the charts on screen, so the page's figures carry no plotly template (most of
    a small figure's bytes, copied and sent for every student); a slide made from one gets the white one."""
    import json

    import plotly.graph_objects as go
    import plotly.io as pio

    from ifo.export import slide_theme

    at = open_step_page()
    at.button("step").click().run()
    assert not at.exception
    layouts = {c.key: json.loads(c.proto.spec)["layout"] for c in at.get("plotly_chart")}
    assert any(k.startswith("panel.") for k in layouts) and "step.diagram" in layouts
    for key, layout in layouts.items():
        assert not layout.get("template", {}).get("layout"), key  # no colours, fonts or axes from plotly
    slide = json.loads(pio.to_json(slide_theme(go.Figure(layout=layouts["panel.aer"]))))["layout"]
    assert slide["template"]["layout"]["plot_bgcolor"] == "white"
