"""Figures are pure functions of records: check them on synthetic records."""
import plotly.graph_objects as go
import pytest

from ifo import figures

ACTIONS = ("N", "S", "W", "E")


def record(i, sampled=True):
    return {
        "iteration": i,
        "idm": {"loss": 1.0 / i, "train_accuracy": 0.5, "val_accuracy": 0.9, "expert_accuracy": 0.6 + 0.1 * i,
                "prediction_counts": [10, 20 + i, 30, 40 - i], "true_counts": [5, 25, 35, 35]},
        "labels": {"counts": [12, 18, 30, 40], "sampled": sampled, "exploration_rate": 0.3 / i},
        "policy": {"loss": 0.5, "agreement": 0.9, "expert_accuracy": 0.7},
        "rollouts": {"returns": [1.0, -1.0], "goals": [1, 0], "win_probability": 0.1 * i, "exploration_rate": 0.2 / i},
        "sampling": {"mode": "iupe", "from_pre": [100, 90, 80, 70], "from_pos": [5 * i, 6, 7, 8], "size": 366},
        "evaluation": {"aer": 0.1 * i, "aer_std": 0.05, "performance": 0.2 * i, "random_reference": -0.9,
                       "expert_reference": 0.96, "goal_rate": 0.5},
        "seconds": {"idm": 0.5, "policy": 0.2, "rollout": 0.3, "evaluate": 0.1, "total": 1.1},
    }


RECORDS = [record(i) for i in (1, 2, 3)]


def test_learning_curves_have_the_learner_and_reference_lines():
    fig = figures.learning_curve(RECORDS, "aer")
    assert isinstance(fig, go.Figure)
    assert list(fig.data[0].y) == pytest.approx([0.1, 0.2, 0.3])
    texts = {a.text for a in fig.layout.annotations}
    assert {"expert", "random"} <= texts
    perf = figures.learning_curve(RECORDS, "performance", iteration=2)
    assert list(perf.data[0].y) == pytest.approx([0.2, 0.4, 0.6])
    assert any(s.type == "line" and s.x0 == 2 for s in perf.layout.shapes)  # the scrubbed iteration


def test_idm_predictions_show_the_hidden_truth_beside_the_predictions():
    fig = figures.idm_predictions(RECORDS, ACTIONS, iteration=1)
    names = [t.name for t in fig.data]
    assert names == ["IDM (MAP)", "labels used (sampled)", "expert's hidden true actions"]
    assert sum(fig.data[0].y) == pytest.approx(1.0)
    assert fig.data[0].y[1] == pytest.approx(21 / 100)
    assert "iteration 1" in fig.layout.title.text
    with pytest.raises(ValueError):
        figures.idm_predictions(RECORDS, ACTIONS, iteration=9)


def test_idm_predictions_over_time_stack_one_area_per_action():
    fig = figures.idm_predictions_over_time(RECORDS, ACTIONS)
    areas = [t for t in fig.data if t.stackgroup]
    assert [t.name for t in areas] == list(ACTIONS)


def test_sampling_mixture_and_exploration_rate():
    fig = figures.sampling_mixture(RECORDS, ACTIONS, iteration=3)
    assert list(fig.data[1].y) == [15, 6, 7, 8] and fig.layout.barmode == "stack"
    rate = figures.exploration_rate(RECORDS)
    assert [t.name for t in rate.data] == ["IDM labels", "policy rollouts"]
    assert list(rate.data[0].y) == pytest.approx([0.3, 0.15, 0.1])


@pytest.mark.parametrize("draw", [
    lambda r: figures.learning_curve(r, "aer"), lambda r: figures.idm_predictions(r, ACTIONS),
    lambda r: figures.idm_predictions_over_time(r, ACTIONS), lambda r: figures.accuracy_curves(r),
    lambda r: figures.win_probability(r), lambda r: figures.exploration_rate(r),
    lambda r: figures.sampling_mixture(r, ACTIONS), lambda r: figures.phase_seconds(r),
])
def test_every_figure_has_an_empty_state_with_a_message(draw):
    fig = draw([])
    assert len(fig.data) == 0 and fig.layout.annotations and fig.layout.annotations[0].text


