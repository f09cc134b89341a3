"""The demonstrations shipped in assets/demos, made by `python -m ifo experts demos`.

Control tasks: an SB3-layout .npz with next states, plus the true actions in a separate
`*-actions.npz`. Maze: the layouts and the agent's cells along the shortest paths;
images (or vector observations) are rendered when loaded, at the size a run asks for.

Expert levels (thesis Ch. 7): level 1 is `<env>.npz` (+ `<env>-actions.npz`); levels 2-5 are one
file each, `<env>-level<K>.npz`, holding the true actions too (only BC and GAIL are given them, as
with anyone's demonstrations), made by `python -m ifo experts demos --env ENV --level K`. A run on
level K's demonstrations measures Performance against that expert's AER (`level_references`).
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from ifo.data.demos import (MAX_DEMO_BYTES, DemoError, Demonstrations, ExpertTransitions, load_demonstrations,
                            shipped_actions_path, shipped_demos_path)
from ifo.data.npz import NpzError, read_npz
from ifo.envs import EnvSpec
from ifo.runtime import BoundedCache, file_stamp


MAZE_KEYS = ("layouts", "episode_layout", "positions", "next_positions", "episode_starts", "rewards")


def _read(path: Path, keys: tuple[str, ...]) -> dict[str, np.ndarray]:
    """The shipped maze arrays, read with the same safe reader and limits as anyone's demonstrations."""
    try:
        data = read_npz(path, keys, max_array_bytes=MAX_DEMO_BYTES, max_total_bytes=MAX_DEMO_BYTES)
    except NpzError as exc:
        raise DemoError(str(exc)) from None
    missing = [k for k in keys if k not in data]
    if missing:
        raise DemoError(f"{path}: missing key(s) {', '.join(map(repr, missing))}; remake it with "
                        f"`python -m ifo experts demos`")
    return data


def level_demos_path(spec: EnvSpec, level: int = 1) -> Path:
    """The shipped demonstrations of expert level `level` (1: the best, `<env>.npz`)."""
    from ifo.experts import check_level

    level = check_level(level)
    return shipped_demos_path(spec) if level == 1 else shipped_demos_path(spec).with_name(f"{spec.name}-level{level}.npz")


def level_references(spec: EnvSpec, level: int = 1) -> dict:
    """{"random_aer", "expert_aer"} that Performance normalises by for a run on level `level`'s demonstrations:
    the random policy's AER and that expert's own AER, both on the evaluation episodes (Sec 7.3: P = 1 means
    'as good as this expert', not 'solved'). Level 1: assets/references.json as before."""
    from ifo.experts import check_level, level_info

    level = check_level(level)
    refs = dict(spec.references())
    if level == 1:
        return {"random_aer": refs.get("random_aer"), "expert_aer": refs.get("expert_aer")}
    info = level_info(spec, level)
    if not info:
        raise DemoError(f"no expert level {level} for {spec.name} in assets/experts/levels.json; make it with "
                        f"`python -m ifo experts train --env {spec.name} --level {level}`")
    return {"random_aer": refs.get("random_aer"), "expert_aer": info["aer"]}


def _arrays(demos: Demonstrations) -> list[np.ndarray]:
    t = demos.transitions
    return [a for a in (t.states, t.next_states, t.episode_index, demos.episode_returns, demos.hidden_actions,
                        demos.maze_layouts) if a is not None]


def _read_only(demos: Demonstrations) -> Demonstrations:
    for a in _arrays(demos):
        a.setflags(write=False)
    return demos


# Every session that opens the step page builds a run on the same shipped files (a class: thirty at once),
# so each is read (and a maze's frames drawn) once per process and its arrays shared read-only; each caller
# gets its own Demonstrations around them, and a run takes its own copies (`Demonstrations.first_episodes`).
# Keyed by the files' inode, size and time: a remade file is read again.
_loaded = BoundedCache(256 * 2**20, size=lambda demos: sum(a.nbytes for a in _arrays(demos)))


def load_shipped_demonstrations(spec: EnvSpec, obs_mode: str = "image", image_size: int = 32,
                                episodes: int | None = None, level: int = 1) -> Demonstrations:
    """The shipped demonstrations (of expert level `level`, 1..5); maze frames are drawn for the first
    `episodes` only (all if None). Shared across callers in this process: the arrays are read-only."""
    if spec.registered:
        raise DemoError(f"IfO Lab ships no demonstrations for {spec.name}, an environment of your own: bring "
                        "them (RunConfig(demos='FILE.npz'), --demos FILE.npz, or Run(config, demos=...))")
    if spec.is_maze and level != 1:
        raise DemoError(f"{spec.name} has one expert (shortest paths): no level {level}")
    path = level_demos_path(spec, level)
    if not path.exists():
        raise DemoError(f"no shipped demonstrations at {path}; make them with "
                        f"`python -m ifo experts demos --env {spec.name}" + (f" --level {level}`" if level != 1 else "`"))
    files = [path, shipped_actions_path(spec)] if level == 1 else [path]
    stamps = tuple(stamp for stamp in map(file_stamp, files) if stamp is not None)
    drawn = (obs_mode, image_size, episodes) if spec.is_maze else None  # what a maze's frames depend on
    key = (spec.name, drawn, level, stamps)
    shared = _loaded.get_or_build(key, lambda: _read_only(_load(spec, path, obs_mode, image_size, episodes, level)))
    t = shared.transitions  # the caller's own objects (it may set their fields) around the shared arrays
    return replace(shared, transitions=replace(t))


def _load(spec: EnvSpec, path: Path, obs_mode: str, image_size: int, episodes: int | None,
          level: int) -> Demonstrations:
    if not spec.is_maze:
        env = spec.make()
        shape = tuple(env.observation_space.shape)
        env.close()
        return load_demonstrations(path, spec, shape, actions_path=shipped_actions_path(spec) if level == 1 else None)
    return load_maze_demonstrations(spec, obs_mode, image_size, episodes)


def load_maze_demonstrations(spec: EnvSpec, obs_mode: str, image_size: int,
                             episodes: int | None = None) -> Demonstrations:
    from ifo.envs.maze import observation

    data = _read(shipped_demos_path(spec), MAZE_KEYS)
    layouts, episode_layout = data["layouts"], data["episode_layout"]
    positions, next_positions = data["positions"], data["next_positions"]
    starts, rewards = data["episode_starts"].astype(bool), data["rewards"]
    actions_file = shipped_actions_path(spec)
    actions = _read(actions_file, ("actions",))["actions"].astype(np.int64) if actions_file.exists() else None
    episode = np.cumsum(starts) - 1
    if episodes is not None:  # drawing frames is the slow part: only the episodes a run uses
        keep = episode < episodes
        episode, positions, next_positions, rewards = episode[keep], positions[keep], next_positions[keep], rewards[keep]
        actions = None if actions is None else actions[keep]
        episode_layout = episode_layout[:episodes]
    layout_of = layouts[episode_layout[episode]]
    states = np.stack([observation(l, p, obs_mode, image_size) for l, p in zip(layout_of, positions)])
    next_states = np.stack([observation(l, p, obs_mode, image_size) for l, p in zip(layout_of, next_positions)])
    returns = np.bincount(episode, weights=rewards)
    return Demonstrations(ExpertTransitions(states, next_states, episode), returns, actions,
                          source=str(shipped_demos_path(spec)), maze_layouts=layouts[episode_layout])
