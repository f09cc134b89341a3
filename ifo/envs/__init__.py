"""Environments IfO Lab knows: names, goal tests, action names, reference returns.

Every environment is a plain gymnasium environment. What the thesis adds on top is
the *goal-aware function* (Sec 5.2, 9.1.1): a test of one finished episode that
ABCO/IUPE use instead of rewards. Each `EnvSpec` carries it, with the random-policy
and expert returns that Performance (Eq 4.2) normalises by.

A researcher's own environment joins with `register_env` (discrete actions, state
vectors, their own demonstrations); named `module:name`, it is found from any process
that can import the module that registers it (a saved run, the command line).
"""
from __future__ import annotations

import importlib
import json
import threading
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Sequence

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


@dataclass(frozen=True)
class ReturnAtLeast:
    """Goal test: the episode's return reached `threshold` (CartPole: surviving 195 steps, thesis
    Sec 4.4 / 5.2)."""

    threshold: float

    def __call__(self, ep: Episode) -> bool:
        return ep.ret >= self.threshold


def reached_terminal(ep: Episode) -> bool:
    """Goal test: the episode ended by termination, not by the time limit. MountainCar (position
    >= 0.5) and Acrobot (tip above the line) terminate exactly when their goal is reached."""
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
    registered: bool = False  # a researcher's own (`register_env`), not one IfO Lab ships
    given_random_return: float | None = None  # register_env's random_return (else measured at first use)

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
        """Random-policy and expert returns measured by `python -m ifo experts`; for a registered
        environment, the random return given or measured here (its expert is the user's demonstrator,
        whose returns `Run` reads from the demonstrations)."""
        if self.registered:
            return {"random_aer": _registered_random_return(self)}
        return load_references().get(self.name, {})

    @property
    def random_return(self) -> float | None:
        return self.references().get("random_aer")

    @property
    def expert_return(self) -> float | None:
        return self.references().get("expert_aer")