def test_bc_records_without_an_idm_explain_themselves():
    bc = [{k: v for k, v in record(1).items() if k not in ("idm", "labels", "rollouts", "sampling")}]
    fig = figures.idm_predictions(bc, ACTIONS)
    assert "BC" in fig.layout.annotations[0].text


def test_figures_are_pure_functions_of_records():
    a = figures.learning_curve(RECORDS, "performance").to_json()
    b = figures.learning_curve([dict(r) for r in RECORDS], "performance").to_json()
    assert a == b


def test_slide_theme_is_16_by_9_with_large_type():
    fig = figures.learning_curve(RECORDS, "aer", theme="slide")
    assert fig.layout.width / fig.layout.height == pytest.approx(16 / 9)
    assert fig.layout.font.size >= 20


# ----------------------------------------------------------------------------- fixed figures
def test_idm_predictions_over_time_draw_a_bar_at_the_first_iteration():
    fig = figures.idm_predictions_over_time(RECORDS[:1], ACTIONS)
    bars = [t for t in fig.data if t.type == "bar"]
    assert [t.name for t in bars] == list(ACTIONS) and fig.layout.barmode == "stack"
    assert [t.y[0] for t in bars] == pytest.approx([0.1, 0.21, 0.3, 0.39])
    truth = [t for t in fig.data if t.type == "scatter"]  # dotted lines across the bar, at the stacked true shares
    assert [t.y[0] for t in truth] == pytest.approx([0.05, 0.30, 0.65, 1.0])
    assert all(len(t.x) == 2 and t.x[0] < 1 < t.x[1] for t in truth)
    assert truth[1].customdata[0] == pytest.approx(0.25)  # the hover gives S's own true share


def test_idm_predictions_over_time_stack_the_true_shares_like_the_bands():
    fig = figures.idm_predictions_over_time(RECORDS, ACTIONS)
    truth = [t for t in fig.data if t.type == "scatter" and not t.stackgroup]
    assert len(truth) == len(ACTIONS) and list(truth[0].x) == [1, 2, 3]
    assert list(truth[2].y) == pytest.approx([0.65] * 3)
    no_truth = [dict(r, idm={k: v for k, v in r["idm"].items() if k != "true_counts"}) for r in RECORDS]
    assert len(figures.idm_predictions_over_time(no_truth, ACTIONS).data) == len(ACTIONS)


def test_exploration_rate_starts_at_zero_and_is_never_a_sliver():
    one = [dict(record(1), labels={"exploration_rate": 0.639, "counts": [1], "sampled": True})]
    one[0].pop("rollouts")
    fig = figures.exploration_rate(one, iteration=1)
    low, high = fig.layout.yaxis.range
    assert low == 0 and 0.639 < high <= 1.02
    tiny = [dict(r, labels={"exploration_rate": 0.001}, rollouts={"exploration_rate": 0.0}) for r in RECORDS]
    assert tuple(figures.exploration_rate(tiny).layout.yaxis.range) == pytest.approx((0, 0.05))


# ----------------------------------------------------------------------------- the IDM up close
def idm_record(i=1, truth=True):
    idm = {"prediction_counts": [5, 25, 30, 40], "confidence_histogram": [0, 0, 1, 2, 3, 4, 10, 20, 30, 30]}
    if truth:
        idm |= {"confusion": [[4, 1, 0, 0], [2, 20, 3, 0], [0, 5, 25, 5], [0, 0, 0, 35]],
                "true_action_probability_histogram": [5, 0, 0, 0, 5, 10, 10, 20, 20, 30]}
    return {"iteration": i, "idm": idm}


