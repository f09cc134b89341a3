"""Expert demonstrations: the learner's state-only view (T_e) and the hidden actions.

File layout (the one stable-baselines3, `imitation` and IL-Datasets users already have):

    obs             (N, *state_shape)  states s_t
    rewards         (N,)               reward after s_t
    episode_starts  (N,)               1 at each episode's first step
    actions         (N,)               optional for IfO methods, required for BC
    next_obs        (N, *state_shape)  optional; without it s_{t+1} = obs[t+1] within an episode

Shipped demonstrations keep the true actions in a separate file (`*-actions.npz`).
Files are read with `ifo.data.npz`: sizes are checked from the headers before any data is
read, other keys are never decompressed, nothing is unpickled, and every problem gets one
message saying exactly what is wrong (`DemoError`).
"""
from __future__ import annotations

import math
import os
import zipfile
from collections.abc import Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ifo.data.npz import ArrayHeader, NpzError, npz_headers, npz_keys, read_npz
from ifo.envs import ASSETS, EnvSpec

DEMOS_DIR = ASSETS / "demos"
# Limits, checked from the headers before any data is read. The file, and its arrays once
# decompressed, may take at most MAX_DEMO_BYTES: the 35,000 states of the 10x10 maze demonstrations
# as 64x64 uint8 images take 430 MB. MAX_DEMO_ROWS is 20 times the largest shipped demonstrations
# (CartPole, 50,000 states).
MAX_DEMO_BYTES = 512 * 1024 * 1024
MAX_DEMO_ROWS = 1_000_000
# States and rewards beyond this are refused: float32 training (squares, sums, normalisation) overflows
# long before float32's 3.4e38, and no environment here comes near it.
MAX_ABS_VALUE, MAX_ABS_TEXT = 1e9, "1e9"
REQUIRED_KEYS = ("obs", "rewards", "episode_starts")
KNOWN_KEYS = REQUIRED_KEYS + ("actions", "next_obs")
STATE_KEYS = ("obs", "next_obs")


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


def _check_file(path: Path) -> None:
    if not path.exists():
        raise DemoError(f"{path}: no such file")
    if path.is_dir():
        raise DemoError(f"{path}: is a folder, expected an .npz file")
    size = path.stat().st_size
    if size == 0:
        raise DemoError(f"{path}: the file is empty (0 bytes)")
    if size > MAX_DEMO_BYTES:
        raise DemoError(f"{path}: {size / 2**20:.0f} MiB is over the {MAX_DEMO_BYTES / 2**20:.0f} MiB limit")
    if not zipfile.is_zipfile(path):
        raise DemoError(f"{path}: not an .npz archive, or a damaged one "
                        f"(save it with numpy.savez or numpy.savez_compressed)")


def _headers(path: Path, keys) -> tuple[dict[str, ArrayHeader], list[str]]:
    """The headers (shape, dtype) of `keys` and the names of all arrays; no array data is read."""
    _check_file(path)
    try:
        return npz_headers(path, keys), npz_keys(path)
    except NpzError as exc:
        raise DemoError(str(exc)) from None


def _read(path: Path, keys) -> dict[str, np.ndarray]:
    try:
        return read_npz(path, keys, max_array_bytes=MAX_DEMO_BYTES, max_total_bytes=MAX_DEMO_BYTES)
    except NpzError as exc:
        raise DemoError(str(exc)) from None


@contextmanager
def _about(path: Path):
    """Validation messages name the file they are about."""
    try:
        yield
    except DemoError as exc:
        raise DemoError(f"{path}: {exc}") from None


def _check_dtype(name: str, dtype: np.dtype) -> None:
    if dtype.hasobject:
        raise DemoError(f"'{name}' holds Python objects (a pickled array); only numeric arrays are accepted, "
                        f"and pickles are never loaded")
    if name in STATE_KEYS and dtype.kind == "b":
        raise DemoError(f"'{name}' has dtype bool; states must be numbers (float or integer), not True/False")
    if dtype.kind not in "biuf":
        raise DemoError(f"'{name}' has dtype {dtype}; expected numbers (float or integer)")


def _check_pixels(name: str, dtype: np.dtype, spec: EnvSpec) -> None:
    if dtype != np.uint8:  # the image networks read uint8 pixels, as the maze renders them
        raise DemoError(f"'{name}' has dtype {dtype}; image states must be uint8 pixels (0..255), "
                        f"as {spec.name} gives them")


