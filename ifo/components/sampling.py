"""Building the IDM's next training set I_s from I_pre and the policy's runs I_pos.

    none        BCO(α) as the thesis describes it: I_s = I_pos, every run of this iteration (a
                uniform subset of at most N = |I_pre| transitions when the runs hold more; I_pre
                when the runs hold nothing to learn from, e.g. a maze policy walking into a wall).
    append      BCO(α) as Torabi et al.'s Algorithm 1: I_s = I_pre plus every post-demonstration
                transition so far (I_s grows by |I_pos| each iteration).
    abco        ABCO, Eqs 5.3-5.5. Only runs that met the goal (v_e = 1) count. With p = P(g|E):
                a share p of I_s from those runs following their action distribution
                q = P(A | E; I_pos) (Eq 5.3: each run's action shares, averaged over runs), and
                1 - p from I_pre following P(A | I_pre) (Eq 5.5); |I_s| <= N.
    abco-whole  Table 5.2's "whole sampling": as abco, drawing from every run, failed ones too.
    iupe        IUPE, Sec 6.1: every transition of the successful runs, completed with I_pre in
                proportion to the failures (share 1 - p), per action following
                (1 - q(a)) * P(a | I_pre): actions rare in the successful runs get more random
                samples, so the IDM keeps seeing them.

The share of I_s that comes from I_pos is p, as Eq 5.4 asks, however long or short the runs
are: when the runs hold too few transitions for p*N, I_s shrinks so that the two parts keep the
ratio p : 1 - p (n_pre = n_pos (1 - p) / p); when I_pre runs short (IUPE with long runs), the
runs' part is subsampled instead. `share_cap` lowers p (CRIL's upper limit, Eq 8.2). With no
successful run (p = 0) the goal-aware modes fall back to I_s = I_pre. Draws are without
replacement; per-action counts are rounded by largest remainders (within one per action).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ifo.data.transitions import Transitions

SAMPLING_MODES = ("none", "append", "abco", "abco-whole", "iupe")


@dataclass
class Mixture:
    """What I_s is made of, per action: how many samples came from I_pre and from I_pos, and the share
    of I_pos the text asked for (`target`) beside the share it got."""

    from_pre: list[int]
    from_pos: list[int]
    target: float | None = None
    cap: float | None = None

    def as_record(self) -> dict:
        size = int(sum(self.from_pre) + sum(self.from_pos))
        return {"from_pre": self.from_pre, "from_pos": self.from_pos, "size": size,
                "target_share": self.target, "realised_share": sum(self.from_pos) / size if size else None,
                "cap": self.cap}


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


def run_action_distribution(actions: np.ndarray, episodes: np.ndarray, n_actions: int) -> np.ndarray:
    """Eq 5.3 over the given (successful) runs: each run's share of each action, averaged over runs,
    so a long run weighs as much as a short one. Normalised to sum to 1 (the text's version sums to
    P(g|E), which is the share p applied separately)."""
    runs = np.unique(episodes)
    if len(runs) == 0:
        return np.zeros(n_actions)
    shares = np.zeros((len(runs), n_actions))
    for k, run in enumerate(runs):
        shares[k] = np.bincount(actions[episodes == run], minlength=n_actions) / max(1, np.sum(episodes == run))
    return shares.mean(0)


def _largest_total(available: np.ndarray, weights: np.ndarray) -> float:
    """The largest n such that n * w[a] / sum(w) <= available[a] for every action with weight."""
    w = np.asarray(weights, dtype=np.float64)
    if w.sum() <= 0:
        return 0.0
    w = w / w.sum()
    return float(min(available[a] / w[a] for a in range(len(w)) if w[a] > 0))


def build_training_set(mode: str, pre: Transitions, pos: Transitions, pos_success: np.ndarray,
                       win_probability: float, n_actions: int, rng: np.random.Generator, *,
                       pos_episodes: np.ndarray | None = None, share_cap: float | None = None,
                       previous: Transitions | None = None) -> tuple[Transitions, Mixture]:
    """I_s for the next iteration (see the module's docstring). `pos_episodes` says which run each
    transition of I_pos came from (Eq 5.3 averages per run; without it every transition is its own
    weight); `previous` is the current I_s (the append mode grows it)."""
    if mode not in SAMPLING_MODES:
        raise ValueError(f"sampling must be one of {SAMPLING_MODES}, not {mode!r}")
    n = len(pre)
    episodes = pos_episodes if pos_episodes is not None else np.zeros(len(pos), dtype=np.int64)
    if mode == "none":
        if len(pos) == 0:  # the runs taught nothing (in a maze: every move hit a wall): keep I_pre
            return pre, Mixture(pre.counts(n_actions).tolist(), [0] * n_actions, target=1.0)
        if len(pos) > n:
            pos = pos.subset(np.sort(rng.choice(len(pos), size=n, replace=False)))
        return pos, Mixture([0] * n_actions, pos.counts(n_actions).tolist(), target=1.0)
    if mode == "append":
        grown = Transitions.concat([previous if previous is not None else pre, pos])
        from_pre = pre.counts(n_actions)
        return grown, Mixture(from_pre.tolist(), (grown.counts(n_actions) - from_pre).tolist())

    p = float(win_probability) if share_cap is None else min(float(win_probability), float(share_cap))
    keep = np.ones(len(pos), bool) if mode == "abco-whole" else np.asarray(pos_success, bool)
    runs, run_episodes = pos.subset(np.flatnonzero(keep)), episodes[keep]
    if len(runs) == 0 or p <= 0:
        return pre, Mixture(pre.counts(n_actions).tolist(), [0] * n_actions, target=p, cap=share_cap)

    q = run_action_distribution(runs.actions, run_episodes, n_actions)  # Eq 5.3
    pos_available, pre_available = runs.counts(n_actions), pre.counts(n_actions)
    if mode == "iupe":  # every successful transition; I_pre by the loss probability per action
        pos_weights = pos_available.astype(np.float64)
        pre_weights = (1.0 - q) * pre_available
        total_cap = np.inf
    else:  # Eqs 5.4, 5.5: I_pos following q, I_pre following P(A | I_pre), |I_s| <= N
        pos_weights, pre_weights, total_cap = q, pre_available.astype(np.float64), n
    total = min(total_cap, _largest_total(pos_available, pos_weights) / p)
    if p < 1:
        total = min(total, _largest_total(pre_available, pre_weights) / (1 - p))
    n_pos = int(round(p * total))
    pos_counts = np.minimum(allocate(n_pos, pos_weights), pos_available)
    pre_counts = np.minimum(allocate(int(round(total)) - int(pos_counts.sum()), pre_weights), pre_available)
    mixed = Transitions.concat([pre.subset(draw_per_action(pre, pre_counts, rng)),
                                runs.subset(draw_per_action(runs, pos_counts, rng))])
    return mixed, Mixture(pre_counts.tolist(), pos_counts.tolist(), target=p, cap=share_cap)
