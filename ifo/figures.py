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
# 20 colours that stay apart (D3's ten, then ten of plotly's Dark24); past 20 runs the dash changes too
RUN_COLORS = COLORS + ["#bcbd22", "#17becf", "#222a2a", "#b68100", "#750d86", "#00a08b", "#fb00d1", "#6c7c32",
                       "#862a16", "#1616a7", "#778aae", "#af0038"]
DASHES = ["solid", "dash", "dot", "dashdot"]


def _layout(fig: go.Figure, title: str, x: str, y: str, theme: str = "screen") -> go.Figure:
    big = theme == "slide"
    # the white template only for slides: on screen Streamlit's theme replaces it, and setting it costs
    # ~25 ms a figure (plotly copies the whole template), a third of a second per page of panels
    fig.update_layout(
        title=dict(text=title, font=dict(size=30 if big else 16)),
        xaxis_title=x, yaxis_title=y, **({"template": "plotly_white"} if big else {}),
        font=dict(size=22 if big else 13), legend=dict(orientation="h", y=-0.2 if big else -0.25),
        margin=dict(l=60, r=20, t=60 if big else 45, b=60),
        **({"width": 1600, "height": 900} if big else {}),
    )
    if big:  # subplot titles and line labels too
        fig.update_annotations(font_size=22)
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


def _headroom(fig: go.Figure, theme: str, lines: int = 1) -> go.Figure:
    """A taller top margin so the title clears the subplot titles (`lines`: of the title)."""
    return fig.update_layout(margin_t=(60 if theme == "slide" else 40) + (40 if theme == "slide" else 25) * lines)


def _mark(fig: go.Figure, iteration: int | None, **where) -> go.Figure:
    """A dotted vertical line at the scrubbed iteration (`where`: row="all", col=1 on subplots)."""
    if iteration is not None:
        fig.add_vline(x=iteration, line=dict(color="#444", dash="dot"), **where)
    return fig


