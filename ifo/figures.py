"""Figures: pure functions of run records -> plotly Figure.

The app, the command line's export and the tests draw exactly these. Each takes the
list of iteration records (plain dicts from `Run.step()`), optionally an iteration to
show (1-based; default the last), and returns a `plotly.graph_objects.Figure`.
"""
from __future__ import annotations

from typing import Sequence

import plotly.graph_objects as go

COLORS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f"]
EXPERT_COLOR, RANDOM_COLOR = "#2ca02c", "#7f7f7f"


def _layout(fig: go.Figure, title: str, x: str, y: str, theme: str = "screen") -> go.Figure:
    big = theme == "slide"
    fig.update_layout(
        title=dict(text=title, font=dict(size=30 if big else 16)),
        xaxis_title=x, yaxis_title=y, template="plotly_white",
        font=dict(size=22 if big else 13), legend=dict(orientation="h", y=-0.2 if big else -0.25),
        margin=dict(l=60, r=20, t=60 if big else 45, b=60),
        **({"width": 1600, "height": 900} if big else {}),
    )
    return fig


def _pick(records: Sequence[dict], iteration: int | None) -> dict | None:
    if not records:
        return None
    if iteration is None:
        return records[-1]
    for r in records:
        if r["iteration"] == iteration:
            return r
    raise ValueError(f"no record for iteration {iteration}")


def _empty(title: str, message: str, theme: str) -> go.Figure:
    fig = go.Figure()
    fig.add_annotation(text=message, showarrow=False, font=dict(size=16), x=0.5, y=0.5, xref="paper", yref="paper")
    fig.update_xaxes(visible=False)
    fig.update_yaxes(visible=False)
    return _layout(fig, title, "", "", theme)


def learning_curve(records: Sequence[dict], metric: str = "aer", iteration: int | None = None,
                   theme: str = "screen") -> go.Figure:
    """AER (Eq 4.1) or Performance (Eq 4.2) across iterations, with expert and random reference lines."""
    title = {"aer": "Average episodic reward", "performance": "Performance"}[metric]
    if not records:
        return _empty(title, "Press Step to train the first iteration", theme)
    xs = [r["iteration"] for r in records]
    ys = [r["evaluation"][metric] for r in records]
    fig = go.Figure()
    if metric == "aer":
        std = [r["evaluation"]["aer_std"] for r in records]
        fig.add_trace(go.Scatter(x=xs, y=ys, mode="lines+markers", name="learner",
                                 error_y=dict(type="data", array=std, visible=True, thickness=1),
                                 line=dict(color=COLORS[0], width=3)))
        ev = records[-1]["evaluation"]
        refs = [("expert", ev.get("expert_reference"), EXPERT_COLOR), ("random", ev.get("random_reference"), RANDOM_COLOR)]
    else:
        fig.add_trace(go.Scatter(x=xs, y=ys, mode="lines+markers", name="learner", line=dict(color=COLORS[0], width=3)))
        refs = [("expert", 1.0, EXPERT_COLOR), ("random", 0.0, RANDOM_COLOR)]
    for name, value, color in refs:
        if value is not None:
            fig.add_hline(y=value, line=dict(color=color, dash="dash"), annotation_text=name,
                          annotation_position="top left")
    if iteration is not None:
        fig.add_vline(x=iteration, line=dict(color="#444", dash="dot"))
    return _layout(fig, title, "iteration", "AER" if metric == "aer" else "P", theme)