def test_idm_confusion_shows_counts_and_row_shares():
    fig = figures.idm_confusion([idm_record(1), idm_record(2)], ACTIONS, iteration=1)
    heat = fig.data[0]
    assert heat.type == "heatmap" and list(heat.x) == list(ACTIONS) and list(heat.y) == list(ACTIONS)
    assert heat.z[1] == pytest.approx((2 / 25, 20 / 25, 3 / 25, 0))  # row = the true action S
    assert heat.text[1][1] == "20<br>80%"
    assert fig.layout.xaxis.title.text == "IDM's label"
    assert "hidden" in fig.layout.yaxis.title.text
    assert "iteration 1" in fig.layout.title.text and "84% right" in fig.layout.title.text


def test_idm_confidence_bins_both_histograms():
    fig = figures.idm_confidence([idm_record()], ACTIONS)
    assert [t.name for t in fig.data] == ["its most likely action", "the expert's true action"]
    assert list(fig.data[0].x) == pytest.approx([0.05 + 0.1 * b for b in range(10)])
    assert list(fig.data[1].y) == [5, 0, 0, 0, 5, 10, 10, 20, 20, 30]
    assert "How sure the IDM is" in fig.layout.title.text
    assert any(s.x0 == 0.25 for s in fig.layout.shapes)  # a uniform guess over 4 actions
    assert len(figures.idm_confidence([idm_record(truth=False)], ACTIONS).data) == 1


def test_idm_figures_explain_what_is_missing():
    for draw in (figures.idm_confusion, figures.idm_confidence):
        assert "Step" in draw([], ACTIONS).layout.annotations[0].text
        assert "BC" in draw([{"iteration": 1, "policy": {}}], ACTIONS).layout.annotations[0].text
    assert "hidden" in figures.idm_confusion([idm_record(truth=False)], ACTIONS).layout.annotations[0].text


# ----------------------------------------------------------------------------- attention gates
def gated(i):
    return {"iteration": i,
            "policy": {"gates": [{"block": 0, "gamma": 0.1 * i, "effect": 0.01 * i}]},
            "idm": {"gates": [{"block": 0, "gamma": 0.2 * i, "effect": 0.02 * i},
                              {"block": 1, "gamma": -0.1 * i, "effect": 0.03 * i}]}}


def test_attention_gates_draw_gamma_and_effect_per_model_and_block():
    fig = figures.attention_gates([gated(1), gated(2), gated(3)], iteration=2)
    names = [t.name for t in fig.data]
    assert names == ["policy, block 0", "IDM, block 0", "IDM, block 1"] * 2
    gamma, effect = fig.data[:3], fig.data[3:]
    assert list(gamma[2].y) == pytest.approx([-0.1, -0.2, -0.3]) and list(gamma[2].x) == [1, 2, 3]
    assert list(effect[0].y) == pytest.approx([0.01, 0.02, 0.03])
    assert {t.yaxis for t in gamma} == {"y"} and {t.yaxis for t in effect} == {"y2"}
    assert sum(s.x0 == 2 for s in fig.layout.shapes) == 2  # the scrubbed iteration on both charts
    assert "gated" in figures.attention_gates([record(1)]).layout.annotations[0].text


# ----------------------------------------------------------------------------- policy map
def mapped(reference=True):
    pm = {"x_name": "position", "y_name": "velocity", "x": [-1.0, 0.0, 0.5], "y": [-0.05, 0.05],
          "action": [[0, 1, 2], [0, 2, 2]], "probability": [[0.5, 0.4, 1.0], [0.9, 0.6, 0.7]],
          "kl": 2.0869, "onehot_kl": 1.7345}
    if reference:
        pm["reference_action"] = [[0, 0, 2], [0, 2, 2]]
    return {"iteration": 4, "policy_map": pm}


