"""Environments IfO Lab knows: names, goal tests, action names, reference returns.

Every environment is a plain gymnasium environment. What the thesis adds on top is
the *goal-aware function* (Sec 5.2, 9.1.1): a test of one finished episode that
ABCO/IUPE use instead of rewards. Each `EnvSpec` carries it, with the random-policy
and expert returns that Performance (Eq 4.2) normalises by.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import gymnasium as gym
import numpy as np

ASSETS = Path(__file__).resolve().parents[2] / "assets"


@dataclass
class Episode:
    """Summary of one finished episode, enough for every goal test."""

    ret: float
    length: int
    terminated: bool
    truncated: bool
    final_obs: np.ndarray
    final_reward: float
    info: dict = field(default_factory=dict)


def _cartpole_goal(ep: Episode) -> bool:
    # Thesis Sec 4.4 / 5.2: surviving 195 steps solves CartPole.
    return ep.ret >= 195


def _reached_terminal(ep: Episode) -> bool:
    # MountainCar (position >= 0.5) and Acrobot (tip above the line) end by
    # termination exactly when their goal is reached; truncation is failure.
    return bool(ep.terminated)


def _lunar_goal(ep: Episode) -> bool:
    # Lander at rest (terminated, the +100 bonus makes the last reward positive),
    # not crashed (a crash gives -100), and still inside the screen.
    return bool(ep.terminated and ep.final_reward > 0 and abs(float(ep.final_obs[0])) < 1.0)


def _maze_goal(ep: Episode) -> bool:
    return bool(ep.info.get("at_goal", False))


@dataclass(frozen=True)
class EnvSpec:
    name: str  # short name: cartpole, maze5, ...
    gym_id: str
    action_names: tuple[str, ...]
    goal: Callable[[Episode], bool]
    kwargs: dict = field(default_factory=dict)
    is_maze: bool = False
    thesis_name: str = ""
    deterministic: bool = False  # same state and action always give the same next state
    feature_names: tuple[str, ...] = ()  # names of the state variables (vector states)
    # two state variables to draw the policy over (Figs 8.2, 8.3): ((index, name, low, high), ...)
    policy_map_axes: tuple = ()
    settings_from: str = ""  # another environment whose per-environment default settings this one shares

    @property
    def settings_name(self) -> str:
        """The name per-environment defaults are looked up by (a braided maze takes its perfect twin's)."""
        return self.settings_from or self.name

    @property
    def n_actions(self) -> int:
        return len(self.action_names)

    def make(self, **overrides: Any) -> gym.Env:
        kwargs = {**self.kwargs, **overrides}
        if kwargs.get("render_mode") is not None:
            import ifo.envs.drawing  # noqa: F401  (pygame ready for drawing from threads)
        if self.is_maze:
            from ifo.envs.maze import MazeEnv

            return MazeEnv(**kwargs)
        return gym.make(self.gym_id, **kwargs)

    def references(self) -> dict:
        """Random-policy and expert returns measured by `python -m ifo experts`."""
        return load_references().get(self.name, {})

    @property
    def random_return(self) -> float | None:
        return self.references().get("random_aer")

    @property
    def expert_return(self) -> float | None:
        return self.references().get("expert_aer")


_CONTROL = [
    EnvSpec("cartpole", "CartPole-v1", ("left", "right"), _cartpole_goal, thesis_name="CartPole",
            feature_names=("cart position", "cart velocity", "pole angle", "pole angular velocity")),
    EnvSpec("acrobot", "Acrobot-v1", ("torque -1", "torque 0", "torque +1"), _reached_terminal,
            thesis_name="Acrobot",
            feature_names=("cos θ1", "sin θ1", "cos θ2", "sin θ2", "θ1 velocity", "θ2 velocity")),
    EnvSpec("mountaincar", "MountainCar-v0", ("push left", "no push", "push right"), _reached_terminal,
            thesis_name="MountainCar", feature_names=("position", "velocity"),
            policy_map_axes=((0, "position", -1.2, 0.6), (1, "velocity", -0.07, 0.07))),
    EnvSpec("lunarlander", "LunarLander-v3", ("noop", "fire left", "fire main", "fire right"), _lunar_goal,
            thesis_name="LunarLander",
            feature_names=("x", "y", "x velocity", "y velocity", "angle", "angular velocity", "left leg contact",
                           "right leg contact")),
]
_MAZES = [
    EnvSpec(f"maze{n}", f"ifo/Maze{n}x{n}-v0", ("N", "S", "W", "E"), _maze_goal, kwargs={"size": n},
            is_maze=True, deterministic=True, thesis_name=f"Maze {n}x{n}")
    for n in (3, 5, 10)
] + [  # the same mazes braided (no dead ends: loops), closer to the world the thesis's references suggest
    EnvSpec(f"maze{n}-loops", f"ifo/Maze{n}x{n}Loops-v0", ("N", "S", "W", "E"), _maze_goal,
            kwargs={"size": n, "loops": 1.0}, is_maze=True, deterministic=True,
            thesis_name=f"Maze {n}x{n} with loops", settings_from=f"maze{n}")
    for n in (3, 5, 10)
]
ENVS: dict[str, EnvSpec] = {spec.name: spec for spec in _CONTROL + _MAZES}
ENV_NAMES = tuple(ENVS)


class UnknownEnvironment(ValueError):
    pass


def get_env(name: str) -> EnvSpec:
    """Look an environment up by short name or gymnasium id (case-insensitive)."""
    key = name.strip().lower()
    for spec in ENVS.values():
        if key in (spec.name, spec.gym_id.lower()):
            return spec
    known = ", ".join(f"{s.name} ({s.gym_id})" for s in ENVS.values())
    raise UnknownEnvironment(f"unknown environment {name!r}; known: {known}")


def load_references() -> dict:
    """Reference returns per environment (a small file, read on each call so it is never stale)."""
    path = ASSETS / "references.json"
    return json.loads(path.read_text()) if path.exists() else {}
