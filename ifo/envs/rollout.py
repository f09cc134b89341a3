"""Run a batch of episodes in lockstep with one batched policy call per step.

One episode per environment copy, each with its own seed, so results do not depend
on how many run at once and the same seeds give the same episodes. Every transition
is recorded as (s_t, a_t, s_{t+1}) with s_{t+1} the observation that a_t produced
(the authors' code shifted these pairs by one step; we do not).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from ifo.envs import Episode, EnvSpec

# act(observations) -> (actions taken, MAP actions); both int arrays of len(batch)
ActFn = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclass
class Rollouts:
    states: np.ndarray
    actions: np.ndarray
    next_states: np.ndarray
    episode_index: np.ndarray
    rewards: np.ndarray
    took_non_map: np.ndarray  # per transition: the action taken was not the MAP action
    episodes: list[Episode]
    goals: np.ndarray
    frames: list[np.ndarray] = field(default_factory=list)  # RGB frames of episode 0

    @property
    def returns(self) -> np.ndarray:
        return np.array([e.ret for e in self.episodes], dtype=np.float64)

    @property
    def lengths(self) -> np.ndarray:
        return np.array([e.length for e in self.episodes], dtype=np.int64)

    @property
    def exploration_rate(self) -> float:
        """Fig 6.2b: per episode, the share of steps not taking the MAP action; mean over episodes."""
        if len(self.episodes) == 0 or len(self.took_non_map) == 0:
            return 0.0
        per_episode = np.bincount(self.episode_index, weights=self.took_non_map.astype(float),
                                  minlength=len(self.episodes))
        return float(np.mean(per_episode / np.maximum(self.lengths, 1)))

    def successful(self) -> np.ndarray:
        """Mask over transitions: those belonging to episodes that met the goal (v_e = 1)."""
        return self.goals[self.episode_index]


class EnvPool:
    """Keeps environment copies alive between calls (creating them is not free)."""

    def __init__(self, spec: EnvSpec, **env_kwargs):
        self.spec = spec
        self.env_kwargs = env_kwargs
        self._envs: list = []

    def get(self, n: int, render: bool = False) -> list:
        while len(self._envs) < n:
            self._envs.append(self.spec.make(**self.env_kwargs))
        return self._envs[:n]

    def close(self) -> None:
        for env in self._envs:
            env.close()
        self._envs.clear()


def _step_limit(env) -> int | None:
    limit = getattr(env.unwrapped, "max_steps", None)
    return limit if limit is not None else getattr(env.spec, "max_episode_steps", None)


def run_episodes(pool: EnvPool, act: ActFn, seeds: Sequence[int], record: bool = True,
                 render_first: bool = False, render_fn: Callable | None = None,
                 skip_cycles: bool = False) -> Rollouts:
    """Run one episode per seed.

    `skip_cycles`: only for a deterministic policy in a deterministic environment (MAP
    actions in the maze). Once an observation repeats, the episode would go round the same
    cycle until the step limit, so its return and length are completed exactly without
    stepping: a lost maze agent costs a few steps instead of a thousand.
    """
    seeds = [int(s) for s in seeds]
    n = len(seeds)
    envs = pool.get(n)
    limits = [_step_limit(env) for env in envs] if skip_cycles else [None] * n
    seen: list[dict] = [{} for _ in range(n)]
    step_rewards_of: list[list[float]] = [[] for _ in range(n)]
    obs = np.stack([env.reset(seed=s)[0] for env, s in zip(envs, seeds)])
    if skip_cycles:
        for i in range(n):
            seen[i][obs[i].tobytes()] = 0
    alive = np.ones(n, dtype=bool)
    rets = np.zeros(n)
    lens = np.zeros(n, dtype=np.int64)
    episodes: list[Episode | None] = [None] * n
    buf_s, buf_a, buf_s2, buf_ep, buf_x, buf_r = [], [], [], [], [], []
    frames = []
    if render_first and render_fn is not None:
        frames.append(render_fn(envs[0]))
    while alive.any():
        idx = np.flatnonzero(alive)
        actions, map_actions = act(obs[idx])
        next_obs = obs.copy()
        step_rewards = np.zeros(len(idx))
        for j, i in enumerate(idx):
            o2, r, term, trunc, info = envs[i].step(int(actions[j]))
            step_rewards[j] = r
            rets[i] += r
            lens[i] += 1
            next_obs[i] = o2
            if limits[i] is not None and not (term or trunc):
                key = o2.tobytes()
                history = step_rewards_of[i]
                history.append(r)
                if key in seen[i]:  # the rest of the episode repeats this cycle up to the step limit
                    cycle = history[seen[i][key]:]
                    full, part = divmod(limits[i] - int(lens[i]), len(cycle))
                    rets[i] += full * sum(cycle) + sum(cycle[:part])
                    lens[i] = limits[i]
                    trunc = True
                seen[i][key] = len(history)
            if term or trunc:
                alive[i] = False
                episodes[i] = Episode(float(rets[i]), int(lens[i]), bool(term), bool(trunc),
                                      np.asarray(o2), float(r), dict(info))
        if render_first and render_fn is not None and 0 in idx:
            frames.append(render_fn(envs[0]))
        if record:
            buf_s.append(obs[idx])
            buf_a.append(np.asarray(actions))
            buf_s2.append(next_obs[idx])
            buf_ep.append(idx)
            buf_x.append(np.asarray(actions) != np.asarray(map_actions))
            buf_r.append(step_rewards)
        obs = next_obs
    spec = pool.spec
    goals = np.array([spec.goal(e) for e in episodes], dtype=bool)
    if record and buf_s:
        states, acts = np.concatenate(buf_s), np.concatenate(buf_a).astype(np.int64)
        next_states, ep_idx = np.concatenate(buf_s2), np.concatenate(buf_ep).astype(np.int64)
        non_map, rewards = np.concatenate(buf_x), np.concatenate(buf_r)
        order = np.argsort(ep_idx, kind="stable")  # group transitions by episode, time order kept
        states, acts, next_states, ep_idx, non_map, rewards = (
            states[order], acts[order], next_states[order], ep_idx[order], non_map[order], rewards[order])
    else:
        shape = obs.shape[1:]
        states = next_states = np.zeros((0, *shape), dtype=obs.dtype)
        acts = ep_idx = np.zeros(0, dtype=np.int64)
        non_map = np.zeros(0, dtype=bool)
        rewards = np.zeros(0)
    return Rollouts(states, acts, next_states, ep_idx, rewards, non_map, episodes, goals, frames)