def test_policy_map_colours_actions_and_shows_the_reference():
    fig = figures.policy_map([mapped()], action_names=["left", "none", "right"])
    policy, reference = fig.data
    assert policy.type == reference.type == "heatmap"
    assert list(policy.x) == [-1.0, 0.0, 0.5] and list(policy.y) == [-0.05, 0.05]
    assert policy.z[0] == pytest.approx((0.4995, 1.3996, 2.999))  # action + probability: hue, then paleness
    assert reference.z[0] == pytest.approx((0.999, 0.999, 2.999))
    assert list(policy.colorbar.ticktext) == ["left", "none", "right"] and policy.zmax == 3
    assert policy.customdata[0][1][0] == "none" and policy.customdata[0][1][1] == pytest.approx(0.4)
    title = fig.layout.title.text
    assert "2.09" in title and "1.73" in title and "83%" in title  # 5 of 6 cells agree
    assert fig.layout.xaxis.title.text == "position" and fig.layout.yaxis.title.text == "velocity"
    alone = figures.policy_map([mapped(reference=False)])
    assert len(alone.data) == 1 and list(alone.data[0].colorbar.ticktext) == ["action 0", "action 1", "action 2"]
    assert figures.policy_map(RECORDS).layout.annotations[0].text


# ----------------------------------------------------------------------------- compare runs
def test_compare_runs_draw_reference_lines():
    runs = [("a", RECORDS), ("b", RECORDS[:2])]
    aer = figures.compare_runs(runs, "aer", references={"expert": 0.96, "random": -0.9})
    lines = {a.text: s.y0 for a, s in zip(aer.layout.annotations, aer.layout.shapes)}
    assert lines == {"expert": 0.96, "random": -0.9}
    assert not figures.compare_runs(runs, "aer").layout.shapes  # no references given, none drawn
    perf = figures.compare_runs(runs, "performance", references={"expert": 5.0})
    assert sorted(s.y0 for s in perf.layout.shapes) == [0.0, 1.0]  # always 0 and 1
    assert list(perf.data[1].y) == pytest.approx([0.2, 0.4])
    assert figures.compare_runs([], "aer").layout.annotations[0].text


def test_compare_runs_keep_forty_runs_apart():
    fig = figures.compare_runs([(f"run {k}", RECORDS) for k in range(40)], "performance")
    styles = [(t.line.color, t.line.dash) for t in fig.data]
    assert len(set(styles)) == 40
    assert len({c for c, _ in styles[:20]}) == 20  # 20 colours before any repeats


# ----------------------------------------------------------------------------- the new methods' sections
def method_record(i):
    return {"iteration": i,
            "td": {"loss": 1.0 / i, "epsilon": 0.5 / i, "q_min": -10.0 + i, "q_max": -2.0 + i, "updates": 100 * i},
            "replay": {"size": 1000 * i, "capacity": 5000},
            "samples": {"environment_steps": 2000 * i, "expert_samples": 500},
            "discriminator": {"loss": 0.7, "accuracy_expert": 0.9 - 0.1 * i, "accuracy_agent": 0.8,
                              "accepted_share": 0.1 * i, "mean_reward": None},
            "generator": {"loss": 1.0 / i, "value_loss": 0.3, "entropy": None},
            "latent": {"assignment_counts": [30, 50, 20], "forward_error": 0.0123,
                       "remap": [[20, 5, 3, 2], [1, 40, 5, 4], [0, 2, 15, 3]]},
            "sampling": {"mode": "cril", "from_pre": [1], "from_pos": [1], "size": 2, "target_share": 0.1 * i,
                         "realised_share": 0.09 * i, "cap": 0.2 * i}}


METHOD_RECORDS = [method_record(i) for i in (1, 2, 3)]


def names_and_y(fig):
    return {t.name: list(t.y) for t in fig.data}


