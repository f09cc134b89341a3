"""Building the IDM's next training set I_s from I_pre and the policy's runs I_pos.

    none        BCO(alpha) (Torabi et al.): I_s = I_pos, every run (a uniform subset of at
                most N = |I_pre| transitions when the runs hold more, as BCO(alpha) spends a
                fixed budget of post-demonstration interactions per iteration).
    abco        ABCO, Eqs 5.3-5.5: only runs that met the goal (v_e = 1) count. With the
                win probability p = P(g|E) and N = |I_pre|, draw p*N samples from the
                successful I_pos following its action distribution P(A|E; I_pos), and
                (1-p)*N from I_pre following P(A|I_pre).
    abco-whole  Table 5.2's "whole sampling": every run of I_pos, plus (1-p)*N from I_pre.
    iupe        IUPE, Sec 6.1: all transitions of the successful runs (no re-sampling by p),
                completed with (1-p)*N samples of I_pre, per action following P(A|I_pre):
                the more runs fail, the more random data the IDM keeps seeing.
With no successful run (p = 0) the goal-aware modes fall back to I_s = I_pre.
Draws are without replacement; a class with fewer samples than its share gives what it has.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ifo.data.transitions import Transitions

SAMPLING_MODES = ("none", "abco", "abco-whole", "iupe")


@dataclass
class Mixture:
    """What I_s is made of, per action: how many samples came from I_pre and from I_pos."""

    from_pre: list[int]
    from_pos: list[int]

    def as_record(self) -> dict:
        return {"from_pre": self.from_pre, "from_pos": self.from_pos,
                "size": int(sum(self.from_pre) + sum(self.from_pos))}


def allocate(total: int, probs: np.ndarray) -> np.ndarray:
    """Split `total` into integer counts following `probs` (largest remainders), summing to `total`."""
    probs = np.asarray(probs, dtype=np.float64)
    if total <= 0 or probs.sum() <= 0:
        return np.zeros(len(probs), dtype=np.int64)
    exact = total * probs / probs.sum()
    counts = np.floor(exact).astype(np.int64)
    remainder = total - counts.sum()
    counts[np.argsort(-(exact - counts), kind="stable")[:remainder]] += 1
    return counts


def draw_per_action(t: Transitions, counts: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Indices of `t`: counts[a] samples of action a, without replacement (capped by what exists)."""
    picked = []
    for a, k in enumerate(counts):
        idx = np.flatnonzero(t.actions == a)
        picked.append(rng.choice(idx, size=min(int(k), len(idx)), replace=False) if k > 0 else idx[:0])
    return np.sort(np.concatenate(picked)) if picked else np.zeros(0, dtype=np.int64)


def build_training_set(mode: str, pre: Transitions, pos: Transitions, pos_success: np.ndarray,
                       win_probability: float, n_actions: int, rng: np.random.Generator, *,
                       pos_episodes=None, share_cap=None, previous=None) -> tuple[Transitions, Mixture]:
    if mode not in SAMPLING_MODES:
        raise ValueError(f"sampling must be one of {SAMPLING_MODES}, not {mode!r}")
    p = float(win_probability)
    n = len(pre)
    if mode == "none":
        if len(pos) > n:
            pos = pos.subset(np.sort(rng.choice(len(pos), size=n, replace=False)))
        return pos, Mixture([0] * n_actions, pos.counts(n_actions).tolist())
    successful = pos.subset(np.flatnonzero(pos_success))
    if mode != "abco-whole" and len(successful) == 0:
        return pre, Mixture(pre.counts(n_actions).tolist(), [0] * n_actions)

    pre_counts = allocate(int(round((1 - p) * n)), pre.counts(n_actions))  # Eq 5.5
    pre_part = pre.subset(draw_per_action(pre, pre_counts, rng))
    if mode == "abco":  # Eqs 5.3-5.4
        pos_counts = allocate(int(round(p * n)), successful.counts(n_actions))
        pos_part = successful.subset(draw_per_action(successful, pos_counts, rng))
    elif mode == "abco-whole":
        pos_part = pos
    else:  # iupe
        pos_part = successful
    mixed = Transitions.concat([pre_part, pos_part])
    return mixed, Mixture(pre_part.counts(n_actions).tolist(), pos_part.counts(n_actions).tolist())
