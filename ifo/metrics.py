"""AER (Eq 4.1), Performance (Eq 4.2) and a behaviour-fidelity measure (Ch. 10's ask)."""
from __future__ import annotations

import numpy as np


def aer(returns) -> float:
    """Average Episodic Reward, Eq 4.1: the mean over episodes of each episode's summed reward."""
    returns = np.asarray(returns, dtype=np.float64)
    if returns.size == 0:
        raise ValueError("AER needs at least one episode")
    return float(returns.mean())


def sample_sd(values) -> float:
    """The spread over seeds (or runs) that every table, page and figure shows: the sample sd (n − 1), 0 for one."""
    values = np.asarray(values, dtype=np.float64)
    return float(values.std(ddof=1)) if values.size > 1 else 0.0


def performance(returns, random_return, expert_return) -> float:
    """Performance, Eq 4.2: mean over episodes of (pi_e - random_e) / (expert_e - random_e).

    The references may be one number (vector tasks) or one per episode (the maze, where
    each layout has its own shortest-path and random returns). 0 is random, 1 the expert;
    values below 0 or above 1 are possible and meaningful.
    """
    returns = np.asarray(returns, dtype=np.float64)
    rnd = np.broadcast_to(np.asarray(random_return, dtype=np.float64), returns.shape)
    exp = np.broadcast_to(np.asarray(expert_return, dtype=np.float64), returns.shape)
    gap = exp - rnd
    if np.any(np.abs(gap) < 1e-12):
        raise ValueError("expert and random references are equal: Performance is undefined")
    return float(np.mean((returns - rnd) / gap))


def _features(states: np.ndarray) -> np.ndarray:
    x = np.asarray(states)
    if x.ndim == 4:  # images: average-pool to 8x8 so the measure looks at layout, not pixels
        import torch

        n, h, w, c = x.shape
        t = torch.as_tensor(x, dtype=torch.float32).permute(0, 3, 1, 2) / 255.0
        x = torch.nn.functional.adaptive_avg_pool2d(t, 8).flatten(1).numpy()
    return x.reshape(len(x), -1).astype(np.float32)


def trajectory_fidelity(learner_states: np.ndarray, expert_states: np.ndarray, max_points: int = 2000,
                        seed: int = 0) -> float:
    """How far the learner's visited states are from the expert's: a symmetric Chamfer distance.

    Mean distance from each learner state to its nearest expert state and vice versa, in
    units of the expert states' per-variable spread. 0 means the learner visits exactly
    the states the expert visits; larger means its behaviour looks less like the
    expert's, whatever reward it gets. (Thesis Ch. 7.3 and 10 ask for such a measure.)
    """
    if len(learner_states) == 0 or len(expert_states) == 0:
        return float("nan")
    import torch  # here, not above: figures read `sample_sd` without loading torch

    rng = np.random.default_rng(seed)
    a, b = _features(learner_states), _features(expert_states)
    if len(a) > max_points:
        a = a[rng.choice(len(a), max_points, replace=False)]
    if len(b) > max_points:
        b = b[rng.choice(len(b), max_points, replace=False)]
    scale = b.std(0)
    scale[scale < 1e-6] = 1.0
    ta, tb = torch.as_tensor(a / scale), torch.as_tensor(b / scale)
    # The distances a block of learner states at a time, so each block stays in the cache: the same
    # nearest distances as one full matrix, bit for bit, in a third of the time. Exact distances:
    # 0 for identical sets.
    nearest_expert, nearest_learner = [], None
    for start in range(0, len(ta), 256):
        d = torch.cdist(ta[start:start + 256], tb, compute_mode="donot_use_mm_for_euclid_dist")
        nearest_expert.append(d.amin(1))
        nearest_learner = d.amin(0) if nearest_learner is None else torch.minimum(nearest_learner, d.amin(0))
    return float(0.5 * (torch.cat(nearest_expert).mean() + nearest_learner.mean()))