def idm_predictions(records: Sequence[dict], action_names: Sequence[str], iteration: int | None = None,
                    theme: str = "screen") -> go.Figure:
    """Fig 5.2/6.2a at one iteration: what the IDM says the expert did, beside what it really did."""
    title = "IDM predictions on the expert's transitions"
    rec = _pick(records, iteration)
    if rec is None or "idm" not in rec:
        return _empty(title, "No IDM in this method (BC learns from the true actions)" if rec else
                      "Press Step to train the first iteration", theme)
    idm = rec["idm"]
    fig = go.Figure()
    total = max(1, sum(idm["prediction_counts"]))
    fig.add_trace(go.Bar(x=list(action_names), y=[c / total for c in idm["prediction_counts"]], name="IDM (MAP)",
                         marker_color=COLORS[0]))
    if "labels" in rec and rec["labels"]["sampled"]:
        fig.add_trace(go.Bar(x=list(action_names), y=[c / total for c in rec["labels"]["counts"]],
                             name="labels used (sampled)", marker_color=COLORS[1]))
    if "true_counts" in idm:
        fig.add_trace(go.Bar(x=list(action_names), y=[c / total for c in idm["true_counts"]],
                             name="expert's hidden true actions", marker_color=EXPERT_COLOR))
    fig.update_layout(barmode="group")
    fig.update_yaxes(range=[0, 1])
    return _layout(fig, f"{title} (iteration {rec['iteration']})", "action", "share of transitions", theme)


def idm_predictions_over_time(records: Sequence[dict], action_names: Sequence[str], theme: str = "screen") -> go.Figure:
    """Fig 5.2: the share of each predicted action across iterations (vanishing actions show up here)."""
    title = "IDM predictions through time"
    recs = [r for r in records if "idm" in r]
    if not recs:
        return _empty(title, "No IDM predictions yet", theme)
    xs = [r["iteration"] for r in recs]
    fig = go.Figure()
    for a, name in enumerate(action_names):
        share = [r["idm"]["prediction_counts"][a] / max(1, sum(r["idm"]["prediction_counts"])) for r in recs]
        fig.add_trace(go.Scatter(x=xs, y=share, mode="lines", stackgroup="pred", name=name,
                                 line=dict(color=COLORS[a % len(COLORS)])))
        if "true_counts" in recs[-1]["idm"]:
            true = recs[-1]["idm"]["true_counts"][a] / max(1, sum(recs[-1]["idm"]["true_counts"]))
            fig.add_trace(go.Scatter(x=[xs[0], xs[-1]], y=[true, true], mode="lines", showlegend=False,
                                     line=dict(color=COLORS[a % len(COLORS)], dash="dot", width=1),
                                     hovertext=f"true share of {name}"))
    fig.update_yaxes(range=[0, 1])
    return _layout(fig, title, "iteration", "share of expert transitions", theme)


def accuracy_curves(records: Sequence[dict], iteration: int | None = None, theme: str = "screen") -> go.Figure:
    """How right the labels are: IDM validation accuracy on I_pre, IDM and policy against the hidden truth."""
    title = "Accuracy"
    if not records:
        return _empty(title, "Press Step to train the first iteration", theme)
    xs = [r["iteration"] for r in records]
    series = [
        ("IDM on I_pre validation", lambda r: r.get("idm", {}).get("val_accuracy")),
        ("pseudo-labels vs hidden truth", lambda r: r.get("idm", {}).get("expert_accuracy")),
        ("policy agrees with its labels", lambda r: r["policy"].get("agreement")),
        ("policy vs hidden truth", lambda r: r["policy"].get("expert_accuracy")),
    ]
    fig = go.Figure()
    for k, (name, get) in enumerate(series):
        ys = [get(r) for r in records]
        if any(y is not None for y in ys):
            fig.add_trace(go.Scatter(x=xs, y=ys, mode="lines+markers", name=name, line=dict(color=COLORS[k])))
    if iteration is not None:
        fig.add_vline(x=iteration, line=dict(color="#444", dash="dot"))
    fig.update_yaxes(range=[0, 1.02])
    return _layout(fig, title, "iteration", "accuracy", theme)


