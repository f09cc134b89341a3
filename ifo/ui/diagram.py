"""The BCO loop as a picture: I_pre -> I_s -> IDM -> labels -> policy -> rollouts -> sampling -> I_s.

`loop_diagram(record, active_phase)` is a pure function (a record in, a plotly Figure out),
drawn with shapes and annotations so it stays sharp on a projector. The box of the phase
being trained is filled; the arrows carry the sizes of the data flowing between the
boxes at that iteration: |I_pre|, |I_s| and its split between I_pre and I_pos, |T_e|,
the |E| policy runs and their win probability P(g|E).
"""
from __future__ import annotations

import plotly.graph_objects as go

ACTIVE, IDLE, OFF = "#ff7f0e", "#eaf2fb", "#f2f2f2"
EDGE, TEXT, MUTED = "#1f4e79", "#111111", "#9a9a9a"

# box name -> (x, y, title); two rows of boxes, the loop runs clockwise
BOXES = {
    "pre": (1.1, 3.6, "I_pre"),
    "is": (4.1, 3.6, "I_s"),
    "idm": (7.1, 3.6, "IDM  M(a | s, s')"),
    "label": (10.1, 3.6, "labels  â"),
    "te": (13.1, 3.6, "T_e"),
    "sampling": (4.1, 1.2, "sampling"),
    "rollout": (7.1, 1.2, "rollouts"),
    "policy": (10.1, 1.2, "policy  π(a | s)"),
    "evaluate": (13.1, 1.2, "evaluation"),
}
W, H = 2.2, 1.1  # box size
PHASE_BOX = {"evaluate": "evaluate"}  # the learner's phases say which box they light up


def _n(v) -> str:
    return "?" if v is None else f"{int(v):,}"


def _texts(record: dict | None, pre_size: int | None, expert_size: int | None) -> tuple[dict, dict, set]:
    """Lines under each box's title, labels of the arrows, and the boxes this method does not use."""
    r = record or {}
    idm, labels, ro, mix, ev = (r.get(k) or {} for k in ("idm", "labels", "rollouts", "sampling", "evaluation"))
    te = expert_size if expert_size is not None else (sum(idm["prediction_counts"]) if idm.get("prediction_counts")
                                                       else None)
    perf = ev.get("performance")
    lines = {
        "pre": ["random (s, a, s')", f"|I_pre| = {_n(pre_size)}"],
        "is": ["the IDM's data", f"|I_s| = {_n(idm.get('train_size'))}"],
        "idm": ["guesses the action", f"{idm['expert_accuracy']:.0%} right on T_e"
                if idm.get("expert_accuracy") is not None else "between two states"],
        "te": ["expert (s, s'), no a", f"|T_e| = {_n(te)}"],
        "label": ["sampled (explore)" if labels.get("sampled") else "MAP (most likely)",
                  f"not MAP: {labels['exploration_rate']:.0%}" if labels.get("exploration_rate") is not None
                  else ""],
        "policy": ["copies the labels", f"agrees {r['policy']['agreement']:.0%}"
                   if r.get("policy", {}).get("agreement") is not None else ""],
        "rollout": [f"|E| = {_n(len(ro['returns']))} runs" if ro.get("returns") is not None else "|E| runs of π",
                    f"P(g|E) = {ro['win_probability']:.0%}" if "win_probability" in ro else "P(g|E) = ?"],
        "sampling": [f"mode: {mix['mode']}" if mix.get("mode") else "builds the next I_s",
                     f"I_pre {_n(sum(mix['from_pre']))} + I_pos {_n(sum(mix['from_pos']))}" if mix else ""],
        "evaluate": [f"AER {ev['aer']:.2f}" if ev.get("aer") is not None else "AER (Eq 4.1)",
                     f"P {perf:.2f}" if perf is not None else "P (Eq 4.2)"],
    }
    arrows = {
        ("pre", "is"): "at first",
        ("label", "policy"): f"{_n(te)} (s, â)" if te is not None else "(s, â)",
        ("rollout", "sampling"): f"I_pos {_n(ro.get('transitions'))}" if ro else "I_pos",
        ("sampling", "is"): f"next |I_s| = {_n(mix.get('size'))}" if mix else "next I_s",
    }
    off = set()
    if record is not None and not idm:
        off |= {"pre", "is", "idm", "label", "sampling", "rollout"}  # BC: the true actions, no IDM
    elif record is not None and not ro:
        off |= {"rollout", "sampling"}  # a single pass (BCO)
    return lines, arrows, off


