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