def test_td_curves_show_loss_epsilon_and_the_q_band():
    fig = figures.td_curves(METHOD_RECORDS, iteration=2)
    ys = names_and_y(fig)
    assert ys["epsilon"] == pytest.approx([0.5, 0.25, 0.5 / 3])
    assert ys["largest Q-value"] == pytest.approx([-1, 0, 1]) and ys["smallest Q-value"] == pytest.approx([-9, -8, -7])
    assert [t.fill for t in fig.data if t.name == "smallest Q-value"] == ["tonexty"]
    assert sum(s.x0 == 2 for s in fig.layout.shapes) == 3


def test_replay_and_sample_counts():
    replay = names_and_y(figures.replay_fill(METHOD_RECORDS))
    assert replay == {"transitions stored": [1000, 2000, 3000], "capacity": [5000] * 3}
    fig = figures.sample_count(METHOD_RECORDS, iteration=2)
    assert names_and_y(fig) == {"expert samples": [500] * 3, "environment steps": [2000, 4000, 6000]}
    assert fig.layout.barmode == "stack" and "4,500" in fig.layout.title.text
    assert any(s.x0 == 2 for s in fig.layout.shapes)


def test_discriminator_curves_mark_the_chance_line_and_skip_missing_values():
    fig = figures.discriminator_curves(METHOD_RECORDS, iteration=2)
    ys = names_and_y(fig)
    assert set(ys) == {"on expert samples", "on the learner's samples", "discriminator loss", "accepted episodes"}
    assert ys["on expert samples"] == pytest.approx([0.8, 0.7, 0.6])
    chance = [a for a in fig.layout.annotations if a.text == "cannot tell them apart"]
    assert len(chance) == 1 and any(s.y0 == 0.5 for s in fig.layout.shapes)
    gail = [dict(r, discriminator={"loss": 0.5, "accuracy_expert": 0.6, "accuracy_agent": 0.6, "mean_reward": 0.2})
            for r in METHOD_RECORDS]
    assert set(names_and_y(figures.discriminator_curves(gail))) == {
        "on expert samples", "on the learner's samples", "discriminator loss", "mean reward"}


def test_generator_loss_draws_what_is_present():
    ys = names_and_y(figures.generator_loss(METHOD_RECORDS))
    assert ys == {"loss": pytest.approx([1.0, 0.5, 1 / 3]), "value loss": [0.3] * 3}


def test_latent_actions_counts_and_remap():
    fig = figures.latent_actions(METHOD_RECORDS, action_names=ACTIONS)
    bars, heat = fig.data
    assert list(bars.x) == ["z0", "z1", "z2"] and list(bars.y) == [30, 50, 20]
    assert list(heat.x) == list(ACTIONS) and heat.z[1][1] == 40
    assert "0.0123" in fig.layout.title.text
    only_counts = [{"iteration": 1, "latent": {"assignment_counts": [3, 4]}}]
    assert len(figures.latent_actions(only_counts).data) == 1


def test_sampling_share_draws_target_realised_and_cap():
    fig = figures.sampling_share(METHOD_RECORDS, iteration=2)
    ys = names_and_y(fig)
    assert ys["share asked for"] == pytest.approx([0.1, 0.2, 0.3]) and ys["upper limit (cap)"] == pytest.approx(
        [0.2, 0.4, 0.6])
    assert fig.layout.title.text == "Share of I_s from the policy's own runs"
    no_cap = [dict(r, sampling={"target_share": 0.5, "realised_share": 0.4, "cap": None}) for r in METHOD_RECORDS]
    assert len(figures.sampling_share(no_cap).data) == 2
    assert figures.sampling_share(RECORDS).layout.annotations[0].text  # ABCO's record: no shares recorded


