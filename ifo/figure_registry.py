"""Which figure shows which record sections: one list, used by the app's panels, the export and
the tests. A figure applies when the records have what it draws, whatever method made them.

    for view in views_for(records):                  # in display order
        fig = view.draw(records, env, iteration, theme)

`env` is an `EnvView` (action and variable names, maze sizes) made from a run's configuration,
so the export can draw from saved files without building the environment.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from typing import Callable, Sequence

import numpy as np
import plotly.graph_objects as go

from ifo import figures
from ifo.envs import get_env


@dataclass(frozen=True)
class EnvView:
    """What figures need to know about the environment."""

    action_names: tuple[str, ...]
    feature_names: tuple[str, ...] = ()
    maze_size: int | None = None
    image_size: int | None = None
    maze_loops: float = 0.0  # the maze world: 0 perfect mazes, 1 braided

    @classmethod
    def of(cls, config: dict) -> "EnvView":
        spec = get_env(str(config.get("env", "")))
        images = spec.is_maze and config.get("obs_mode", "image") == "image"
        return cls(tuple(spec.action_names), tuple(spec.feature_names), spec.kwargs.get("size") if images else None,
                   int(config.get("image_size", 32)) if images else None, float(spec.kwargs.get("loops", 0.0)))


Draw = Callable[[Sequence[dict], EnvView, "int | None", str], go.Figure]


@dataclass(frozen=True)
class FigureView:
    key: str  # stable: the chart's widget key, the export's file name, the ?hide= name
    title: str
    source: str  # "Thesis Fig 6.2b", or where in the thesis it comes from
    explanation: str  # one or two plain sentences for a student
    applies: Callable[[Sequence[dict]], bool]
    draw: Draw
    wide: bool = False  # takes a whole row on the page
    page: bool = True  # shown on the step page (all are exported)
    tags: tuple[str, ...] = field(default=())


def _has(section: str, key: str | None = None) -> Callable[[Sequence[dict]], bool]:
    def applies(records: Sequence[dict]) -> bool:
        return any(section in r and (key is None or r[section].get(key) not in (None, [], {})) for r in records)

    return applies


def _any(*tests) -> Callable[[Sequence[dict]], bool]:
    return lambda records: any(t(records) for t in tests)


def _all(*tests) -> Callable[[Sequence[dict]], bool]:
    return lambda records: all(t(records) for t in tests)


def _explores(records: Sequence[dict]) -> bool:
    return any(r.get("labels", {}).get("sampled") or r.get("rollouts", {}).get("sampled")
               or (r.get("rollouts", {}).get("exploration_rate") or 0) > 0 or "td" in r for r in records)


def _upto(records: Sequence[dict], it: int | None) -> list[dict]:
    return [r for r in records if it is None or r["iteration"] <= it]


@lru_cache(maxsize=8)
def _probe_frames(size: int, image_size: int, loops: float) -> np.ndarray:
    from ifo.probes import maze_probe_frames

    frames = maze_probe_frames(size, image_size, loops=loops)
    frames.setflags(write=False)
    return frames


def _grad_cam(records, env: EnvView, it, theme):
    frames = _probe_frames(env.maze_size, env.image_size, env.maze_loops) if env.maze_size else None
    return figures.grad_cam_panel(records, iteration=it, theme=theme, frames=frames, action_names=env.action_names)


FIGURES: list[FigureView] = [
    FigureView("aer", "Average episodic reward", "Thesis Eq 4.1 (Tables 5.1, 6.1)",
               "The learner's mean score over its evaluation episodes after each iteration; dashed lines show the "
               "expert's and a random policy's scores.",
               _has("evaluation"), lambda r, env, it, theme: figures.learning_curve(r, "aer", iteration=it, theme=theme)),
    FigureView("performance", "Performance", "Thesis Eq 4.2 (Tables 5.1, 6.1)",
               "The same score rescaled so that a random policy is 0 and the expert is 1.",
               _has("evaluation", "performance"),
               lambda r, env, it, theme: figures.learning_curve(r, "performance", iteration=it, theme=theme)),
    FigureView("idm", "IDM predictions on the expert's transitions", "Thesis Fig 5.2/6.2a",
               "What the inverse dynamics model says the expert did on each demonstrated transition, beside what "
               "it really did. The true actions are hidden from the learner and shown only to you.",
               _has("idm"), lambda r, env, it, theme: figures.idm_predictions(r, env.action_names, iteration=it, theme=theme)),
    FigureView("idm_over_time", "IDM predictions through time", "Thesis Fig 5.2/6.2a",
               "The IDM's predicted share of each action, iteration after iteration; dotted lines mark where each "
               "band would end if the IDM matched the expert's hidden actions. An action that vanishes here is one "
               "the policy can no longer learn.",
               _has("idm"),
               lambda r, env, it, theme: figures.idm_predictions_over_time(_upto(r, it), env.action_names, theme=theme)),
    FigureView("idm_confusion", "The IDM's labels against the truth", "Not in the thesis: uses the hidden truth",
               "Each row is what the expert really did, each column what the IDM guessed: a good IDM puts "
               "everything on the diagonal.",
               _has("idm", "confusion"), lambda r, env, it, theme: figures.idm_confusion(r, env.action_names, iteration=it, theme=theme)),
    FigureView("idm_confidence", "How sure the IDM is", "Not in the thesis",
               "How much probability the IDM gives its own guess on each expert transition, and (from the hidden "
               "truth) how much it gives the action the expert really took.",
               _has("idm", "confidence_histogram"),
               lambda r, env, it, theme: figures.idm_confidence(r, env.action_names, iteration=it, theme=theme)),
    FigureView("accuracy", "Accuracy", "Not in the thesis: uses the hidden true actions",
               "How often the IDM's labels and the policy's choices match the expert's hidden actions, and how well "
               "the IDM does on random transitions it did not train on.",
               _any(_has("idm"), _has("policy", "expert_accuracy")),
               lambda r, env, it, theme: figures.accuracy_curves(r, iteration=it, theme=theme)),
    FigureView("sampling", "Sampling mixture of I_s", "Thesis Eqs 5.3–5.5, Sec 6.1",
               "What the IDM will learn from next, per action: random transitions (I_pre) and the policy's own runs "
               "(I_pos). ABCO and IUPE trust I_pos more as more runs reach the goal.",
               _has("sampling"), lambda r, env, it, theme: figures.sampling_mixture(r, env.action_names, iteration=it, theme=theme)),
    FigureView("sampling_share", "Share of I_s from the policy's own runs", "Thesis Eqs 5.4–5.5, Eq 8.2",
               "The share of the IDM's next training set that the text asks to come from successful runs (p), "
               "beside the share that did.",
               _has("sampling", "target_share"), lambda r, env, it, theme: figures.sampling_share(r, iteration=it, theme=theme)),
    FigureView("exploration", "Exploration rate", "Thesis Fig 6.2b",
               "The share of choices that were not the most likely action: labels sampled from the IDM and actions "
               "sampled by the policy. It decays by itself as the models grow sure.",
               _explores, lambda r, env, it, theme: figures.exploration_rate(r, iteration=it, theme=theme)),
    FigureView("win", "Win probability P(g|E)", "Thesis Eq 5.3 (Sec 5.2)",
               "The share of the policy's own runs in each iteration that reached the goal: it sets how much of I_s "
               "comes from those runs.",
               _has("rollouts"), lambda r, env, it, theme: figures.win_probability(r, iteration=it, theme=theme)),
    FigureView("attention_gates", "How much the attention blocks change the input", "Thesis Sec 5.3 (the authors' module)",
               "On vector states the thesis's attention block reduces to x + γ·(W x + b), γ starting at 0: it is a "
               "learned gate, not a map over variables. γ and the size of what it adds show how much it is used.",
               _any(_has("policy", "gates"), _has("idm", "gates")),
               lambda r, env, it, theme: figures.attention_gates(r, iteration=it, theme=theme)),
    FigureView("state_attention", "Attention over state variables", "Thesis Sec 5.3 (self-attention module)",
               "How much weight the policy and the IDM give each state variable; the dotted line is what uniform "
               "attention would give.",
               _any(_has("policy", "attention"), _has("idm", "attention")),
               lambda r, env, it, theme: figures.state_attention(r, env.feature_names, iteration=it, theme=theme)),
    FigureView("grad_cam", "Where the policy looks", "Thesis Fig 6.1",
               "Grad-CAM of the policy on fixed maze frames: red is where the pixels pushed its choice the most. "
               "A good policy looks at the agent and the walls around it.",
               _has("attention", "grad_cam"), _grad_cam, wide=True),
    FigureView("action_distance", "Distance of each action's mean image to the expert's", "Thesis Fig 5.3",
               "For each action, how far the average frame of the policy's runs is from the expert's (0) compared "
               "with random moves (1): it falls as the policy's runs start to look like the expert's.",
               _has("attention", "mean_image_distance"),
               lambda r, env, it, theme: figures.action_distance_curves(_upto(r, it), env.action_names, theme=theme)),
    FigureView("policy_map", "The policy's choice over the state space", "Thesis Figs 8.2, 8.3 (Table 8.1)",
               "The policy's most likely action over a grid of positions and velocities, beside a reference "
               "policy's; KL says how far apart they are.",
               _has("policy_map"),
               lambda r, env, it, theme: figures.policy_map(r, iteration=it, action_names=env.action_names, theme=theme), wide=True),
    FigureView("td", "Learning from its own rewards (temporal-difference updates)", "Thesis Sec 8.2 (Algorithm 8.1)",
               "CRIL also learns from its own rewards: the TD loss of its updates, the range of its Q-values, and ε, "
               "the share of random actions in its own runs, taken from the imitation step's exploration.",
               _has("td"), lambda r, env, it, theme: figures.td_curves(r, iteration=it, theme=theme)),
    FigureView("replay", "Replay memory", "Thesis Sec 8.2",
               "How full the memory of the policy's own experience is (CRIL: 10× an expert episode of transitions; "
               "SAIL: trajectories, 100× an expert episode of states).",
               _has("replay"), lambda r, env, it, theme: figures.replay_fill(r, iteration=it, theme=theme)),
    FigureView("samples", "Samples used", "Thesis Table 8.3",
               "Environment steps the learner took plus expert samples it used, so far: what it cost to get here.",
               # on the page for learners that also learn from rewards (CRIL, GAIL, GAIfO); exported for all
               _all(_has("samples"), _any(_has("td"), _has("generator"))),
               lambda r, env, it, theme: figures.sample_count(r, iteration=it, theme=theme)),
    FigureView("discriminator", "Can the discriminator tell the expert from the learner?", "Thesis Table 9.3, Sec 3.3–3.4",
               "How often the discriminator recognises the expert's and the agent's behaviour; near 50% it can no "
               "longer tell them apart.",
               _has("discriminator"), lambda r, env, it, theme: figures.discriminator_curves(r, iteration=it, theme=theme)),
    FigureView("generator", "Training the generator (the policy)", "Thesis Fig 9.2, Eq 9.2",
               "The error of the model that predicts the next state (SAIL) or of the policy-gradient learner "
               "(GAIL, GAIfO).",
               _has("generator"), lambda r, env, it, theme: figures.generator_loss(r, iteration=it, theme=theme)),
    FigureView("latent", "ILPO's latent actions", "Thesis Sec 3.2 (ILPO)",
               "How many expert transitions each latent action explains, and which real action each one was "
               "mapped to.",
               _has("latent"), lambda r, env, it, theme: figures.latent_actions(r, iteration=it, action_names=env.action_names, theme=theme)),
    FigureView("phase_seconds", "Where the time goes", "Not in the thesis",
               "Seconds each part of an iteration took.",
               _has("seconds"), lambda r, env, it, theme: figures.phase_seconds(r, theme=theme), page=False),
]


def views_for(records: Sequence[dict], page: bool = False) -> list[FigureView]:
    """The figures these records can show, in display order (only the step page's with `page`)."""
    if not records:
        return []
    return [v for v in FIGURES if v.applies(records) and (v.page or not page)]


def figure_keys() -> list[str]:
    return [v.key for v in FIGURES]