def _references(fig: go.Figure, refs) -> None:
    """Dashed horizontal lines for (name, value, colour); a None value draws nothing."""
    for name, value, color in refs:
        if value is not None:
            fig.add_hline(y=value, line=dict(color=color, dash="dash"), annotation_text=name,
                          annotation_position="top left")


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
    _references(fig, refs)
    _mark(fig, iteration)
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
    """Fig 5.2: the share of each predicted action across iterations (vanishing actions show up here).

    Stacked areas, one band per action; with a single iteration, one stacked bar. A dotted line of
    an action's colour marks where the top of its band would be if the IDM matched the expert's
    hidden true actions (its hover gives the true share).
    """
    title = "IDM predictions through time"
    recs = [r for r in records if "idm" in r]
    if not recs:
        return _empty(title, "No IDM predictions yet", theme)
    xs = [r["iteration"] for r in recs]
    one = len(recs) == 1  # a stacked area needs two x values: draw a bar instead

    def shares(counts):
        return [c / max(1, sum(counts)) for c in counts]

    pred = [shares(r["idm"]["prediction_counts"]) for r in recs]
    truth = [shares(r["idm"]["true_counts"]) if "true_counts" in r["idm"] else None for r in recs]
    fig = go.Figure()
    below = [0.0] * len(recs)  # the true shares of the actions drawn so far, stacked like the bands
    for a, name in enumerate(action_names):
        color = COLORS[a % len(COLORS)]
        ys = [p[a] for p in pred]
        hover = f"{name}: %{{y:.0%}} of the IDM's labels<extra></extra>"
        if one:
            fig.add_trace(go.Bar(x=xs, y=ys, name=name, marker_color=color, width=0.5, hovertemplate=hover))
        else:
            fig.add_trace(go.Scatter(x=xs, y=ys, mode="lines", stackgroup="pred", name=name,
                                     line=dict(color=color), hovertemplate=hover))
        if any(t is not None for t in truth):
            true = [t[a] if t is not None else None for t in truth]
            below = [b + t if b is not None and t is not None else None for b, t in zip(below, true)]
            line_x = [xs[0] - 0.3, xs[0] + 0.3] if one else xs  # across the bar, or along the bands
            line_y = below * 2 if one else below
            fig.add_trace(go.Scatter(x=line_x, y=line_y, mode="lines", showlegend=False, name=f"true {name}",
                                     line=dict(color=color, dash="dot", width=2),
                                     customdata=true * 2 if one else true,
                                     hovertemplate=f"true share of {name}: %{{customdata:.0%}}<extra></extra>"))
    if one:
        fig.update_layout(barmode="stack")
        fig.update_xaxes(range=[xs[0] - 1, xs[0] + 1])
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
        ("policy agrees with its labels", lambda r: r.get("policy", {}).get("agreement")),
        ("policy vs hidden truth", lambda r: r.get("policy", {}).get("expert_accuracy")),
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
    peak = max((v for v in labels + rolls if v is not None), default=0.0)
    fig.update_yaxes(range=[0, min(1.02, max(0.05, 1.15 * peak))])  # from 0, never a sliver around one value
    _mark(fig, iteration)
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
                 theme: str = "screen", references: dict | None = None) -> go.Figure:
    """Several runs' curves on shared axes (Eqs 4.1, 4.2), with the expert's and a random policy's level:
    `references={"expert": float, "random": float}` for "aer"; always 1 and 0 for "performance".
    Colours repeat only after 20 runs, and then with another dash pattern."""
    title = {"aer": "Average episodic reward", "performance": "Performance"}[metric]
    runs = [(name, records) for name, records in runs if records]
    if not runs:
        return _empty(title, "Curves appear after each run's first iteration", theme)
    fig = go.Figure()
    for k, (name, records) in enumerate(runs):
        style = dict(color=RUN_COLORS[k % len(RUN_COLORS)], dash=DASHES[(k // len(RUN_COLORS)) % len(DASHES)])
        fig.add_trace(go.Scatter(x=[r["iteration"] for r in records],
                                 y=[r.get("evaluation", {}).get(metric) for r in records],
                                 mode="lines+markers", name=name, line=style))
    refs = references or {}
    if metric == "performance":
        refs = {"expert": 1.0, "random": 0.0}
    _references(fig, [("expert", refs.get("expert"), EXPERT_COLOR), ("random", refs.get("random"), RANDOM_COLOR)])
    return _layout(fig, title, "iteration", "AER" if metric == "aer" else "P", theme)


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


# ----------------------------------------------------------------------------- the IDM up close (Ch. 5, 6)
def _labels(action_names: Sequence[str] | None, n: int) -> list[str]:
    """The action names when they fit `n` actions, else "action 0", "action 1", ..."""
    names = list(action_names or [])
    return names[:n] if len(names) >= n else [f"action {a}" for a in range(n)]


def _no_idm(rec: dict | None, what: str) -> str | None:
    """Why an IDM figure has nothing to draw for this record (None: it has `what`)."""
    if rec is None:
        return "Press Step to train the first iteration"
    if "idm" not in rec:
        return "No IDM in this method (BC learns from the true actions)"
    if rec["idm"].get(what) is None:
        return "This needs the expert's hidden true actions, which this run did not record"
    return None


def idm_confusion(records: Sequence[dict], action_names: Sequence[str], iteration: int | None = None,
                  theme: str = "screen") -> go.Figure:
    """Which action the IDM names for what the expert really did (the detail behind Figs 5.2, 6.2a).

    Rows are the expert's hidden true actions, columns the IDM's MAP labels; each cell shows its
    count and its share of the row, and is coloured by that share (the diagonal is what it got right).
    """
    title = "The IDM's labels against the truth"
    rec = _pick(records, iteration)
    why = _no_idm(rec, "confusion")
    if why:
        return _empty(title, why, theme)
    counts = rec["idm"]["confusion"]
    names = _labels(action_names, len(counts))
    shares = [[c / max(1, sum(row)) for c in row] for row in counts]
    text = [[f"{c}<br>{s:.0%}" for c, s in zip(row, srow)] for row, srow in zip(counts, shares)]
    fig = go.Figure(go.Heatmap(z=shares, x=names, y=names, zmin=0, zmax=1, colorscale="Blues", text=text,
                               texttemplate="%{text}", colorbar=dict(title="share of row"),
                               hovertemplate="true %{y}, labelled %{x}: %{text}<extra></extra>"))
    fig.update_yaxes(autorange="reversed")  # first action on top, as a table reads
    right = sum(counts[a][a] for a in range(min(len(counts), len(counts[0]) if counts else 0)))
    total = max(1, sum(map(sum, counts)))
    return _layout(fig, f"{title} (iteration {rec['iteration']}: {right / total:.0%} right)", "IDM's label",
                   "expert's true action (hidden from the learner)", theme)


def idm_confidence(records: Sequence[dict], action_names: Sequence[str], iteration: int | None = None,
                   theme: str = "screen") -> go.Figure:
    """How sure the IDM is on the expert's transitions (Sec 6.2: what sampled labels explore).

    Over 10 probability bins: the probability of its MAP action on each expert pair and, when the
    hidden truth was recorded, the probability it gives the expert's true action.
    """
    title = "How sure the IDM is"
    rec = _pick(records, iteration)
    why = _no_idm(rec, "confidence_histogram")
    if why:
        return _empty(title, "No confidence recorded for this iteration" if why.startswith("This needs") else why,
                      theme)
    idm = rec["idm"]
    series = [("its most likely action", idm["confidence_histogram"], COLORS[0]),
              ("the expert's true action", idm.get("true_action_probability_histogram"), EXPERT_COLOR)]
    fig = go.Figure()
    for name, counts, color in series:
        if counts is not None:
            centres = [(b + 0.5) / len(counts) for b in range(len(counts))]
            fig.add_trace(go.Bar(x=centres, y=counts, name=name, marker_color=color,
                                 hovertemplate="probability near %{x:.2f}: %{y} transitions<extra></extra>"))
    if action_names:
        fig.add_vline(x=1 / len(action_names), line=dict(color=RANDOM_COLOR, dash="dot"),
                      annotation_text="a uniform guess", annotation_position="top right")
    fig.update_layout(barmode="group", bargap=0.1)
    fig.update_xaxes(range=[0, 1], tick0=0, dtick=0.1, tickformat=".0%")
    return _layout(fig, f"{title} (iteration {rec['iteration']})", "probability the IDM gives",
                   "expert transitions", theme)


# ----------------------------------------------------------------------------- charts by iteration
def _series(records: Sequence[dict], section: str, key: str) -> list:
    return [r.get(section, {}).get(key) for r in records]


def _line(xs, ys, name: str, color: str, **kwargs) -> go.Scatter | None:
    """A lines+markers trace (markers: visible from the first iteration), or None when every value is missing."""
    if all(y is None for y in ys):
        return None
    return go.Scatter(x=xs, y=ys, mode="lines+markers", name=name, line=dict(color=color, **kwargs))


def _over_iterations(title: str, panels, iteration: int | None, theme: str, message: str) -> go.Figure:
    """Charts stacked over one shared iteration axis. `panels`: (subtitle, y label, traces, y range or None,
    horizontal lines [(y, label)]); a panel whose traces are all None is left out."""
    panels = [(sub, ylab, [t for t in traces if t is not None], yrange, lines)
              for sub, ylab, traces, yrange, lines in panels]
    panels = [p for p in panels if p[2]]
    if not panels:
        return _empty(title, message, theme)
    fig = _subplots(len(panels), 1, [p[0] for p in panels], shared_xaxes=True, vertical_spacing=0.12)
    for row, (_, _, traces, _, lines) in enumerate(panels, 1):
        for t in traces:
            fig.add_trace(t, row=row, col=1)
        for y, label in lines:
            fig.add_hline(y=y, line=dict(color=RANDOM_COLOR, dash="dash"), annotation_text=label,
                          annotation_position="top left", row=row, col=1)
    _mark(fig, iteration, row="all", col=1)
    fig = _layout(fig, title, "iteration", "", theme)
    for row, (_, ylab, _, yrange, _) in enumerate(panels, 1):
        fig.update_yaxes(title_text=ylab, range=yrange, row=row, col=1)
    fig.update_xaxes(title_text=None)
    fig.update_xaxes(title_text="iteration", row=len(panels), col=1)
    if theme != "slide":  # 200 px a chart; the legend just under the last axis title
        fig.update_layout(height=160 + 200 * len(panels), legend_y=-80 / (200 * len(panels)))
    return _headroom(fig, theme)


def attention_gates(records: Sequence[dict], iteration: int | None = None, theme: str = "screen") -> go.Figure:
    """The gated attention blocks (Sec 5.3's self-attention on vectors): each block computes
    x + gamma * (W_v x + b) with gamma starting at 0, so gamma says how much attention the model lets in;
    "effect" is the size of gamma * (W_v x + b) relative to x on the expert's states."""
    title = "How much the attention blocks change the input"
    models = [("policy", "policy", COLORS[0]), ("idm", "IDM", COLORS[1])]
    gamma, effect = [], []
    for key, label, color in models:
        recs = [r for r in records if r.get(key, {}).get("gates")]
        blocks = sorted({g["block"] for r in recs for g in r[key]["gates"]})
        for k, block in enumerate(blocks):
            rows = [(r["iteration"], g) for r in recs for g in r[key]["gates"] if g["block"] == block]
            xs = [x for x, _ in rows]
            style = dict(color=color, dash=DASHES[k % len(DASHES)])
            name = f"{label}, block {block}"
            gamma.append(go.Scatter(x=xs, y=[g["gamma"] for _, g in rows], mode="lines+markers", name=name,
                                    legendgroup=name, line=style))
            effect.append(go.Scatter(x=xs, y=[g["effect"] for _, g in rows], mode="lines+markers", name=name,
                                     legendgroup=name, showlegend=False, line=style))
    return _over_iterations(title, [
        ("gamma: how much attention is let in (starts at 0)", "gamma", gamma, None, [(0, "no attention")]),
        ("its effect on the expert's states, relative to the input", "relative size", effect, None, []),
    ], iteration, theme, "No gated attention blocks: choose attention = gated")


def td_curves(records: Sequence[dict], iteration: int | None = None, theme: str = "screen") -> go.Figure:
    """CRIL's temporal-difference updates (Ch. 8, Fig 8.1): their loss, the exploration ratio epsilon
    of its epsilon-greedy runs, and the band of Q-values from the smallest to the largest."""
    title = "Learning from its own rewards (temporal-difference updates)"
    recs = [r for r in records if "td" in r]
    xs = [r["iteration"] for r in recs]
    q_min, q_max = _series(recs, "td", "q_min"), _series(recs, "td", "q_max")
    band = []
    if any(v is not None for v in q_max + q_min):
        band = [go.Scatter(x=xs, y=q_max, mode="lines+markers", name="largest Q-value", line=dict(color=COLORS[0])),
                go.Scatter(x=xs, y=q_min, mode="lines+markers", name="smallest Q-value", fill="tonexty",
                           fillcolor="rgba(31,119,180,0.2)", line=dict(color=COLORS[0], dash="dot"))]
    return _over_iterations(title, [
        ("temporal-difference loss", "loss", [_line(xs, _series(recs, "td", "loss"), "TD loss", COLORS[3])],
         None, []),
        ("epsilon: share of random actions in its runs", "epsilon",
         [_line(xs, _series(recs, "td", "epsilon"), "epsilon", COLORS[4])], [0, 1.02], []),
        ("Q-values, smallest to largest", "Q-value", band, None, []),
    ], iteration, theme, "No temporal-difference updates: only CRIL learns from its own rewards")


def discriminator_curves(records: Sequence[dict], iteration: int | None = None, theme: str = "screen") -> go.Figure:
    """An adversarial learner's discriminator D (GAIL, GAIfO, SAIL; Ch. 9): how often it is right on
    expert and on agent samples (50%: it cannot tell them apart), its loss, and, when present, the share
    of the policy's episodes it accepts (SAIL) and the mean learned reward (GAIL/GAIfO)."""
    title = "Can the discriminator tell the expert from the learner?"
    recs = [r for r in records if "discriminator" in r]
    xs = [r["iteration"] for r in recs]

    def get(key):
        return _series(recs, "discriminator", key)

    return _over_iterations(title, [
        ("how often it is right", "accuracy",
         [_line(xs, get("accuracy_expert"), "on expert samples", EXPERT_COLOR),
          _line(xs, get("accuracy_agent"), "on the learner's samples", COLORS[0])],
         [0, 1.02], [(0.5, "cannot tell them apart")]),
        ("its loss", "loss", [_line(xs, get("loss"), "discriminator loss", COLORS[3])], None, []),
        ("share of the policy's episodes it accepts", "share",
         [_line(xs, get("accepted_share"), "accepted episodes", COLORS[1])], [0, 1.02], []),
        ("mean learned reward of the learner's samples", "reward",
         [_line(xs, get("mean_reward"), "mean reward", COLORS[4])], None, []),
    ], iteration, theme, "No discriminator: only the adversarial methods (GAIL, GAIfO, SAIL) train one")


def generator_loss(records: Sequence[dict], iteration: int | None = None, theme: str = "screen") -> go.Figure:
    """The generator (the policy) of an adversarial learner (Ch. 9): its loss (SAIL's G of Eq 9.2, or
    PPO's loss for GAIL/GAIfO) and, when present, the value loss and the policy's entropy."""
    title = "Training the generator (the policy)"
    recs = [r for r in records if "generator" in r]
    xs = [r["iteration"] for r in recs]
    return _over_iterations(title, [
        ("generator loss", "loss", [_line(xs, _series(recs, "generator", "loss"), "loss", COLORS[0])], None, []),
        ("value loss", "loss", [_line(xs, _series(recs, "generator", "value_loss"), "value loss", COLORS[1])],
         None, []),
        ("entropy: how spread its choices are", "entropy",
         [_line(xs, _series(recs, "generator", "entropy"), "entropy", COLORS[2])], None, []),
    ], iteration, theme, "No generator: only the adversarial methods (GAIL, GAIfO, SAIL) train one")


def replay_fill(records: Sequence[dict], iteration: int | None = None, theme: str = "screen") -> go.Figure:
    """CRIL's replay memory (Ch. 8): how many of its own transitions it keeps, against its capacity."""
    title = "Replay memory filling up"
    recs = [r for r in records if "replay" in r]
    if not recs:
        return _empty(title, "No replay memory: only CRIL keeps one", theme)
    xs = [r["iteration"] for r in recs]
    fig = go.Figure([t for t in (
        _line(xs, _series(recs, "replay", "size"), "transitions stored", COLORS[0], width=3),
        _line(xs, _series(recs, "replay", "capacity"), "capacity", RANDOM_COLOR, dash="dash"),
    ) if t is not None])
    fig.update_yaxes(rangemode="tozero")
    _mark(fig, iteration)
    return _layout(fig, title, "iteration", "transitions", theme)


def sample_count(records: Sequence[dict], iteration: int | None = None, theme: str = "screen") -> go.Figure:
    """The thesis's sample count (Table 8.3): environment steps plus expert samples consumed so far."""
    title = "Samples used so far"
    recs = [r for r in records if "samples" in r]
    if not recs:
        return _empty(title, "This method does not count its samples", theme)
    xs = [r["iteration"] for r in recs]
    fig = go.Figure([
        go.Bar(x=xs, y=[v or 0 for v in _series(recs, "samples", "expert_samples")], name="expert samples",
               marker_color=EXPERT_COLOR),
        go.Bar(x=xs, y=[v or 0 for v in _series(recs, "samples", "environment_steps")], name="environment steps",
               marker_color=COLORS[0]),
    ])
    fig.update_layout(barmode="stack")
    rec = _pick(recs, iteration) if iteration in xs else recs[-1]
    total = sum(rec["samples"].get(k) or 0 for k in ("expert_samples", "environment_steps"))
    _mark(fig, iteration)
    return _layout(fig, f"{title} (iteration {rec['iteration']}: {total:,} in all)", "iteration", "samples", theme)


def sampling_share(records: Sequence[dict], iteration: int | None = None, theme: str = "screen") -> go.Figure:
    """How much of I_s comes from the policy's own runs I_pos (Eqs 5.3-5.5): the share asked for, the share
    realised, and CRIL's cap on it (Eq 8.2)."""
    title = "Share of I_s from the policy's own runs"
    recs = [r for r in records if "sampling" in r]
    xs = [r["iteration"] for r in recs]
    traces = [t for t in (
        _line(xs, _series(recs, "sampling", "target_share"), "share asked for", COLORS[0], width=3),
        _line(xs, _series(recs, "sampling", "realised_share"), "share realised", COLORS[1]),
        _line(xs, _series(recs, "sampling", "cap"), "upper limit (cap)", RANDOM_COLOR, dash="dash"),
    ) if t is not None]
    if not traces:
        return _empty(title, "This method does not mix I_pos into I_s", theme)
    fig = go.Figure(traces)
    fig.update_yaxes(range=[0, 1.02], tickformat=".0%")
    _mark(fig, iteration)
    return _layout(fig, title, "iteration", "share from I_pos", theme)


# ----------------------------------------------------------------------------- one iteration's maps
def latent_actions(records: Sequence[dict], iteration: int | None = None, action_names: Sequence[str] | None = None,
                   theme: str = "screen") -> go.Figure:
    """ILPO's latent actions: how many expert pairs each latent action explains best, and how they
    were remapped to real actions (latent x real action counts)."""
    title = "ILPO's latent actions"
    rec = _pick(records, iteration)
    if rec is None or "latent" not in rec:
        return _empty(title, "No latent actions: only ILPO learns them" if rec else
                      "Press Step to train the first iteration", theme)
    lat = rec["latent"]
    counts, remap = lat.get("assignment_counts") or [], lat.get("remap")
    latent = [f"z{k}" for k in range(max(len(counts), len(remap or [])))]
    fig = _subplots(1, 2 if remap else 1, ["expert pairs each latent action explains best"]
                    + (["which real action each latent action became"] if remap else []), horizontal_spacing=0.15)
    fig.add_trace(go.Bar(x=latent[:len(counts)], y=counts, name="expert pairs", marker_color=COLORS[0],
                         showlegend=False), row=1, col=1)
    if remap:
        real = _labels(action_names, len(remap[0]))
        fig.add_trace(go.Heatmap(z=remap, x=real, y=latent[:len(remap)], colorscale="Blues", text=remap,
                                 texttemplate="%{text}", colorbar=dict(title="count"),
                                 hovertemplate="%{y} -> %{x}: %{z}<extra></extra>"), row=1, col=2)
        fig.update_yaxes(autorange="reversed", title_text="latent action", row=1, col=2)
        fig.update_xaxes(title_text="real action", row=1, col=2)
    error = lat.get("forward_error")
    suffix = f"; forward model error {error:.3g}" if error is not None else ""
    fig = _layout(fig, f"{title} (iteration {rec['iteration']}{suffix})", "latent action", "expert pairs", theme)
    return _headroom(fig, theme)


def _blend(color: str, weight: float) -> str:
    """`color` (#rrggbb) mixed with white: weight 1 is the colour, 0 white."""
    rgb = [int(color[i:i + 2], 16) for i in (1, 3, 5)]
    return "rgb({},{},{})".format(*(round(255 + weight * (c - 255)) for c in rgb))


def policy_map(records: Sequence[dict], iteration: int | None = None, action_names: Sequence[str] | None = None,
               theme: str = "screen") -> go.Figure:
    """Figs 8.2, 8.3 (Table 8.1): the policy's most likely action over a grid of two state variables,
    its colour pale where the policy is unsure (the probability is in the hover), beside a reference
    policy's most likely action when recorded; the KL divergences from the reference in the title."""
    title = "The policy's choice over the state space"
    rec = _pick(records, iteration)
    pm = (rec or {}).get("policy_map")
    if not pm or not pm.get("action"):
        return _empty(title, "No policy map: it is drawn for environments with two state variables to grid"
                      if rec else "Press Step to train the first iteration", theme)
    ref = pm.get("reference_action")
    n = max(len(action_names or []), 1 + max(max(map(max, m)) for m in (pm["action"], ref) if m))
    names = _labels(action_names, n)
    # one colour per action, from pale (probability 0) to full (probability 1): z = action + probability
    scale = []
    for a in range(n):
        color = RUN_COLORS[a % len(RUN_COLORS)]
        scale += [[a / n, _blend(color, 0.15)], [(a + 1) / n, color]]
    probability = pm.get("probability") or [[1.0] * len(row) for row in pm["action"]]
    fig = _subplots(1, 2 if ref else 1, ["policy"] + (["reference policy"] if ref else []), horizontal_spacing=0.08)
    maps = [(pm["action"], probability)] + ([(ref, [[1.0] * len(row) for row in ref])] if ref else [])
    for col, (action, prob) in enumerate(maps, 1):
        z = [[a + 0.999 * p for a, p in zip(ra, rp)] for ra, rp in zip(action, prob)]
        hover = [[[names[a], p] for a, p in zip(ra, rp)] for ra, rp in zip(action, prob)]
        fig.add_trace(go.Heatmap(
            z=z, x=pm["x"], y=pm["y"], zmin=0, zmax=n, colorscale=scale, customdata=hover, showscale=col == 1,
            colorbar=dict(title="action (pale: unsure)", tickvals=[a + 0.5 for a in range(n)], ticktext=names),
            hovertemplate=f"{pm.get('x_name', 'x')} %{{x:.3g}}, {pm.get('y_name', 'y')} %{{y:.3g}}: "
                          "%{customdata[0]}" + (" (%{customdata[1]:.0%})" if col == 1 else "") + "<extra></extra>",
        ), row=1, col=col)
    kls = [f"{label} {pm[key]:.3g}" for key, label in (("kl", "KL from the reference"), ("onehot_kl", "one-hot KL"))
           if pm.get(key) is not None]
    if ref:
        same = sum(a == b for ra, rb in zip(pm["action"], ref) for a, b in zip(ra, rb))
        kls.append(f"same action on {same / max(1, sum(map(len, ref))):.0%} of the grid")
    fig = _layout(fig, f"{title} (iteration {rec['iteration']})" + (f"<br><sup>{', '.join(kls)}</sup>" if kls else ""),
                  pm.get("x_name", "x"), pm.get("y_name", "y"), theme)
    fig.update_xaxes(title_text=pm.get("x_name", "x"))
    return _headroom(fig, theme, lines=2 if kls else 1)


# ----------------------------------------------------------------------------- resilience (Ch. 7, Fig 7.1)
RESILIENCE_METRICS = {"aer": "AER", "performance": "P (against this expert)",
                      "performance_expert1": "P against Expert¹", "fidelity": "fidelity (0 = the expert's states)"}


def resilience_curves(results: Sequence[dict], env: str, theme: str = "screen", metric: str = "aer",
                      thesis: dict | None = None, colors_by: Sequence[str] | None = None) -> go.Figure:
    """Thesis Fig 7.1: each method's result against the expert's AER, one line per method over the expert
    levels (mean over seeds, bars one sd), for one environment.

    `results`: flat dicts with env, method, level, expert_aer and the metric (aer, performance,
    performance_expert1 or fidelity); rows whose method is "Random" or "Expert..." are references: the
    expert is drawn as the line y = x (AER), the random policy as a dashed level. `thesis`: method -> list
    of (expert AER, agent AER) drawn dotted, for comparison (AER only). `colors_by`: every method that may
    appear, in order, so a method keeps its colour when a budget or a choice leaves others out."""
    if metric not in RESILIENCE_METRICS:
        raise ValueError(f"metric must be one of {', '.join(RESILIENCE_METRICS)}, got {metric!r}")
    import numpy as np

    from ifo.metrics import sample_sd

    # the axis says what the metric means; the title stays short enough for half a page
    title = f"{RESILIENCE_METRICS[metric].split(' (')[0]} against the expert's AER ({env})"
    mine = [r for r in results if r.get("env") == env and r.get("expert_aer") is not None]
    learners = [r for r in mine if r.get("method") != "Random" and not str(r.get("method", "")).startswith("Expert")]
    if not learners:
        return _empty(title, "No results for this environment yet", theme)
    fig = go.Figure()
    xs = sorted({float(r["expert_aer"]) for r in mine})
    if metric == "aer":  # the expert itself, y = x (thesis Fig 7.1's blue line), under the methods' lines
        fig.add_trace(go.Scatter(x=xs, y=xs, mode="lines+markers", name="expert",
                                 line=dict(color=COLORS[0], width=2, dash="dash"), marker=dict(size=5)))
    methods = list(dict.fromkeys(r["method"] for r in learners))
    palette = list(colors_by or []) + [m for m in methods if m not in (colors_by or [])]
    for method in methods:
        by_level: dict[int, list[dict]] = {}
        for r in learners:
            if r["method"] == method and r.get(metric) is not None and np.isfinite(r[metric]):
                by_level.setdefault(int(r["level"]), []).append(r)
        points = sorted((float(np.mean([r["expert_aer"] for r in rs])), float(np.mean([r[metric] for r in rs])),
                         sample_sd([r[metric] for r in rs]), level, len(rs)) for level, rs in by_level.items())
        if not points:
            continue
        color = COLORS[(palette.index(method) + 1) % len(COLORS)]
        fig.add_trace(go.Scatter(
            x=[p[0] for p in points], y=[p[1] for p in points], mode="lines+markers", name=method,
            line=dict(color=color), error_y=dict(type="data", array=[p[2] for p in points], visible=True),
            customdata=[[f"Expert level {p[3]}", p[4]] for p in points],
            hovertemplate=f"{method}<br>%{{customdata[0]}} (AER %{{x:.1f}})<br>{RESILIENCE_METRICS[metric]} "
                          "%{y:.3f} over %{customdata[1]} run(s)<extra></extra>"))
        if thesis and metric == "aer" and thesis.get(method):
            tx, ty = zip(*sorted(thesis[method]))
            fig.add_trace(go.Scatter(x=list(tx), y=list(ty), mode="lines+markers", name=f"{method} (thesis)",
                                     line=dict(color=color, dash="dot"), marker=dict(symbol="x"), opacity=0.6))
    if metric == "aer":
        randoms = [r["aer"] for r in results
                   if r.get("env") == env and r.get("method") == "Random" and r.get("aer") is not None]
        _references(fig, [("random", float(np.mean(randoms)) if randoms else None, RANDOM_COLOR)])
    elif metric == "performance":
        _references(fig, [("this expert", 1.0, EXPERT_COLOR), ("random", 0.0, RANDOM_COLOR)])
    elif metric == "performance_expert1":
        _references(fig, [("Expert¹", 1.0, EXPERT_COLOR), ("random", 0.0, RANDOM_COLOR)])
    return _layout(fig, title, "expert's AER (its level's demonstrations)", RESILIENCE_METRICS[metric], theme)