def win_probability(records: Sequence[dict], iteration: int | None = None, theme: str = "screen") -> go.Figure:
    """P(g|E): the share of the policy's runs that met the goal (drives ABCO/IUPE sampling)."""
    title = "Win probability P(g|E)"
    recs = [r for r in records if "rollouts" in r]
    if not recs:
        return _empty(title, "This method does not run the policy between iterations", theme)
    fig = go.Figure(go.Scatter(x=[r["iteration"] for r in recs], y=[r["rollouts"]["win_probability"] for r in recs],
                               mode="lines+markers", name="runs that met the goal", line=dict(color=COLORS[2], width=3)))
    if iteration is not None:
        fig.add_vline(x=iteration, line=dict(color="#444", dash="dot"))
    fig.update_yaxes(range=[0, 1.02])
    return _layout(fig, title, "iteration", "P(g|E)", theme)


def exploration_rate(records: Sequence[dict], iteration: int | None = None, theme: str = "screen") -> go.Figure:
    """Fig 6.2b: share of choices that were not the MAP action, for labels and for rollout actions."""
    title = "Exploration rate"
    if not records:
        return _empty(title, "Press Step to train the first iteration", theme)
    xs = [r["iteration"] for r in records]
    fig = go.Figure()
    labels = [r.get("labels", {}).get("exploration_rate") for r in records]
    rolls = [r.get("rollouts", {}).get("exploration_rate") for r in records]
    if any(v is not None for v in labels):
        fig.add_trace(go.Scatter(x=xs, y=labels, mode="lines+markers", name="IDM labels", line=dict(color=COLORS[1])))
    if any(v is not None for v in rolls):
        fig.add_trace(go.Scatter(x=xs, y=rolls, mode="lines+markers", name="policy rollouts", line=dict(color=COLORS[4])))
    if iteration is not None:
        fig.add_vline(x=iteration, line=dict(color="#444", dash="dot"))
    return _layout(fig, title, "iteration", "share not MAP", theme)


def sampling_mixture(records: Sequence[dict], action_names: Sequence[str], iteration: int | None = None,
                     theme: str = "screen") -> go.Figure:
    """What the IDM trains on next: per action, samples drawn from I_pre and from I_pos."""
    title = "Sampling mixture of I_s"
    rec = _pick(records, iteration)
    if rec is None or "sampling" not in rec:
        return _empty(title, "This method does not rebuild I_s", theme)
    mix = rec["sampling"]
    fig = go.Figure([
        go.Bar(x=list(action_names), y=mix["from_pre"], name="from I_pre (random)", marker_color=RANDOM_COLOR),
        go.Bar(x=list(action_names), y=mix["from_pos"], name="from I_pos (policy runs)", marker_color=COLORS[0]),
    ])
    fig.update_layout(barmode="stack")
    return _layout(fig, f"{title} after iteration {rec['iteration']} ({mix['mode']})", "action", "samples", theme)


def phase_seconds(records: Sequence[dict], theme: str = "screen") -> go.Figure:
    title = "Where the time goes"
    if not records:
        return _empty(title, "No iteration yet", theme)
    xs = [r["iteration"] for r in records]
    phases = [p for p in ("idm", "label", "policy", "rollout", "sampling", "evaluate")
              if any(p in r["seconds"] for r in records)]
    fig = go.Figure([go.Bar(x=xs, y=[r["seconds"].get(p, 0) for r in records], name=p,
                            marker_color=COLORS[k % len(COLORS)]) for k, p in enumerate(phases)])
    fig.update_layout(barmode="stack")
    return _layout(fig, title, "iteration", "seconds", theme)


def compare_runs(runs: Sequence[tuple[str, Sequence[dict]]], metric: str = "performance",
                 theme: str = "screen") -> go.Figure:
    """Several runs' curves on shared axes."""
    title = {"aer": "Average episodic reward", "performance": "Performance"}[metric]
    fig = go.Figure()
    for k, (name, records) in enumerate(runs):
        fig.add_trace(go.Scatter(x=[r["iteration"] for r in records], y=[r["evaluation"][metric] for r in records],
                                 mode="lines+markers", name=name, line=dict(color=COLORS[k % len(COLORS)])))
    return _layout(fig, title, "iteration", metric, theme)
