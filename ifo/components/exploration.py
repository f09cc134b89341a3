"""Exploration over maximisation (Sec 6.2): sample from the softmax instead of the MAP action."""
from __future__ import annotations

import numpy as np


def choose(probs: np.ndarray, sample: bool, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Actions chosen from each row of `probs` (sampled or MAP) and the MAP actions."""
    map_actions = probs.argmax(-1)
    if not sample or len(probs) == 0:
        return map_actions, map_actions
    cumulative = np.cumsum(probs, axis=-1)
    u = rng.random((len(probs), 1)) * cumulative[:, -1:]
    chosen = np.minimum((u > cumulative).sum(-1), probs.shape[-1] - 1)
    return chosen, map_actions


def label_passes(probs: np.ndarray, sample: bool, passes: int,
                 rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Labels for `passes` epochs of the policy over T_e (passes x samples) and the MAP labels.

    Sampled labels are drawn afresh for each pass, so one unlucky draw is not memorised for a
    whole iteration (the authors' code made one pass per iteration, hence one draw per pass).
    """
    map_actions = probs.argmax(-1)
    if not sample:
        return np.tile(map_actions, (passes, 1)), map_actions
    return np.stack([choose(probs, True, rng)[0] for _ in range(passes)]), map_actions


def exploration_rate(chosen: np.ndarray, map_actions: np.ndarray) -> float:
    """Share of choices that were not the MAP action (Fig 6.2b)."""
    return float(np.mean(chosen != map_actions)) if len(chosen) else 0.0