# ----------------------------------------------------------------------------- every new figure
NEW = {
    "idm_confusion": (lambda r, **kw: figures.idm_confusion(r, ACTIONS, **kw), [idm_record(1), idm_record(2)]),
    "idm_confidence": (lambda r, **kw: figures.idm_confidence(r, ACTIONS, **kw), [idm_record(1), idm_record(2)]),
    "attention_gates": (figures.attention_gates, [gated(1), gated(2)]),
    "policy_map": (lambda r, **kw: figures.policy_map(r, action_names=("l", "n", "r"), **kw),
                   [dict(mapped(), iteration=1), dict(mapped(), iteration=2)]),
    "td_curves": (figures.td_curves, METHOD_RECORDS),
    "replay_fill": (figures.replay_fill, METHOD_RECORDS),
    "sample_count": (figures.sample_count, METHOD_RECORDS),
    "discriminator_curves": (figures.discriminator_curves, METHOD_RECORDS),
    "generator_loss": (figures.generator_loss, METHOD_RECORDS),
    "latent_actions": (lambda r, **kw: figures.latent_actions(r, action_names=ACTIONS, **kw), METHOD_RECORDS),
    "sampling_share": (figures.sampling_share, METHOD_RECORDS),
}


@pytest.mark.parametrize("name", NEW)
def test_new_figures_are_empty_with_a_message_without_their_section(name):
    draw, _ = NEW[name]
    for records in ([], [{"iteration": 1, "policy": {}, "evaluation": {"aer": 0.0}}]):
        fig = draw(records)
        assert len(fig.data) == 0 and fig.layout.annotations[0].text


@pytest.mark.parametrize("name", NEW)
def test_new_figures_draw_on_slides_and_serialise(name):
    import plotly.io as pio

    draw, records = NEW[name]
    for it in (1, 2, None):
        fig = draw(records[:1] if it == 1 else records, iteration=it)
        assert len(fig.data) > 0
        fig.to_dict()
        assert pio.from_json(pio.to_json(fig)).data
    slide = draw(records, theme="slide")
    assert slide.layout.width == 1600 and slide.layout.font.size >= 20


@pytest.mark.parametrize("draw", [
    lambda r, **kw: figures.idm_predictions_over_time(r, ACTIONS, **kw),
    lambda r, **kw: figures.exploration_rate(r, iteration=1, **kw),
    lambda r, **kw: figures.compare_runs([("a", r), ("b", r)], "aer", references={"expert": 1.0, "random": -1.0}, **kw),
])
@pytest.mark.parametrize("n", [1, 3])
def test_fixed_figures_draw_on_slides_and_serialise(draw, n):
    import plotly.io as pio

    for theme in ("screen", "slide"):
        fig = draw(RECORDS[:n], theme=theme)
        assert fig.data and pio.from_json(pio.to_json(fig)).data
        fig.to_dict()
    assert fig.layout.width == 1600


# ----------------------------------------------------------------------------- Fig 7.1 (resilience)
def _resilience_results():
    rows = []
    for level, expert in ((1, 500.0), (3, 350.0), (5, 110.0)):
        for seed in (0, 1):
            rows.append({"env": "cartpole", "method": "BC", "level": level, "seed": seed, "expert_aer": expert,
                         "aer": expert - 10 * seed, "performance": 1.0, "performance_expert1": expert / 500,
                         "fidelity": 0.1 * level})
        rows.append({"env": "cartpole", "method": "ILPO", "level": level, "seed": 0, "expert_aer": expert,
                     "aer": 500.0, "performance": 500 / expert, "performance_expert1": 1.0, "fidelity": 0.2})
        rows.append({"env": "cartpole", "method": f"Expert{level}", "level": level, "seed": 0, "expert_aer": expert,
                     "aer": expert, "performance": 1.0})
        rows.append({"env": "cartpole", "method": "Random", "level": level, "seed": 0, "expert_aer": None,
                     "aer": 20.0, "performance": 0.0})
    rows.append({"env": "acrobot", "method": "BC", "level": 1, "seed": 0, "expert_aer": -80.0, "aer": -90.0})
    return rows


