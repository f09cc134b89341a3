"""The step page's panels, in one list: adding a panel is adding one `Panel(...)` to PANELS.

A panel is a chart with a short plain-language explanation and the thesis figure it
corresponds to. The page loops over PANELS: for each panel whose `applies(run)` is true
and that the lesson does not hide (`?hide=<key>`), it calls
`draw(records, run, iteration)` and shows the figure (None: nothing to show yet).
`iteration` is the one the slider scrubs to (1-based); figures take `iteration=`.

Panels that are not a single plotly figure (the rollout video) set `render(ctx)`
instead, a function that draws into the current Streamlit container.

For example, CRIL's ε would be one entry:

    Panel("cril_epsilon", "CRIL's exploration ε", "Thesis Fig 8.x", "How often CRIL acts at random...",
          draw=lambda records, run, it: figures.cril_epsilon(records, iteration=it),
          applies=lambda run: run.config.method == "cril"),
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any, Callable

import numpy as np
import plotly.graph_objects as go

from ifo import figures


@dataclass(frozen=True)
class Panel:
    key: str  # stable: the chart's widget key, the ?hide= name
    title: str
    thesis_figure: str  # "Thesis Fig 6.2b", or where in the thesis it comes from
    explanation: str  # one or two plain sentences for a student
    draw: Callable[[list, Any, int | None], go.Figure | None] | None = None
    applies: Callable[[Any], bool] = field(default=lambda run: True)
    render: Callable[[Any], None] | None = None  # custom drawing (gets a PanelContext) instead of `draw`
    wide: bool = False  # takes a whole row


def _uses_idm(run) -> bool:
    return run is not None and run.method.uses_idm


def _has_rollouts(run) -> bool:
    return run is not None and run.method.uses_idm and run.method.iterative


def _explores(run) -> bool:
    return _uses_idm(run) and bool(run.config.explore_labels or run.config.explore_rollouts)


def _maze_images(run) -> bool:
    return run is not None and run.spec.is_maze and run.config.obs_mode == "image"


def _names(run) -> list[str]:
    return list(run.spec.action_names) if run is not None else []


@lru_cache(maxsize=8)
def _probe_frames(size: int, image_size: int) -> np.ndarray:
    from ifo.probes import maze_probe_frames

    frames = maze_probe_frames(size, image_size)
    frames.setflags(write=False)
    return frames


def _grad_cam(records, run, it):
    frames = _probe_frames(run.spec.kwargs["size"], run.config.image_size) if _maze_images(run) else None
    return figures.grad_cam_panel(records, iteration=it, frames=frames, action_names=_names(run))


def _rollout_render(ctx) -> None:  # imported lazily: the video panel needs streamlit
    from ifo.ui.panels import rollout_panel

    rollout_panel(ctx)


PANELS: list[Panel] = [
    Panel("aer", "Average episodic reward", "Thesis Eq 4.1 (Tables 5.1, 6.1)",
          "The learner's mean score over its evaluation episodes after each iteration; dashed lines show the "
          "expert's and a random policy's scores.",
          draw=lambda records, run, it: figures.learning_curve(records, "aer", iteration=it)),
    Panel("performance", "Performance", "Thesis Eq 4.2 (Tables 5.1, 6.1)",
          "The same score rescaled so that a random policy is 0 and the expert is 1.",
          draw=lambda records, run, it: figures.learning_curve(records, "performance", iteration=it)),
    Panel("idm", "IDM predictions vs hidden truth", "Thesis Fig 5.2/6.2a",
          "What the inverse dynamics model says the expert did on each demonstrated transition, beside what it "
          "really did. The true actions are hidden from the learner and shown only to you.",
          draw=lambda records, run, it: figures.idm_predictions(records, _names(run), iteration=it),
          applies=_uses_idm),
    Panel("idm_over_time", "IDM predictions through time", "Thesis Fig 5.2/6.2a",
          "The IDM's predicted share of each action, iteration after iteration; dotted lines are the true shares. "
          "An action that vanishes here is one the policy can no longer learn.",
          draw=lambda records, run, it: figures.idm_predictions_over_time(
              [r for r in records if it is None or r["iteration"] <= it], _names(run)),
          applies=_uses_idm),
    Panel("accuracy", "Pseudo-label accuracy", "Not in the thesis: uses the hidden true actions",
          "How often the IDM's labels and the policy's choices match the expert's hidden actions, and how well "
          "the IDM does on random transitions it did not train on.",
          draw=lambda records, run, it: figures.accuracy_curves(records, iteration=it)),
    Panel("sampling", "Sampling mixture of I_s", "Thesis Eqs 5.3–5.5, Sec 6.1",
          "What the IDM will learn from next, per action: random transitions (I_pre) and the policy's own runs "
          "(I_pos). ABCO and IUPE trust I_pos more as more runs reach the goal.",
          draw=lambda records, run, it: figures.sampling_mixture(records, _names(run), iteration=it),
          applies=_has_rollouts),
    Panel("exploration", "Exploration rate", "Thesis Fig 6.2b",
          "The share of choices that were not the most likely action: labels sampled from the IDM and actions "
          "sampled by the policy. It decays by itself as the models grow sure.",
          draw=lambda records, run, it: figures.exploration_rate(records, iteration=it),
          applies=_explores),
    Panel("win", "Win probability P(g|E)", "Thesis Eq 5.3 (Sec 5.2)",
          "The share of the policy's own runs in each iteration that reached the goal: it sets how much of I_s "
          "comes from those runs.",
          draw=lambda records, run, it: figures.win_probability(records, iteration=it),
          applies=_has_rollouts),
    Panel("grad_cam", "Where the policy looks", "Thesis Fig 6.1",
          "Grad-CAM of the policy on fixed maze frames: red is where the pixels pushed its choice the most. "
          "A good policy looks at the agent and the walls around it.",
          draw=_grad_cam, applies=_maze_images, wide=True),
    Panel("action_distance", "Distance of each action's mean image to the expert's", "Thesis Fig 5.3",
          "For each action, how far the average frame of the policy's runs is from the expert's (0) compared with "
          "random moves (1): it falls as the policy's runs start to look like the expert's.",
          draw=lambda records, run, it: figures.action_distance_curves(
              [r for r in records if it is None or r["iteration"] <= it], _names(run)),
          applies=lambda run: _maze_images(run) and _has_rollouts(run)),
    Panel("state_attention", "Attention over state variables", "Thesis Sec 5.3 (self-attention module)",
          "How much weight the policy and the IDM give each state variable; the dotted line is what uniform "
          "attention would give.",
          draw=lambda records, run, it: figures.state_attention(
              records, run.spec.feature_names if run is not None else (), iteration=it),
          applies=lambda run: run is not None and run.config.attention == "features"),
    Panel("rollout", "A rollout of the current policy", "Thesis Figs 4.1–4.5 (the environments), Fig 5.1",
          "The learner playing one episode beside the expert playing the same episode: what the numbers above "
          "look like.",
          render=_rollout_render, wide=True),
]


def panel_keys() -> list[str]:
    return [p.key for p in PANELS]


def active_panels(run, hidden: set[str] = frozenset()) -> list[Panel]:
    """The panels this run shows, in order, minus the hidden ones."""
    return [p for p in PANELS if p.key not in hidden and p.applies(run)]