def check_layout(arrays: Mapping, spec: EnvSpec, obs_shape: tuple[int, ...], require_actions: bool = False,
                 found: list[str] | None = None) -> None:
    """Keys, dtypes, shapes and sizes. Takes arrays or `ArrayHeader`s (anything with .shape and .dtype),
    so a file is checked from its headers before any of its data is read."""
    for key in KNOWN_KEYS:  # a pickle is refused first, whatever else is wrong
        if key in arrays and arrays[key].dtype.hasobject:
            _check_dtype(key, arrays[key].dtype)
    missing = [k for k in REQUIRED_KEYS if k not in arrays]
    if missing:
        found = sorted(arrays) if found is None else sorted(found)
        raise DemoError(f"missing key(s) {', '.join(repr(k) for k in missing)}; "
                        f"found {found}; expected {list(REQUIRED_KEYS)} (+ optional 'actions', 'next_obs')")
    obs = arrays["obs"]
    image = len(obs_shape) == 3
    _check_dtype("obs", obs.dtype)
    if len(obs.shape) < 2:
        raise DemoError(f"'obs' has shape {tuple(obs.shape)}; expected (N, {', '.join(map(str, obs_shape))})")
    n = obs.shape[0]
    if tuple(obs.shape[1:]) != tuple(obs_shape):
        raise DemoError(f"'obs' states have shape {tuple(obs.shape[1:])} but {spec.name} states have shape "
                        f"{tuple(obs_shape)}")
    if image:
        _check_pixels("obs", obs.dtype, spec)
    if n > MAX_DEMO_ROWS:
        raise DemoError(f"'obs' holds {n:,} states; at most {MAX_DEMO_ROWS:,} are accepted "
                        f"(20 times the largest shipped demonstrations)")
    if n < 2:
        raise DemoError(f"'obs' holds {n} state(s); at least 2 are needed to make a transition")
    for key in ("rewards", "episode_starts", "actions"):
        if key not in arrays:
            continue
        _check_dtype(key, arrays[key].dtype)
        shape = tuple(arrays[key].shape)
        if shape not in ((n,), (n, 1)):  # (N, 1) columns are what some tools write
            raise DemoError(f"'{key}' has shape {shape}; expected ({n},), one entry per state in 'obs'")
    if "next_obs" in arrays:
        nxt = arrays["next_obs"]
        _check_dtype("next_obs", nxt.dtype)
        if image:
            _check_pixels("next_obs", nxt.dtype, spec)
        if tuple(nxt.shape) != tuple(obs.shape):
            raise DemoError(f"'next_obs' has shape {tuple(nxt.shape)}; expected {tuple(obs.shape)}, the same as 'obs'")
    if require_actions and "actions" not in arrays:
        raise DemoError("no 'actions' key: BC learns from the expert's actions, so this file cannot train BC "
                        "(IfO methods can use it)")
    total = sum(math.prod(arrays[k].shape) * arrays[k].dtype.itemsize for k in KNOWN_KEYS if k in arrays)
    if total > MAX_DEMO_BYTES:
        raise DemoError(f"the arrays would take {total / 2**20:,.0f} MiB once decompressed; "
                        f"at most {MAX_DEMO_BYTES / 2**20:,.0f} MiB are accepted")


def _check_finite(name: str, arr: np.ndarray) -> None:
    if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
        bad = int(np.size(arr) - np.count_nonzero(np.isfinite(arr)))
        raise DemoError(f"'{name}' has {bad} non-finite values (NaN or inf)")


def _check_magnitude(name: str, arr: np.ndarray, why: str) -> None:
    """Finite is not enough: 1e300 is finite in float64 but inf in float32, and 3e38 overflows
    as soon as training squares it. Numbers up to MAX_ABS_VALUE leave ample headroom."""
    if arr.dtype.kind == "b":
        return
    info = np.iinfo(arr.dtype) if arr.dtype.kind in "iu" else np.finfo(arr.dtype)
    if float(info.max) <= MAX_ABS_VALUE:
        return  # cannot hold such values (uint8 images, int16 cells, float16)
    big = (arr > MAX_ABS_VALUE) | (arr < -MAX_ABS_VALUE)  # not np.abs: abs(int64 min) overflows
    if big.any():
        largest = float(np.max(np.abs(arr[big].astype(np.float64))))
        raise DemoError(f"'{name}' has {np.count_nonzero(big)} values beyond ±{MAX_ABS_TEXT} "
                        f"(largest {largest:g}): {why}")


def check_values(data: dict[str, np.ndarray], spec: EnvSpec) -> None:
    """Finite, float32-safe numbers; episode boundaries; discrete actions the environment has."""
    for key in ("obs", "next_obs"):
        if key in data:
            _check_finite(key, data[key])
            _check_magnitude(key, data[key], "states that large overflow float32 training")
    for key in ("rewards", "episode_starts", "actions"):
        if key in data:
            _check_finite(key, data[key])
    _check_magnitude("rewards", data["rewards"],
                     "rewards that large make the expert's return, which Performance is measured against, meaningless")
    starts = data["episode_starts"]
    if not np.isin(starts, (0, 1)).all():
        raise DemoError("'episode_starts' must hold only 0 and 1 (1 at each episode's first step)")
    if starts[0] != 1:
        raise DemoError("'episode_starts' must be 1 at index 0: the first state starts an episode")
    if "next_obs" not in data:
        n = len(starts)
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


def validate_arrays(data: dict[str, np.ndarray], spec: EnvSpec, obs_shape: tuple[int, ...],
                    require_actions: bool = False) -> None:
    """Check keys, shapes against the environment, dtypes, values and episode boundaries.
    (N, 1) columns of 'rewards', 'episode_starts' and 'actions' are flattened in place."""
    check_layout(data, spec, obs_shape, require_actions)
    for key in ("rewards", "episode_starts", "actions"):
        if key in data and data[key].ndim == 2:
            data[key] = data[key][:, 0]
    check_values(data, spec)


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
    """Load and validate a user's (or shipped) demonstrations file.

    Shapes, dtypes and sizes are checked from the archive's headers before any data is read;
    keys other than obs, rewards, episode_starts, actions and next_obs are never decompressed.
    Every problem raises one DemoError naming the file."""
    path = Path(path)
    headers, found = _headers(path, KNOWN_KEYS)
    actions_file = Path(actions_path) if actions_path is not None and Path(actions_path).exists() else None
    if actions_file is not None:  # shipped demonstrations keep the true actions in their own file
        headers.update(_headers(actions_file, ["actions"])[0])
    with _about(path):
        check_layout(headers, spec, obs_shape, require_actions, found)
    data = _read(path, [k for k in headers if not (k == "actions" and actions_file is not None)])
    if actions_file is not None:
        data.update(_read(actions_file, ["actions"]))
    with _about(path):
        validate_arrays(data, spec, obs_shape, require_actions)
    if len(obs_shape) == 1:  # vector states train in float32 (integers would not); values are bounded, so exact enough
        for key in STATE_KEYS:
            if key in data:
                data[key] = data[key].astype(np.float32, copy=False)
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