def test_resilience_curves_draw_one_line_per_method_against_the_experts_aer():
    fig = figures.resilience_curves(_resilience_results(), "cartpole")
    names = [t.name for t in fig.data]
    assert names == ["expert", "BC", "ILPO"]  # references are not methods; the expert is the line y = x, drawn first
    bc = fig.data[1]
    assert list(bc.x) == [110.0, 350.0, 500.0]  # sorted by the expert's AER
    assert list(bc.y) == pytest.approx([105.0, 345.0, 495.0])  # mean over seeds
    assert list(bc.error_y.array) == pytest.approx([50 ** 0.5] * 3)  # one sample sd (n − 1), as the tables
    assert list(fig.data[0].x) == list(fig.data[0].y) == [110.0, 350.0, 500.0]
    assert any(a.text == "random" for a in fig.layout.annotations)
    assert "cartpole" in fig.layout.title.text


def test_resilience_curves_show_fidelity_and_performance_and_the_thesis_dotted():
    fid = figures.resilience_curves(_resilience_results(), "cartpole", metric="fidelity")
    assert [t.name for t in fid.data] == ["BC", "ILPO"]
    assert list(fid.data[0].y) == pytest.approx([0.5, 0.3, 0.1])
    perf = figures.resilience_curves(_resilience_results(), "cartpole", metric="performance")
    assert list(perf.data[1].y) == pytest.approx([500 / 110, 500 / 350, 1.0])
    with_thesis = figures.resilience_curves(_resilience_results(), "cartpole", theme="slide",
                                            thesis={"BC": [(500, 500), (112, 155.96)]})
    dotted = next(t for t in with_thesis.data if t.name == "BC (thesis)")
    assert dotted.line.dash == "dot" and list(dotted.x) == [112, 500]
    assert with_thesis.layout.width == 1600  # the slide theme
    empty = figures.resilience_curves(_resilience_results(), "mountaincar")
    assert not empty.data and "No results" in empty.layout.annotations[0].text
    with pytest.raises(ValueError):
        figures.resilience_curves([], "cartpole", metric="nope")


def test_a_method_keeps_its_colour_when_a_budget_leaves_another_out():
    """The longer budget has no BC: ILPO must not take BC's colour (a class compares the two budgets)."""
    every = ["BC", "GAIL", "ILPO", "IUPE"]
    both = figures.resilience_curves(_resilience_results(), "cartpole", colors_by=every)
    without_bc = figures.resilience_curves([r for r in _resilience_results() if r["method"] != "BC"], "cartpole",
                                           colors_by=every)
    colour = {fig_name: {t.name: t.line.color for t in fig.data} for fig_name, fig in
              (("both", both), ("without BC", without_bc))}
    assert colour["both"]["ILPO"] == colour["without BC"]["ILPO"] != colour["both"]["BC"]


def test_every_chart_draws_its_registry_title(tiny_config):
    """A chart is named once: the title a lesson's hide list shows (the registry's) is the one drawn on
    the page and on the slides, maybe followed by the iteration. Real one-iteration runs of every
    method, plus the runs that draw attention, the policy map and Grad-CAM."""
    from ifo.figure_registry import FIGURES, EnvView, views_for
    from ifo.methods import METHODS
    from ifo.run import Run

    cases = [dict(method=m) for m in METHODS] + [
        dict(method="abco", attention="features"), dict(env="mountaincar", method="bco"),
        dict(env="maze3", method="iupe")]
    drawn = {}
    for case in cases:
        config = tiny_config(**case)
        run = Run(config)
        run.step()
        env = EnvView.of(config.to_dict())
        for view in views_for(run.records):
            drawn[view.key] = view.draw(run.records, env, None, "screen").layout.title.text
    assert sorted(drawn) == sorted(v.key for v in FIGURES), "a figure no case above draws"
    for view in FIGURES:
        assert drawn[view.key].startswith(view.title), (view.key, view.title, drawn[view.key])
