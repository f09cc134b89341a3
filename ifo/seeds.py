"""Every random number a run uses comes from one of these named streams of its seed.

    seeds = Seeds(run_seed)
    seeds.rng("pre")                   numpy Generator for building I_pre
    seeds.rng("iteration", i)          everything random inside iteration i (one stream per iteration)
    seeds.episodes("rollouts", n, i)   environment seeds of the i-th batch of n policy runs
    evaluation_seeds(n)                the same held-out episodes for every run (fixed, not per seed)

Same seed, same numbers; and a run can be resumed at any iteration, because iteration i's
stream does not depend on what earlier iterations drew.
"""
from __future__ import annotations

import numpy as np
import torch

EVAL_SEED_BASE = 1_000_000_000  # vector tasks: evaluation episodes use seeds 10^9, 10^9 + 1, ...
_STREAM = {"pre": (0,), "iteration": (1,), "evaluation": (2,), "video": (3,)}
_EPISODE_BASE = {"pre": 0, "rollouts": 1_000_000}


class Seeds:
    """The named random streams of one run seed."""

    def __init__(self, seed: int):
        self.seed = int(seed)

    def rng(self, stream: str, *index: int) -> np.random.Generator:
        return np.random.default_rng([self.seed, *_STREAM[stream], *index])

    def episodes(self, stream: str, n: int, batch: int = 0) -> np.ndarray:
        """Environment seeds for the `batch`-th group of `n` episodes of a stream (I_pre's random
        runs, the policy's runs)."""
        return self.seed * 10_000_000 + _EPISODE_BASE[stream] + batch * n + np.arange(n)

    @staticmethod
    def torch_generator(rng: np.random.Generator) -> torch.Generator:
        """A torch Generator seeded from a numpy stream (mini-batch order)."""
        return torch.Generator().manual_seed(int(rng.integers(2**31)))


def evaluation_seeds(n: int, maze: bool) -> np.ndarray:
    """The held-out evaluation episodes: the same for every run, whatever its seed. Maze seeds pick
    layouts of the evaluation pool (0..n-1); vector tasks start from seeds 10^9 + k."""
    return np.arange(n) if maze else EVAL_SEED_BASE + np.arange(n)
