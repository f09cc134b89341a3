"""A learner's loop as a picture; the BCO loop: I_pre -> I_s -> IDM -> labels -> policy -> rollouts
-> sampling -> I_s, and the loops of the adversarial learners (GAIL, GAIfO) and of ILPO.

`loop_diagram(record, active_phase, layout=...)` is a pure function (a record in, a plotly Figure
out), drawn with shapes and annotations so it stays sharp on a projector. A learner names its
layout (`Learner.diagram`) and its phases name their boxes. The box of the phase being trained
is filled; the boxes and arrows carry the numbers of that iteration (for the BCO loop: |I_pre|,
|I_s| and its split between I_pre and I_pos, |T_e|, the |E| policy runs and their P(g|E)).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

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


def _edge(notes: list, boxes: dict, a: str, b: str, label: str = "", off: bool = False, size: int = 13) -> None:
    """An arrow from box a to box b (and its label) as annotations appended to `notes`."""
    (x0, y0, _), (x1, y1, _) = boxes[a], boxes[b]
    sx, sy = _border(x0, y0, x1, y1)
    ex, ey = _border(x1, y1, x0, y0)
    color = MUTED if off else EDGE
    notes.append(dict(x=ex, y=ey, ax=sx, ay=sy, xref="x", yref="y", axref="x", ayref="y", text="",
                      showarrow=True, arrowhead=3, arrowsize=1.3, arrowwidth=2.5, arrowcolor=color))
    if not label:
        return
    if abs(ex - sx) < abs(ey - sy):  # vertical: beside the arrow
        notes.append(dict(x=(sx + ex) / 2, y=(sy + ey) / 2, text=label, showarrow=False, xanchor="left", xshift=6,
                          font=dict(size=size, color=color)))
    else:  # horizontal: outside the row of boxes, so long labels never cover a box
        top = y0 > 2.4
        notes.append(dict(x=(sx + ex) / 2, y=y0 + (H / 2 + 0.05) * (1 if top else -1), text=label,
                          showarrow=False, yanchor="bottom" if top else "top", font=dict(size=size, color=color)))


def _pct(v) -> str:
    return "?" if v is None else f"{v:.0%}"


def _adversarial_texts(record: dict | None, pre_size: int | None, expert_size: int | None) -> tuple[dict, dict, set]:
    r = record or {}
    d, g, ev, smp = (r.get(k) or {} for k in ("discriminator", "generator", "evaluation", "samples"))
    perf = ev.get("performance")
    lines = {
        "te": ["the expert's samples", f"|T_e| = {_n(expert_size)}"],
        "discriminator": ["tells expert from agent", f"expert {_pct(d.get('accuracy_expert'))}, "
                                                     f"agent {_pct(d.get('accuracy_agent'))}" if d else ""],
        "reward": ["learned reward of the agent", f"mean {d['mean_reward']:.2f}" if d.get("mean_reward") is not None
                   else ""],
        "policy": ["PPO on D's reward", f"loss {g['loss']:.3f}" if g.get("loss") is not None else ""],
        "rollout": ["the agent's samples", f"{_n(smp.get('environment_steps'))} steps so far" if smp else ""],
        "evaluate": [f"AER {ev['aer']:.2f}" if ev.get("aer") is not None else "AER (Eq 4.1)",
                     f"P {perf:.2f}" if perf is not None else "P (Eq 4.2)"],
    }
    return lines, {}, set()


def _ilpo_texts(record: dict | None, pre_size: int | None, expert_size: int | None) -> tuple[dict, dict, set]:
    r = record or {}
    lat, pol, ev, smp = (r.get(k) or {} for k in ("latent", "policy", "evaluation", "samples"))
    perf = ev.get("performance")
    lines = {
        "te": ["expert (s, s'), no a", f"|T_e| = {_n(expert_size)}"],
        "latent": ["s' for each latent z; π(z | s)", f"error {lat['forward_error']:.3f}"
                   if lat.get("forward_error") is not None else ""],
        "remap": ["which real a is each z", f"{len(lat['remap'])} latent actions" if lat.get("remap") else ""],
        "rollout": ["a few environment steps", f"{_n(smp.get('environment_steps'))} so far" if smp else ""],
        "policy": ["Σ_z π(z | s) π(a | z, s)", f"agrees {pol['agreement']:.0%}" if pol.get("agreement") is not None
                   else ""],
        "evaluate": [f"AER {ev['aer']:.2f}" if ev.get("aer") is not None else "AER (Eq 4.1)",
                     f"P {perf:.2f}" if perf is not None else "P (Eq 4.2)"],
    }
    return lines, {}, set()


@dataclass(frozen=True)
class Layout:
    """Where a learner's boxes stand, how its arrows run, and what they say at an iteration."""

    boxes: dict  # name -> (x, y, title)
    edges: tuple  # (from, to, label): the label is literal text, or None for texts()'s arrow label
    texts: Callable  # (record, pre_size, expert_size) -> (lines per box, arrow labels, boxes not used)
    title: str = "The loop"


