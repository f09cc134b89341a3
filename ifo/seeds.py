"""Every random number a run uses comes from one of these named, disjoint streams of its seed.

    seeds = Seeds(run_seed)
    seeds.rng("init")                  the networks' initial weights
    seeds.rng("pre")                   building I_pre
    seeds.rng("iteration", i)          everything random inside iteration i (one stream per iteration)
    seeds.episodes("rollouts", n, i)   environment seeds of the i-th batch of n policy runs
    evaluation_seeds(n)                the same held-out episodes for every run (fixed, not per seed)

Streams are `numpy.random.SeedSequence(seed, spawn_key=(stream, *index))`, which is exactly what
`SeedSequence.spawn` does: independent whatever the seed. Environment seeds of the learner's own
episodes are drawn from 2^48-wide ranges, one per stream and all above 2^48, so they never meet
each other, the evaluation episodes (10^9 + k) or the demonstrations' episodes (0, 1, ...):
before, seed arithmetic made run seed 100's random episodes the evaluation's very seeds.
Same seed, same numbers; and a run can be resumed at any iteration, because iteration i's stream
does not depend on what earlier iterations drew.
"""
from __future__ import annotations

import threading

import numpy as np
import torch

EVAL_SEED_BASE = 1_000_000_000  # vector tasks: evaluation episodes use seeds 10^9, 10^9 + 1, ...
STREAMS = {"init": 1, "pre": 2, "iteration": 3, "evaluation": 4, "video": 5, "learner": 6}
EPISODE_STREAMS = {"pre": 1, "rollouts": 2, "learner": 3}  # environment seeds of the learner's own episodes
EPISODE_RANGE = 2**48

# Torch's default generator and numpy's global one are one per process, not per thread. torch's dropout and
# PPO's sampling draw from them, so a learner that uses them seeds them (from its iteration's stream)
# and holds this lock while it trains: two trainings in threads of one process (the app's sessions,
# IFO_LAB_MAX_TRAININGS of them at once) would otherwise interleave their draws, and the same seed
# would give other numbers, shared with the whole class through the iteration cache.
GLOBAL_RNG = threading.RLock()


class Seeds:
    """The named random streams of one run seed."""

    def __init__(self, seed: int):
        self.seed = int(seed)

    def rng(self, stream: str, *index: int) -> np.random.Generator:
        key = (STREAMS[stream], *(int(i) for i in index))
        return np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=key))

    def episodes(self, stream: str, n: int, batch: int = 0) -> np.ndarray:
        """Environment seeds for the `batch`-th group of `n` episodes of a stream (I_pre's random runs,
        the policy's runs): from the stream's own range, disjoint from every other stream's."""
        k = EPISODE_STREAMS[stream]
        sequence = np.random.SeedSequence(self.seed, spawn_key=(100 + k, int(batch)))
        draws = np.random.default_rng(sequence).integers(0, EPISODE_RANGE, n, dtype=np.int64)
        return (k * EPISODE_RANGE + draws).astype(np.int64)

    def torch_seed(self, stream: str, *index: int) -> int:
        return int(self.rng(stream, *index).integers(2**63 - 1))

    @staticmethod
    def torch_generator(rng: np.random.Generator) -> torch.Generator:
        """A torch Generator seeded from a numpy stream (mini-batch order)."""
        return torch.Generator().manual_seed(int(rng.integers(2**31)))


def evaluation_seeds(n: int, maze: bool) -> np.ndarray:
    """The held-out evaluation episodes: the same for every run, whatever its seed. Maze seeds pick
    layouts of the evaluation pool (0..n-1); vector tasks start from seeds 10^9 + k."""
    return np.arange(n) if maze else EVAL_SEED_BASE + np.arange(n)
