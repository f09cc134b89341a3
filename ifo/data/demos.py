"""Expert demonstrations: the learner's state-only view (T_e) and the hidden actions.

File layout (the one stable-baselines3, `imitation` and IL-Datasets users already have):

    obs             (N, *state_shape)  states s_t
    rewards         (N,)               reward after s_t
    episode_starts  (N,)               1 at each episode's first step
    actions         (N,)               optional for IfO methods, required for BC
    next_obs        (N, *state_shape)  optional; without it s_{t+1} = obs[t+1] within an episode

Shipped demonstrations keep the true actions in a separate file (`*-actions.npz`).
Files are read with `allow_pickle=False`; every problem gets a message saying exactly
what is wrong (`DemoError`).
"""
from __future__ import annotations

import os
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ifo.envs import ASSETS, EnvSpec

DEMOS_DIR = ASSETS / "demos"
MAX_DEMO_BYTES = 512 * 1024 * 1024
REQUIRED_KEYS = ("obs", "rewards", "episode_starts")


class DemoError(ValueError):
    """A demonstrations file that cannot be used, with the reason in plain words."""


@dataclass
class ExpertTransitions:
    """T_e: expert state pairs (s_t, s_{t+1}). No actions, by construction."""

    states: np.ndarray
    next_states: np.ndarray
    episode_index: np.ndarray  # which episode each pair came from

    def __len__(self) -> int:
        return len(self.states)

    @property
    def n_episodes(self) -> int:
        return int(self.episode_index.max()) + 1 if len(self.episode_index) else 0


@dataclass
class Demonstrations:
    transitions: ExpertTransitions
    episode_returns: np.ndarray
    # The expert's true actions, aligned with `transitions`. Only BC trains on them;
    # IfO methods use them for diagnostics shown to people (IDM accuracy), never to learn.
    hidden_actions: np.ndarray | None
    source: str = ""
    maze_layouts: np.ndarray | None = None  # (episodes, size, size) for maze demos

    @property
    def n_episodes(self) -> int:
        return self.transitions.n_episodes

    def first_episodes(self, k: int) -> "Demonstrations":
        keep = self.transitions.episode_index < k
        t = self.transitions
        return Demonstrations(
            ExpertTransitions(t.states[keep], t.next_states[keep], t.episode_index[keep]),
            self.episode_returns[:k],
            None if self.hidden_actions is None else self.hidden_actions[keep],
            self.source,
            None if self.maze_layouts is None else self.maze_layouts[:k],
        )


def _open_npz(path: Path) -> dict[str, np.ndarray]:
    if not path.exists():
        raise DemoError(f"{path}: no such file")
    if path.is_dir():
        raise DemoError(f"{path}: is a folder, expected an .npz file")
    size = path.stat().st_size
    if size > MAX_DEMO_BYTES:
        raise DemoError(f"{path}: {size / 2**20:.0f} MiB is over the {MAX_DEMO_BYTES / 2**20:.0f} MiB limit")
    if not zipfile.is_zipfile(path):
        raise DemoError(f"{path}: not an .npz archive (save it with numpy.savez or numpy.savez_compressed)")
    try:
        with np.load(path, allow_pickle=False) as data:
            return {k: data[k] for k in data.files}
    except ValueError as exc:
        if "allow_pickle" in str(exc):
            raise DemoError(f"{path}: holds Python objects (pickled arrays); only numeric arrays are accepted") from None
        raise DemoError(f"{path}: unreadable npz ({exc})") from None
    except (OSError, zipfile.BadZipFile, EOFError) as exc:
        raise DemoError(f"{path}: damaged npz archive ({exc})") from None


def _numeric(name: str, arr: np.ndarray) -> None:
    if arr.dtype.kind not in "biuf":
        raise DemoError(f"'{name}' has dtype {arr.dtype}; expected numbers")
    if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
        bad = int(np.size(arr) - np.count_nonzero(np.isfinite(arr)))
        raise DemoError(f"'{name}' has {bad} non-finite values (NaN or inf)")