LAYOUTS = {
    "bco": Layout(BOXES, (("pre", "is", None), ("is", "idm", "train"), ("idm", "label", "label"), ("te", "label", ""),
                          ("label", "policy", None), ("policy", "evaluate", ""), ("policy", "rollout", "run π"),
                          ("rollout", "sampling", None), ("pre", "sampling", ""), ("sampling", "is", None)), _texts),
    "adversarial": Layout(
        {"te": (1.1, 3.6, "T_e"), "discriminator": (5.6, 3.6, "discriminator D"), "reward": (10.1, 3.6, "reward"),
         "rollout": (5.6, 1.2, "agent's runs"), "policy": (10.1, 1.2, "policy  π(a | s)"),
         "evaluate": (13.1, 1.2, "evaluation")},
        (("te", "discriminator", "expert"), ("rollout", "discriminator", "agent"), ("discriminator", "reward", ""),
         ("reward", "policy", "PPO"), ("policy", "rollout", "run π"), ("policy", "evaluate", "")),
        _adversarial_texts, "The adversarial round"),
    "ilpo": Layout(
        {"te": (1.1, 3.6, "T_e"), "latent": (5.6, 3.6, "latent model"), "remap": (10.1, 3.6, "remap  z → a"),
         "rollout": (5.6, 1.2, "env steps"), "policy": (10.1, 1.2, "policy  π(a | s)"),
         "evaluate": (13.1, 1.2, "evaluation")},
        (("te", "latent", "learn"), ("latent", "remap", "π(z | s)"), ("rollout", "remap", "(s, a, s')"),
         ("remap", "policy", ""), ("policy", "rollout", "run π"), ("policy", "evaluate", "")),
        _ilpo_texts, "ILPO's loop"),
}


def loop_diagram(record: dict | None, active_phase: str | None = None, pre_size: int | None = None,
                 expert_size: int | None = None, theme: str = "screen", phase_boxes: dict | None = None,
                 doing: str | None = None, layout: str = "bco") -> go.Figure:
    """The loop at one iteration (`record`, None before the first), with `active_phase`'s box
    highlighted (`phase_boxes`: the learner's phase -> box; `doing`: what that phase does, in words).
    `pre_size` (|I_pre|) and `expert_size` (|T_e|) come from the run when known; `layout` is the
    learner's (`Learner.diagram`)."""
    shape = LAYOUTS.get(layout, LAYOUTS["bco"])
    lines, arrows, off = shape.texts(record, pre_size, expert_size)
    active = {**PHASE_BOX, **(phase_boxes or {})}.get(active_phase) if active_phase else None
    big = theme == "slide"
    shapes, notes = [], []  # gathered as plain dicts and set once: a figure built shape by shape is 5x slower
    for name, (x, y, title) in shape.boxes.items():
        is_active = name == active
        fill = ACTIVE if is_active else (OFF if name in off else IDLE)
        shapes.append(dict(type="rect", x0=x - W / 2, x1=x + W / 2, y0=y - H / 2, y1=y + H / 2, layer="below",
                           line=dict(color=ACTIVE if is_active else (MUTED if name in off else EDGE),
                                     width=4 if is_active else 2), fillcolor=fill))
        color = "white" if is_active else (MUTED if name in off else TEXT)
        body = "<br>".join(t for t in lines[name] if t)
        notes.append(dict(x=x, y=y, text=f"<b>{title}</b><br>{body}", showarrow=False, align="center",
                          font=dict(size=20 if big else 14, color=color)))
    size = 18 if big else 13
    for a, b, label in shape.edges:
        text = arrows.get((a, b), "") if label is None else label
        _edge(notes, shape.boxes, a, b, text, off=(a in off or b in off) and a != "label", size=size)
    if active_phase:
        note = doing or f"now: {active_phase}"
        note = f"iteration {(record or {}).get('iteration', 0) + 1}, {note}"
    else:
        note = f"iteration {record['iteration']}" if record else "before the first iteration"
    return go.Figure(layout=dict(
        shapes=shapes, annotations=notes, title=dict(text=f"{shape.title} ({note})", font=dict(size=30 if big else 16)),
        xaxis=dict(visible=False, range=[-0.1, 14.3], fixedrange=True),
        yaxis=dict(visible=False, range=[0.05, 4.75], fixedrange=True, scaleanchor="x", scaleratio=1),
        **({"template": "plotly_white"} if big else {}), margin=dict(l=5, r=5, t=40, b=5), height=900 if big else 340,
        width=1600 if big else None, showlegend=False, dragmode=False, plot_bgcolor="white"))