_CONTROL = [
    EnvSpec("cartpole", "CartPole-v1", ("left", "right"), ReturnAtLeast(195), thesis_name="CartPole",
            feature_names=("cart position", "cart velocity", "pole angle", "pole angular velocity")),
    EnvSpec("acrobot", "Acrobot-v1", ("torque -1", "torque 0", "torque +1"), reached_terminal,
            thesis_name="Acrobot",
            feature_names=("cos θ1", "sin θ1", "cos θ2", "sin θ2", "θ1 velocity", "θ2 velocity")),
    EnvSpec("mountaincar", "MountainCar-v0", ("push left", "no push", "push right"), reached_terminal,
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


_REGISTERED: dict[str, EnvSpec] = {}  # register_env's environments, by lower-case name
_RANDOM_RETURNS: dict[str, float] = {}  # a registered environment's measured random return, by name
_FOUND_BY_MODULE: dict[str, None] = {}  # the module:name names get_env has found in this process, in order
_REGISTRY_LOCK = threading.Lock()
REFERENCE_EPISODES = 100  # random-policy episodes a registered environment's random return is measured on


def register_env(name: str, gym_id: str, *, goal: Callable[[Episode], bool],
                 action_names: Sequence[str] | None = None, feature_names: Sequence[str] | None = None,
                 random_return: float | None = None, max_episode_steps: int | None = None,
                 title: str | None = None, **kwargs: Any) -> EnvSpec:
    """Make a gymnasium environment (`gym_id`, made with `kwargs`) one IfO Lab learns in, as `name`.

    It needs discrete actions, states that are vectors, and episodes that end (a time limit in its
    gymnasium registration, or `max_episode_steps`). `goal` is its goal-aware function, the test of a
    finished episode that ABCO, IUPE and CRIL sample by (`reached_terminal`, `ReturnAtLeast(x)` or any
    callable taking an `Episode`). Performance (Eq 4.2) runs from `random_return` (measured on 100
    random-policy episodes when not given) to the mean return of the demonstrations a run learns
    from, which the user brings (`RunConfig(demos=...)`): no expert ships for it. `title` is what pages
    and figures call it (default: `name`). Registering a name again with the same environment replaces
    its names and goal; ValueError in plain words otherwise.
    Named `module:name` (the module calls this when imported), `get_env` finds it in any process."""
    import gymnasium as gym

    key = str(name).strip().lower()
    if not key or any(c.isspace() for c in key) or ":" in key:
        raise ValueError(f"an environment's name is one word without spaces or ':', got {name!r}")
    if _builtin(key) is not None:
        raise ValueError(f"{name!r} is one of IfO Lab's own environments; register yours under another name")
    if not callable(goal):
        raise ValueError(f"goal must be a test of a finished episode (a callable taking an Episode), got {goal!r}")
    if max_episode_steps is not None:
        if int(max_episode_steps) < 1:
            raise ValueError(f"max_episode_steps must be at least 1, got {max_episode_steps}")
        kwargs["max_episode_steps"] = int(max_episode_steps)
    try:
        env = gym.make(gym_id, **kwargs)
    except Exception as e:  # not registered, a missing module, wrong keyword arguments
        raise ValueError(f"gymnasium could not make {gym_id!r}: {e}") from e
    try:
        actions, states = env.action_space, env.observation_space
        limit = getattr(env.spec, "max_episode_steps", None)
    finally:
        env.close()
    if not isinstance(actions, gym.spaces.Discrete) or int(actions.start) != 0 or actions.n < 2:
        raise ValueError(f"{gym_id} has actions {actions}: IfO Lab's methods choose among discrete actions "
                         "0..n-1 (a Discrete space with n >= 2)")
    if not isinstance(states, gym.spaces.Box) or len(states.shape) != 1:
        raise ValueError(f"{gym_id} has states {states}: a registered environment's states must be vectors "
                         "(a one-dimensional Box)")
    if limit is None:
        raise ValueError(f"{gym_id} has no time limit, so an episode may never end: register it with "
                         "max_episode_steps")
    n, d = int(actions.n), int(states.shape[0])
    action_names = tuple(action_names) if action_names is not None else tuple(f"action {a}" for a in range(n))
    feature_names = tuple(feature_names) if feature_names is not None else tuple(f"s[{i}]" for i in range(d))
    if len(action_names) != n:
        raise ValueError(f"{gym_id} has {n} actions, but {len(action_names)} action names were given")
    if len(feature_names) != d:
        raise ValueError(f"{gym_id}'s states hold {d} numbers, but {len(feature_names)} feature names were given")
    spec = EnvSpec(key, gym_id, action_names, goal, kwargs=dict(kwargs), thesis_name=title or str(name).strip(),
                   feature_names=feature_names, registered=True,
                   given_random_return=None if random_return is None else float(random_return))
    with _REGISTRY_LOCK:
        before = _REGISTERED.get(key)
        if before is not None and (before.gym_id, before.kwargs) != (spec.gym_id, spec.kwargs):
            raise ValueError(f"{key!r} is already registered as {before.gym_id} {before.kwargs or ''}; register "
                             "this environment under another name")
        _REGISTERED[key] = spec
    return spec


def _builtin(key: str) -> EnvSpec | None:
    for spec in ENVS.values():
        if key in (spec.name, spec.gym_id.lower()):
            return spec
    return None


def get_env(name: str) -> EnvSpec:
    """Look an environment up by short name or gymnasium id (case-insensitive), or a registered one
    by its name; `module:name` imports the module (which registers `name`) first."""
    key = str(name).strip().lower()
    spec = _builtin(key) or _REGISTERED.get(key)
    if spec is not None:
        return spec
    module, colon, inner = str(name).strip().partition(":")
    if colon and module and inner:
        try:
            importlib.import_module(module)
        except Exception as e:  # not found, or the module itself failed (its register_env refused, a typo)
            raise UnknownEnvironment(f"unknown environment {name!r}: could not import {module!r} "
                                     f"({type(e).__name__}: {e})") from e
        spec = _REGISTERED.get(inner.lower())
        if spec is None:
            raise UnknownEnvironment(f"unknown environment {name!r}: importing {module!r} registered no "
                                     f"environment {inner!r} (ifo.envs.register_env)")
        _FOUND_BY_MODULE.setdefault(f"{module}:{spec.name}", None)
        return replace(spec, name=f"{module}:{spec.name}")  # saved runs name the module that registers it
    known = ", ".join(f"{s.name} ({s.gym_id})" for s in [*ENVS.values(), *_REGISTERED.values()])
    raise UnknownEnvironment(f"unknown environment {name!r}; known: {known}; your own: ifo.envs.register_env, "
                             "named module:name")


def found_by_module() -> tuple[str, ...]:
    """The registered environments this process has found as module:name (a setting, a saved run)."""
    return tuple(_FOUND_BY_MODULE)


def env_file_name(env: str) -> str:
    """An environment's name as file and folder names hold it: a registered one's without its module."""
    return env.rpartition(":")[2]


def _registered_random_return(spec: EnvSpec) -> float:
    """The random reference of a registered environment: given, else measured once per process."""
    if spec.given_random_return is not None:
        return spec.given_random_return
    key = env_file_name(spec.name)
    with _REGISTRY_LOCK:
        if key not in _RANDOM_RETURNS:
            from ifo.envs.rollout import random_returns

            _RANDOM_RETURNS[key] = float(random_returns(spec, REFERENCE_EPISODES).mean())
        return _RANDOM_RETURNS[key]


def load_references() -> dict:
    """Reference returns per environment (a small file, read on each call so it is never stale)."""
    path = ASSETS / "references.json"
    return json.loads(path.read_text()) if path.exists() else {}