def _border(x: float, y: float, tx: float, ty: float) -> tuple[float, float]:
    """Where the segment from a box's centre (x, y) towards (tx, ty) leaves the box."""
    dx, dy = tx - x, ty - y
    if abs(dx) * H >= abs(dy) * W:
        return x + (W / 2 if dx > 0 else -W / 2), y + dy * (W / 2) / abs(dx)
    return x + dx * (H / 2) / abs(dy), y + (H / 2 if dy > 0 else -H / 2)


def _edge(fig: go.Figure, a: str, b: str, label: str = "", off: bool = False, size: int = 13) -> None:
    (x0, y0, _), (x1, y1, _) = BOXES[a], BOXES[b]
    sx, sy = _border(x0, y0, x1, y1)
    ex, ey = _border(x1, y1, x0, y0)
    color = MUTED if off else EDGE
    fig.add_annotation(x=ex, y=ey, ax=sx, ay=sy, xref="x", yref="y", axref="x", ayref="y", text="",
                       showarrow=True, arrowhead=3, arrowsize=1.3, arrowwidth=2.5, arrowcolor=color)
    if not label:
        return
    if abs(ex - sx) < abs(ey - sy):  # vertical: beside the arrow
        fig.add_annotation(x=(sx + ex) / 2, y=(sy + ey) / 2, text=label, showarrow=False, xanchor="left", xshift=6,
                           font=dict(size=size, color=color))
    else:  # horizontal: outside the row of boxes, so long labels never cover a box
        top = y0 > 2.4
        fig.add_annotation(x=(sx + ex) / 2, y=y0 + (H / 2 + 0.05) * (1 if top else -1), text=label,
                           showarrow=False, yanchor="bottom" if top else "top", font=dict(size=size, color=color))


def loop_diagram(record: dict | None, active_phase: str | None = None, pre_size: int | None = None,
                 expert_size: int | None = None, theme: str = "screen", phase_boxes: dict | None = None,
                 doing: str | None = None) -> go.Figure:
    """The loop at one iteration (`record`, None before the first), with `active_phase`'s box
    highlighted (`phase_boxes`: the learner's phase -> box; `doing`: what that phase does, in words).
    `pre_size` (|I_pre|) and `expert_size` (|T_e|) come from the run when known."""
    lines, arrows, off = _texts(record, pre_size, expert_size)
    active = {**PHASE_BOX, **(phase_boxes or {})}.get(active_phase) if active_phase else None
    big = theme == "slide"
    fig = go.Figure()
    for name, (x, y, title) in BOXES.items():
        is_active = name == active
        fill = ACTIVE if is_active else (OFF if name in off else IDLE)
        fig.add_shape(type="rect", x0=x - W / 2, x1=x + W / 2, y0=y - H / 2, y1=y + H / 2, layer="below",
                      line=dict(color=ACTIVE if is_active else (MUTED if name in off else EDGE),
                                width=4 if is_active else 2), fillcolor=fill)
        color = "white" if is_active else (MUTED if name in off else TEXT)
        body = "<br>".join(t for t in lines[name] if t)
        fig.add_annotation(x=x, y=y, text=f"<b>{title}</b><br>{body}", showarrow=False, align="center",
                           font=dict(size=20 if big else 14, color=color))
    size = 18 if big else 13
    _edge(fig, "pre", "is", arrows[("pre", "is")], off="pre" in off, size=size)
    _edge(fig, "is", "idm", "train", off="idm" in off, size=size)
    _edge(fig, "idm", "label", "label", off="idm" in off, size=size)
    _edge(fig, "te", "label", "", off="label" in off, size=size)
    _edge(fig, "label", "policy", arrows[("label", "policy")], size=size)
    _edge(fig, "policy", "evaluate", "", size=size)
    _edge(fig, "policy", "rollout", "run π", off="rollout" in off, size=size)
    _edge(fig, "rollout", "sampling", arrows[("rollout", "sampling")], off="rollout" in off, size=size)
    _edge(fig, "pre", "sampling", "", off="sampling" in off, size=size)
    _edge(fig, "sampling", "is", arrows[("sampling", "is")], off="sampling" in off, size=size)
    if active_phase:
        note = doing or f"now: {active_phase}"
        note = f"iteration {(record or {}).get('iteration', 0) + 1}, {note}"
    else:
        note = f"iteration {record['iteration']}" if record else "before the first iteration"
    fig.update_xaxes(visible=False, range=[-0.1, 14.3], fixedrange=True)
    fig.update_yaxes(visible=False, range=[0.05, 4.75], fixedrange=True, scaleanchor="x", scaleratio=1)
    fig.update_layout(title=dict(text=f"The loop ({note})", font=dict(size=30 if big else 16)),
                      template="plotly_white", margin=dict(l=5, r=5, t=40, b=5), height=900 if big else 340,
                      width=1600 if big else None, showlegend=False, dragmode=False,
                      plot_bgcolor="white")
    return fig
