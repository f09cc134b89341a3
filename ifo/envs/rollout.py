"""Run a batch of episodes in lockstep with one batched policy call per step.

One episode per seed, so results do not depend on how many run at once and the same
seeds give the same episodes. Every transition is recorded as (s_t, a_t, s_{t+1}) with
s_{t+1} the observation that a_t produced (the authors' code shifted these pairs by
one step; we do not).

Stepping goes through a *stepper*: `GymStepper` drives one gymnasium environment per
episode (works for any environment); environments with a numpy implementation of
their dynamics (`ifo.envs.batched`) step every episode in one array operation, and
LunarLander steps its Box2D worlds without gymnasium's per-step overhead (`ifo.envs.lunar`).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Protocol, Sequence

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
        steps = np.bincount(self.episode_index, minlength=len(self.episodes))
        return float(np.mean(per_episode / np.maximum(steps, 1)))

    def successful(self) -> np.ndarray:
        """Mask over transitions: those belonging to episodes that met the goal (v_e = 1)."""
        return self.goals[self.episode_index]


class Stepper(Protocol):
    step_limit: int | None

    def reset(self, seeds: Sequence[int]) -> np.ndarray: ...

    def step(self, idx: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list]:
        """Step episodes `idx`; returns next observations, rewards, terminated, truncated, infos (for idx)."""
        ...

    def render(self, i: int) -> np.ndarray: ...


class GymStepper:
    """One gymnasium environment per episode, stepped in a Python loop."""

    def __init__(self, envs: list):
        self.envs = envs
        env = envs[0]
        limit = getattr(env.unwrapped, "max_steps", None)
        self.step_limit = limit if limit is not None else getattr(env.spec, "max_episode_steps", None)

    def reset(self, seeds: Sequence[int]) -> np.ndarray:
        return np.stack([env.reset(seed=int(s))[0] for env, s in zip(self.envs, seeds)])

    def step(self, idx, actions):
        out = [self.envs[i].step(int(a)) for i, a in zip(idx, actions)]
        obs = np.stack([o[0] for o in out])
        rewards = np.array([o[1] for o in out], dtype=np.float64)
        terminated = np.array([o[2] for o in out], dtype=bool)
        truncated = np.array([o[3] for o in out], dtype=bool)
        return obs, rewards, terminated, truncated, [o[4] for o in out]

    def render(self, i: int) -> np.ndarray:
        from ifo.envs.drawing import render_frame

        return render_frame(self.envs[i])


class EnvPool:
    """Keeps environment copies alive between calls (creating them is not free)."""

    def __init__(self, spec: EnvSpec, batched: bool = True, **env_kwargs):
        self.spec = spec
        self.env_kwargs = env_kwargs
        self.batched = batched
        self._envs: list = []

    def envs(self, n: int) -> list:
        while len(self._envs) < n:
            self._envs.append(self.spec.make(**self.env_kwargs))
        return self._envs[:n]

    def stepper(self, n: int) -> Stepper:
        if self.batched and not self.env_kwargs:
            from ifo.envs.batched import batched_stepper

            fast = batched_stepper(self.spec, n)
            if fast is not None:
                return fast
            if not self.spec.is_maze:  # LunarLander (the import loads Box2D, which mazes never need)
                from ifo.envs import lunar

                envs = self.envs(n)
                if lunar.supports(envs[0]):
                    return lunar.LunarLanderStepper(envs, envs[0].spec.max_episode_steps)
        return GymStepper(self.envs(n))

    def close(self) -> None:
        for env in self._envs:
            env.close()
        self._envs.clear()


def run_episodes(pool: EnvPool, act: ActFn, seeds: Sequence[int], record: bool = True,
                 skip_cycles: bool = False, render_first: bool = False) -> Rollouts:
    """Run one episode per seed.

    `skip_cycles`: only for a deterministic policy in a deterministic environment (MAP
    actions in the maze). Once an observation repeats, the episode would go round the same
    cycle until the step limit, so its return and length are completed exactly without
    stepping: a lost maze agent costs a few steps instead of a thousand.
    `render_first`: keep the RGB frames of the first episode (for showing a rollout).
    """
    seeds = [int(s) for s in seeds]
    n = len(seeds)
    stepper = pool.stepper(n)
    obs = stepper.reset(seeds)
    limit = stepper.step_limit if skip_cycles else None
    seen: list[dict] = [{obs[i].tobytes(): 0} for i in range(n)] if limit else []
    history: list[list[float]] = [[] for _ in range(n)]
    alive = np.ones(n, dtype=bool)
    rets = np.zeros(n)
    lens = np.zeros(n, dtype=np.int64)
    episodes: list[Episode | None] = [None] * n
    buf_s, buf_a, buf_s2, buf_ep, buf_x, buf_r = [], [], [], [], [], []
    frames = [stepper.render(0)] if render_first else []
    while alive.any():
        idx = np.flatnonzero(alive)
        every = len(idx) == n  # no episode has ended yet: the arrays themselves, no copies by index
        here = obs if every else obs[idx]
        actions, map_actions = act(here)
        actions = np.asarray(actions, dtype=np.int64)
        o2, r, term, trunc, infos = stepper.step(idx, actions)
        rets[idx] += r
        lens[idx] += 1
        if limit:
            for j, i in enumerate(idx):
                if term[j] or trunc[j]:
                    continue
                history[i].append(r[j])
                key = o2[j].tobytes()
                if key in seen[i]:  # the rest repeats this cycle up to the step limit
                    cycle = history[i][seen[i][key]:]
                    full, part = divmod(limit - int(lens[i]), len(cycle))
                    rets[i] += full * sum(cycle) + sum(cycle[:part])
                    lens[i] = limit
                    trunc[j] = True
                seen[i][key] = len(history[i])
        for j in np.flatnonzero(term | trunc):
            i = idx[j]
            alive[i] = False
            episodes[i] = Episode(float(rets[i]), int(lens[i]), bool(term[j]), bool(trunc[j]),
                                  np.asarray(o2[j]), float(r[j]), dict(infos[j]))
        if render_first and idx[0] == 0:  # episode 0 took this step
            frames.append(stepper.render(0))
        if record:
            buf_s.append(here)
            buf_a.append(actions)
            buf_s2.append(o2)
            buf_ep.append(idx)
            buf_x.append(actions != np.asarray(map_actions))
            buf_r.append(r)
        if every:
            obs = o2  # a fresh array each step: nothing above keeps writing into it
        else:
            obs = obs.copy()
            obs[idx] = o2
    goals = np.array([pool.spec.goal(e) for e in episodes], dtype=bool)
    if record and buf_s:
        order = np.argsort(np.concatenate(buf_ep), kind="stable")  # group by episode, time order kept
        states, acts, next_states, ep_idx, non_map, rewards = (
            np.concatenate(b)[order] for b in (buf_s, buf_a, buf_s2, buf_ep, buf_x, buf_r))
    else:
        shape = obs.shape[1:]
        states = next_states = np.zeros((0, *shape), dtype=obs.dtype)
        acts = ep_idx = np.zeros(0, dtype=np.int64)
        non_map = np.zeros(0, dtype=bool)
        rewards = np.zeros(0)
    return Rollouts(states, acts, next_states, ep_idx.astype(np.int64), rewards, non_map, episodes, goals, frames)


def random_returns(spec: EnvSpec, episodes: int = 100) -> np.ndarray:
    """Returns of a uniformly random policy on the evaluation seeds (`ifo.seeds.EVAL_SEED_BASE` on):
    the random reference of Performance (Eq 4.2)."""
    from ifo.seeds import EVAL_SEED_BASE

    rng = np.random.default_rng(0)

    def act(obs):
        a = rng.integers(0, spec.n_actions, size=len(obs))
        return a, a

    pool = EnvPool(spec)
    try:
        return run_episodes(pool, act, EVAL_SEED_BASE + np.arange(episodes), record=False).returns
    finally:
        pool.close()
