"""Labelled transitions (s_t, a_t, s_{t+1}): I_pre, I_pos and the IDM's training set I_s."""
from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ifo.envs.rollout import EnvPool, run_episodes
from ifo.runtime import BoundedCache


@dataclass
class Transitions:
    states: np.ndarray
    actions: np.ndarray
    next_states: np.ndarray

    def __len__(self) -> int:
        return len(self.actions)

    def subset(self, idx: np.ndarray) -> "Transitions":
        return Transitions(self.states[idx], self.actions[idx], self.next_states[idx])

    @staticmethod
    def concat(parts: list["Transitions"]) -> "Transitions":
        parts = [p for p in parts if len(p)] or parts[:1]
        return Transitions(np.concatenate([p.states for p in parts]),
                           np.concatenate([p.actions for p in parts]),
                           np.concatenate([p.next_states for p in parts]))

    def moved(self) -> np.ndarray:
        """Mask of the transitions whose state changed. In the maze a move into a wall leaves the
        frame as it was: such a pair carries no information about which action was taken."""
        n = len(self)
        return (self.states.reshape(n, -1) != self.next_states.reshape(n, -1)).any(1)

    def counts(self, n_actions: int) -> np.ndarray:
        return np.bincount(self.actions, minlength=n_actions)

    def arrays(self, prefix: str) -> dict[str, np.ndarray]:
        return {f"{prefix}states": self.states, f"{prefix}actions": self.actions,
                f"{prefix}next_states": self.next_states}

    @staticmethod
    def from_arrays(data, prefix: str) -> "Transitions":
        return Transitions(data[f"{prefix}states"], data[f"{prefix}actions"], data[f"{prefix}next_states"])


@dataclass
class PreDemonstrations:
    """I_pre, split 70/30 (stratified by action) into IDM training and validation parts."""

    train: Transitions
    validation: Transitions


def collect_random_transitions(pool: EnvPool, n_actions: int, size: int, per_action_cap: int,
                               rng: np.random.Generator, seeds: Callable[[int, int], np.ndarray],
                               drop_unchanged: bool = False, episodes_per_batch: int = 32) -> tuple[Transitions, int]:
    """Random-policy transitions, class-balanced at `per_action_cap` per action.

    `seeds(batch, n)` gives the environment seeds of the batch-th group of n random episodes.
    Returns the transitions and the number of environment steps taken to collect them.
    `drop_unchanged` removes moves that left the state as it was (the maze's moves into
    walls): they carry no information about which action was taken.
    """
    parts: list[Transitions] = []
    counts = np.zeros(n_actions, dtype=np.int64)
    target = min(size // n_actions, per_action_cap)
    batch = steps = 0

    def act(obs):
        a = rng.integers(0, n_actions, size=len(obs))
        return a, a

    while counts.min() < target and batch < 200:
        ro = run_episodes(pool, act, seeds(batch, episodes_per_batch))
        steps += len(ro.actions)
        part = Transitions(ro.states, ro.actions, ro.next_states)
        if drop_unchanged:
            part = part.subset(np.flatnonzero(part.moved()))
        parts.append(part)
        counts += part.counts(n_actions)
        batch += 1
    everything = Transitions.concat(parts)
    keep = []
    for a in range(n_actions):
        idx = np.flatnonzero(everything.actions == a)
        keep.append(rng.permutation(idx)[:target])
    return everything.subset(np.sort(np.concatenate(keep))), steps


def _nbytes(t: Transitions) -> int:
    return t.states.nbytes + t.actions.nbytes + t.next_states.nbytes


# I_pre's random transitions, collected once per process for each (environments, seed, sizes, random
# stream state): every session of a lesson builds the same run, and collecting is most of building it
# (about a second on CartPole). The sets are read-only (learners take subsets, i.e. copies).
RANDOM_TRANSITIONS = BoundedCache(256 << 20, size=lambda kept: _nbytes(kept[0]))


def random_transitions_once(key: dict, rng: np.random.Generator,
                            collect: Callable[[], tuple[Transitions, int]]) -> tuple[Transitions, int]:
    """`collect()` (which draws from `rng`) once per process for `key` and `rng`'s state. A kept set also
    leaves `rng` where the collection left it, so the numbers are those of a fresh collection."""
    name = json.dumps({**key, "rng": rng.bit_generator.state}, sort_keys=True, default=str)

    def collect_and_freeze():
        transitions, steps = collect()
        for a in (transitions.states, transitions.actions, transitions.next_states):
            a.flags.writeable = False
        return transitions, steps, rng.bit_generator.state

    # Once per key: sessions asking for the same set wait for its one collection; a set already kept,
    # or another key's collection, is not held up by it.
    transitions, steps, rng_after = RANDOM_TRANSITIONS.get_or_build(name, collect_and_freeze)
    rng.bit_generator.state = rng_after
    return transitions, steps


def stratified_split(t: Transitions, n_actions: int, val_share: float,
                     rng: np.random.Generator) -> PreDemonstrations:
    train_idx, val_idx = [], []
    for a in range(n_actions):
        idx = rng.permutation(np.flatnonzero(t.actions == a))
        n_val = int(round(len(idx) * val_share))
        val_idx.append(idx[:n_val])
        train_idx.append(idx[n_val:])
    return PreDemonstrations(t.subset(np.sort(np.concatenate(train_idx))),
                             t.subset(np.sort(np.concatenate(val_idx))))
