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
    if x == "iteration":  # whole iterations only: no 1.5 ticks
        last = max((max(t.x) for t in fig.data if getattr(t, "x", None) is not None and len(t.x)), default=1)
        fig.update_xaxes(tick0=1, dtick=max(1, int(round(last / 10))))
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
    phases = [p for p in ("idm", "label", "policy", "attention", "rollout", "sampling", "evaluate")
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


# ----------------------------------------------------------------------------- attention (Sec 5.5.2, 6.4.1)
def _subplots(rows: int, cols: int, titles: Sequence[str], **kwargs):
    from plotly.subplots import make_subplots

    return make_subplots(rows=rows, cols=cols, subplot_titles=list(titles), **kwargs)


# jet with an alpha ramp: where the map is 0 the frame shows through untouched
CAM_COLORSCALE = [[0.0, "rgba(0,0,255,0)"], [0.25, "rgba(0,160,255,0.35)"], [0.5, "rgba(0,230,0,0.5)"],
                  [0.75, "rgba(255,210,0,0.65)"], [1.0, "rgba(230,0,0,0.8)"]]


def grad_cam_panel(records: Sequence[dict], iteration: int | None = None, theme: str = "screen",
                   frames=None, action_names: Sequence[str] | None = None) -> go.Figure:
    """Fig 6.1: the fixed probe frames (top row) and where the policy looks on each (bottom row).

    The bottom row is Grad-CAM of the policy's chosen action, from
    `record["attention"]["grad_cam"]`; with `frames` (uint8 (n, H, W, 3), e.g.
    `ifo.probes.maze_probe_frames`) the heatmap is laid over the frame. Each map is
    normalised on its own; the hover shows its raw peak to compare iterations.
    """
    title = "Where the policy looks (Grad-CAM)"
    rec = _pick(records, iteration)
    cam = (rec or {}).get("attention", {}).get("grad_cam") if rec else None
    if not cam or not cam.get("maps"):
        return _empty(title, "No Grad-CAM yet: it is drawn for image policies (the maze with image observations)"
                      if rec else "Press Step to train the first iteration", theme)
    maps = cam["maps"]
    n = len(maps)
    actions = cam.get("actions") or [None] * n
    probs = cam.get("probabilities") or [None] * n
    raw = cam.get("raw_max") or [None] * n
    probes = cam.get("probes") or [{}] * n
    has_frames = frames is not None and len(frames) >= n

    def action_label(k: int) -> str:
        a = actions[k]
        if a is None:
            return ""
        name = action_names[a] if action_names is not None and a < len(action_names) else str(a)
        p = probs[k][a] if probs[k] is not None else None
        return f"{name} ({p:.0%})" if p is not None else name

    top = [probes[k].get("kind", f"probe {k + 1}") if k < len(probes) else f"probe {k + 1}" for k in range(n)]
    bottom = [action_label(k) for k in range(n)]
    rows = 2 if has_frames else 1
    fig = _subplots(rows, n, (top + bottom) if has_frames else bottom, horizontal_spacing=0.02,
                    vertical_spacing=0.12)
    for k, m in enumerate(maps):
        res_y, res_x = len(m), len(m[0]) if m else 0
        heat = dict(z=m, zmin=0, zmax=1, colorscale=CAM_COLORSCALE if has_frames else "Jet", showscale=k == n - 1,
                    colorbar=dict(title="attention", len=0.5 if has_frames else 1, y=0.25 if has_frames else 0.5),
                    hovertemplate=f"row %{{y}}, col %{{x}}: %{{z:.2f}}<br>raw peak {raw[k]}<extra></extra>"
                    if raw[k] is not None else None)
        if has_frames:
            frame = frames[k]
            h, w = frame.shape[:2]
            fig.add_trace(go.Image(z=frame, hoverinfo="skip"), row=1, col=k + 1)
            fig.add_trace(go.Image(z=frame, hoverinfo="skip"), row=2, col=k + 1)
            # one map cell covers (h / res_y, w / res_x) pixels; image pixel i is centred at i
            fig.add_trace(go.Heatmap(**heat, x0=w / (2 * res_x) - 0.5, dx=w / res_x,
                                     y0=h / (2 * res_y) - 0.5, dy=h / res_y), row=2, col=k + 1)
        else:
            fig.add_trace(go.Heatmap(**heat), row=1, col=k + 1)
            fig.update_yaxes(autorange="reversed", row=1, col=k + 1)  # row 0 of the map is the image's top
    fig.update_xaxes(visible=False)
    fig.update_yaxes(visible=False)
    for k in range(1, rows * n + 1):  # square pixels: each y axis keeps the scale of its own x axis
        suffix = "" if k == 1 else str(k)
        fig.layout[f"yaxis{suffix}"].scaleanchor = f"x{suffix}"
    fig = _layout(fig, f"{title} (iteration {rec['iteration']})", "", "", theme)
    if theme != "slide":
        fig.update_layout(height=420 if has_frames else 260)
    return fig


def state_attention(records: Sequence[dict], feature_names: Sequence[str], iteration: int | None = None,
                    theme: str = "screen") -> go.Figure:
    """Attention over state variables (attention="features"): the mean weight each variable
    receives in the policy (inputs s) and in the IDM (inputs [s, s' - s], labelled x, Δx)."""
    title = "Attention over state variables"
    rec = _pick(records, iteration)
    if rec is None:
        return _empty(title, "Press Step to train the first iteration", theme)
    names = list(feature_names)
    panels = []
    pol = rec.get("policy", {}).get("attention")
    if pol:
        labels = names if len(names) == len(pol) else [f"s[{i}]" for i in range(len(pol))]
        panels.append(("policy π(a|s)", labels, pol))
    idm = rec.get("idm", {}).get("attention")
    if idm:
        if 2 * len(names) == len(idm):
            labels = names + [f"Δ{n}" for n in names]
        else:
            labels = [f"x[{i}]" for i in range(len(idm))]
        panels.append(("IDM M(a|s,s')", labels, idm))
    if not panels:
        return _empty(title, "No attention over state variables: choose attention = features "
                      "(vector observations)", theme)
    fig = _subplots(len(panels), 1, [p[0] for p in panels], vertical_spacing=0.25 if len(panels) > 1 else 0.1)
    for k, (name, labels, att) in enumerate(panels):
        fig.add_trace(go.Bar(x=labels, y=att, name=name, marker_color=COLORS[k], showlegend=False,
                             hovertemplate="%{x}: %{y:.3f}<extra></extra>"), row=k + 1, col=1)
        fig.add_hline(y=1 / len(att), line=dict(color=RANDOM_COLOR, dash="dot"), annotation_text="uniform",
                      annotation_position="top right", row=k + 1, col=1)
        fig.update_yaxes(title_text="attention", rangemode="tozero", row=k + 1, col=1)
    fig = _layout(fig, f"{title} (iteration {rec['iteration']})", "", "", theme)
    fig.update_yaxes(title_text="attention")
    return fig


def action_distance_curves(records: Sequence[dict], action_names: Sequence[str], theme: str = "screen") -> go.Figure:
    """Fig 5.3: per action, the L2 distance of the mean image of the policy's runs (I_pos) to the
    expert's, across iterations; 0 is the expert's mean image, 1 the random policy's (I_pre)."""
    title = "Distance of each action's mean image to the expert's"
    recs = [r for r in records if r.get("attention", {}).get("mean_image_distance")]
    if not recs:
        return _empty(title, "No image distances yet: they are measured on maze runs that run the policy "
                      "(ABCO, IUPE, BCO(α))" if records else "Press Step to train the first iteration", theme)
    xs = [r["iteration"] for r in recs]
    fig = go.Figure()
    for a, name in enumerate(action_names):
        ys = [(r["attention"]["mean_image_distance"]["distance"] + [None] * len(action_names))[a] for r in recs]
        fig.add_trace(go.Scatter(x=xs, y=ys, mode="lines+markers", name=name, connectgaps=False,
                                 line=dict(color=COLORS[a % len(COLORS)], width=2)))
    fig.add_hline(y=0, line=dict(color=EXPERT_COLOR, dash="dash"), annotation_text="expert",
                  annotation_position="top right")
    fig.add_hline(y=1, line=dict(color=RANDOM_COLOR, dash="dash"), annotation_text="random (I_pre)",
                  annotation_position="top right")
    fig.update_yaxes(rangemode="tozero")
    return _layout(fig, title, "iteration", "normalised L2 distance", theme)