def validate_arrays(data: dict[str, np.ndarray], spec: EnvSpec, obs_shape: tuple[int, ...],
                    require_actions: bool = False) -> None:
    """Check keys, shapes against the environment, dtypes, finite values and episode boundaries."""
    missing = [k for k in REQUIRED_KEYS if k not in data]
    if missing:
        raise DemoError(f"missing key(s) {', '.join(repr(k) for k in missing)}; "
                        f"found {sorted(data)}; expected {list(REQUIRED_KEYS)} (+ optional 'actions', 'next_obs')")
    obs = data["obs"]
    _numeric("obs", obs)
    if obs.ndim < 2:
        raise DemoError(f"'obs' has shape {obs.shape}; expected (N, {', '.join(map(str, obs_shape))})")
    n = obs.shape[0]
    if tuple(obs.shape[1:]) != tuple(obs_shape):
        raise DemoError(f"'obs' states have shape {tuple(obs.shape[1:])} but {spec.name} states have shape "
                        f"{tuple(obs_shape)}")
    if n < 2:
        raise DemoError(f"'obs' holds {n} state(s); at least 2 are needed to make a transition")
    for key in ("rewards", "episode_starts", "actions"):
        if key not in data:
            continue
        arr = data[key]
        if arr.ndim == 2 and arr.shape[1] == 1:
            arr = data[key] = arr[:, 0]
        if arr.ndim != 1 or arr.shape[0] != n:
            raise DemoError(f"'{key}' has shape {arr.shape}; expected ({n},), one entry per state in 'obs'")
        _numeric(key, arr)
    starts = data["episode_starts"]
    if not np.isin(starts, (0, 1)).all():
        raise DemoError("'episode_starts' must hold only 0 and 1 (1 at each episode's first step)")
    if starts[0] != 1:
        raise DemoError("'episode_starts' must be 1 at index 0: the first state starts an episode")
    if "next_obs" in data:
        nxt = data["next_obs"]
        _numeric("next_obs", nxt)
        if nxt.shape != obs.shape:
            raise DemoError(f"'next_obs' has shape {nxt.shape}; expected {obs.shape}, the same as 'obs'")
    else:
        lengths = np.diff(np.append(np.flatnonzero(starts), n))
        if (lengths < 2).all():
            raise DemoError("every episode has a single state: without 'next_obs' no (s_t, s_t+1) pair can be formed")
    if "actions" in data:
        acts = data["actions"]
        if acts.dtype.kind == "f" and not np.all(acts == np.round(acts)):
            raise DemoError("'actions' must be whole numbers (discrete action indices)")
        lo, hi = acts.min(), acts.max()
        if lo < 0 or hi >= spec.n_actions:
            raise DemoError(f"'actions' range from {lo:g} to {hi:g}; {spec.name} has actions 0..{spec.n_actions - 1}")
    elif require_actions:
        raise DemoError("no 'actions' key: BC learns from the expert's actions, so this file cannot train BC "
                        "(IfO methods can use it)")


def transitions_from_arrays(data: dict[str, np.ndarray]) -> tuple[ExpertTransitions, np.ndarray | None, np.ndarray]:
    """Form (s_t, s_{t+1}) pairs; returns T_e, the aligned actions (or None) and episode returns."""
    obs, starts, rewards = data["obs"], data["episode_starts"].astype(bool), data["rewards"].astype(np.float64)
    episode = np.cumsum(starts) - 1
    acts = data.get("actions")
    if "next_obs" in data:
        keep = np.ones(len(obs), dtype=bool)
        next_obs = data["next_obs"]
    else:
        # the last state of an episode has no successor in the file
        keep = np.append(episode[1:] == episode[:-1], False)
        next_obs = np.concatenate([obs[1:], obs[-1:]])
    returns = np.bincount(episode, weights=rewards)
    t = ExpertTransitions(np.ascontiguousarray(obs[keep]), np.ascontiguousarray(next_obs[keep]), episode[keep])
    return t, None if acts is None else acts[keep].astype(np.int64), returns


def load_demonstrations(path: str | os.PathLike, spec: EnvSpec, obs_shape: tuple[int, ...],
                        require_actions: bool = False, actions_path: str | os.PathLike | None = None) -> Demonstrations:
    """Load and validate a user's (or shipped) demonstrations file."""
    path = Path(path)
    data = _open_npz(path)
    if actions_path is not None and Path(actions_path).exists():
        data["actions"] = _open_npz(Path(actions_path))["actions"]
    try:
        validate_arrays(data, spec, obs_shape, require_actions)
    except DemoError as exc:
        raise DemoError(f"{path}: {exc}") from None
    t, actions, returns = transitions_from_arrays(data)
    return Demonstrations(t, returns, actions, source=str(path))


def shipped_demos_path(spec: EnvSpec) -> Path:
    return DEMOS_DIR / f"{spec.name}.npz"


def shipped_actions_path(spec: EnvSpec) -> Path:
    return DEMOS_DIR / f"{spec.name}-actions.npz"


def summarize(demos: Demonstrations) -> dict:
    return {
        "episodes": demos.n_episodes,
        "transitions": len(demos.transitions),
        "mean_return": float(np.mean(demos.episode_returns)) if len(demos.episode_returns) else None,
        "has_actions": demos.hidden_actions is not None,
    }
