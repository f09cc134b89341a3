"""Batched numpy steppers against the gymnasium environments they replace.

Finding: with the same operation order as gymnasium (and libm `pow` for Acrobot's
squares, see `_pow2`), all three tasks match gymnasium bit for bit -- observations,
internal float64 state, rewards, flags -- Acrobot included for its full 500 steps. That
needs numpy's vectorised float64 sin/cos/pow to round like the scalar calls gymnasium
makes, true where numpy uses libm (no AVX-512). Elsewhere (SVML) last bits may differ
and Acrobot's chaos amplifies them, so there the tests fall back to 1e-6 and, for
Acrobot, the first 100 steps.
"""
import math

import gymnasium as gym
import numpy as np
import pytest

from ifo.envs import get_env
from ifo.envs.batched import AcrobotStepper, CartPoleStepper, MountainCarStepper, batched_stepper
from ifo.envs.rollout import EnvPool, GymStepper, run_episodes

CONTROL = ("cartpole", "acrobot", "mountaincar")


def _vector_math_is_scalar_math() -> bool:
    x = np.random.default_rng(0).uniform(-10, 10, 2000)
    return (np.array_equal(np.cos(x), [math.cos(v) for v in x])
            and np.array_equal(np.sin(x), [math.sin(v) for v in x])
            and np.array_equal(np.power(x, np.full_like(x, 2.0)), [v**2 for v in x]))


EXACT = _vector_math_is_scalar_math()
ATOL = 0.0 if EXACT else 1e-6


def _policy(name):
    """Deterministic policies that reach the goal often enough to exercise termination."""
    if name == "cartpole":
        return lambda o: (o[:, 2] + o[:, 3] > 0).astype(np.int64)  # push towards the fall
    if name == "mountaincar":
        return lambda o: np.where(o[:, 1] >= 0, 2, 0)  # push along the velocity
    return lambda o: np.where(o[:, 5] >= 0, 2, 0)  # acrobot: torque along the elbow's swing


@pytest.mark.parametrize("name", CONTROL)
def test_trajectories_match_gymnasium_step_by_step(name):
    spec = get_env(name)
    seeds = [0, 1, 7, 42, 123, 2024]
    stepper = batched_stepper(spec, len(seeds))
    envs = [gym.make(spec.gym_id) for _ in seeds]
    obs = stepper.reset(seeds)
    np.testing.assert_array_equal(obs, np.stack([e.reset(seed=s)[0] for e, s in zip(envs, seeds)]))
    assert obs.dtype == np.float32

    rng = np.random.default_rng(5)
    alive = np.ones(len(seeds), dtype=bool)
    steps = np.zeros(len(seeds), dtype=np.int64)
    horizon = stepper.step_limit if EXACT or name != "acrobot" else 100
    while alive.any() and steps.max() < horizon:
        idx = np.flatnonzero(alive)
        actions = rng.integers(0, spec.n_actions, size=len(idx))
        o, r, term, trunc, infos = stepper.step(idx, actions)
        ref = [envs[i].step(int(a)) for i, a in zip(idx, actions)]
        steps[idx] += 1
        np.testing.assert_allclose(o, np.stack([x[0] for x in ref]), rtol=0, atol=ATOL)
        np.testing.assert_array_equal(r, [x[1] for x in ref])
        np.testing.assert_array_equal(term, [x[2] for x in ref])
        np.testing.assert_array_equal(trunc, [x[3] for x in ref])
        assert o.dtype == np.float32 and r.dtype == np.float64 and term.dtype == trunc.dtype == bool
        assert infos == [{}] * len(idx)
        if EXACT:  # the float64 state too, not just its float32 observation
            np.testing.assert_array_equal(stepper.state[idx],
                                          np.stack([np.asarray(envs[i].unwrapped.state, float) for i in idx]))
        np.testing.assert_array_equal(stepper.steps, steps)
        alive[idx[term | trunc]] = False
    if horizon == stepper.step_limit:
        assert not alive.any()


@pytest.mark.parametrize("name", CONTROL)
def test_stepping_some_episodes_leaves_the_others_alone(name):
    spec = get_env(name)
    seeds = [3, 4, 5, 6, 7]
    whole = batched_stepper(spec, 5)
    whole.reset(seeds)
    before = whole.state.copy()
    pair = batched_stepper(spec, 2)
    pair.reset([4, 7])
    idx = np.array([1, 4])
    for t in range(15):
        actions = np.array([t % spec.n_actions, (t * 7) % spec.n_actions])
        o, *_ = whole.step(idx, actions)
        o2, *_ = pair.step(np.arange(2), actions)
        np.testing.assert_array_equal(o, o2)  # an episode does not depend on its batch mates
    rest = [0, 2, 3]
    np.testing.assert_array_equal(whole.state[rest], before[rest])
    np.testing.assert_array_equal(whole.steps, [0, 15, 0, 0, 15])


@pytest.mark.parametrize("name, limit", [("cartpole", 500), ("acrobot", 500), ("mountaincar", 200)])
def test_time_limit_truncates_at_exactly_the_limit(name, limit):
    stepper = batched_stepper(get_env(name), 3)
    assert stepper.step_limit == limit
    stepper.reset([0, 1, 2])
    stepper.steps[:] = limit - 2
    idx = np.arange(3)
    _, _, term, trunc, _ = stepper.step(idx, np.ones(3, dtype=np.int64))
    assert not term.any() and not trunc.any()
    _, _, term, trunc, _ = stepper.step(idx, np.zeros(3, dtype=np.int64))
    assert not term.any() and trunc.all()


def test_terminating_on_the_last_step_is_also_truncated_as_in_gymnasium():
    # gymnasium's TimeLimit sets truncated whenever the limit is reached, terminated or not
    stepper = CartPoleStepper(1)
    stepper.reset([0])
    stepper.state[0] = [2.39, 1.0, 0.0, 0.0]
    stepper.steps[0] = 499
    _, r, term, trunc, _ = stepper.step(np.array([0]), np.array([1]))
    assert term[0] and trunc[0] and r[0] == 1.0


@pytest.mark.parametrize("name", CONTROL)
def test_run_episodes_gives_the_same_episodes_as_gymnasium(name):
    spec = get_env(name)
    policy = _policy(name)

    def act(obs):
        a = policy(obs)
        return a, a

    seeds = list(range(100, 120))
    fast_pool, slow_pool = EnvPool(spec), EnvPool(spec, batched=False)
    assert not isinstance(fast_pool.stepper(2), GymStepper) and isinstance(slow_pool.stepper(2), GymStepper)
    fast, slow = run_episodes(fast_pool, act, seeds), run_episodes(slow_pool, act, seeds)
    if EXACT or name != "acrobot":
        np.testing.assert_array_equal(fast.returns, slow.returns)
        np.testing.assert_array_equal(fast.lengths, slow.lengths)
        np.testing.assert_array_equal(fast.goals, slow.goals)
        assert [e.truncated for e in fast.episodes] == [e.truncated for e in slow.episodes]
    if EXACT:
        np.testing.assert_array_equal(fast.states, slow.states)
        np.testing.assert_array_equal(fast.next_states, slow.next_states)
    assert fast.goals.any()  # the policies do reach the goal sometimes, so termination is covered


def test_only_the_three_classic_control_tasks_are_batched():
    for name, cls in [("cartpole", CartPoleStepper), ("acrobot", AcrobotStepper),
                      ("mountaincar", MountainCarStepper)]:
        assert type(batched_stepper(get_env(name), 4)) is cls
    for name in ("lunarlander", "maze3", "maze5", "maze10"):
        assert batched_stepper(get_env(name), 4) is None
    assert isinstance(EnvPool(get_env("cartpole"), render_mode="rgb_array").stepper(1), GymStepper)


def test_render_draws_the_current_state():
    spec = get_env("cartpole")
    stepper = batched_stepper(spec, 2)
    stepper.reset([8, 9])
    env = gym.make(spec.gym_id, render_mode="rgb_array")
    env.reset(seed=9)
    for a in (1, 1, 0, 1):
        stepper.step(np.array([1]), np.array([a]))
        env.step(a)
    frame = stepper.render(1)
    assert frame.shape == (400, 600, 3) and frame.dtype == np.uint8
    np.testing.assert_array_equal(frame, env.render())
    assert not np.array_equal(frame, stepper.render(0))


# ----------------------------------------------------------------------------- LunarLander
# Box2D has no batched form; ifo.envs.lunar steps gymnasium's own worlds with less Python around them.
# Its arithmetic is gymnasium's, so the comparison is exact on every machine.

def _lander_policy(rng):
    """gymnasium's heuristic lander (it lands: the episode ends at rest) with some random actions mixed in."""
    from gymnasium.envs.box2d.lunar_lander import heuristic

    discrete = gym.make("LunarLander-v3")  # the heuristic only asks it whether actions are continuous

    def act(obs):
        a = np.array([heuristic(discrete, o) for o in obs], dtype=np.int64)
        noise = rng.random(len(a)) < 0.3
        return np.where(noise, rng.integers(0, 4, len(a)), a)
    return act


@pytest.mark.parametrize("limit", [1000, 60])
def test_lunarlander_steps_as_gymnasium_does(limit):
    from ifo.envs.lunar import LunarLanderStepper

    seeds = [0, 3, 11, 42, 2024]
    stepper = LunarLanderStepper([gym.make("LunarLander-v3") for _ in seeds], limit)
    envs = [gym.make("LunarLander-v3", max_episode_steps=limit) for _ in seeds]
    obs = stepper.reset(seeds)
    np.testing.assert_array_equal(obs, np.stack([e.reset(seed=s)[0] for e, s in zip(envs, seeds)]))
    act, alive, ends = _lander_policy(np.random.default_rng(1)), np.ones(len(seeds), dtype=bool), []
    while alive.any():
        idx = np.flatnonzero(alive)
        actions = act(obs[idx])
        o, r, term, trunc, infos = stepper.step(idx, actions)
        ref = [envs[i].step(int(a)) for i, a in zip(idx, actions)]
        np.testing.assert_array_equal(o, np.stack([x[0] for x in ref]))
        np.testing.assert_array_equal(r, [x[1] for x in ref])
        np.testing.assert_array_equal(term, [x[2] for x in ref])
        np.testing.assert_array_equal(trunc, [x[3] for x in ref])
        assert o.dtype == np.float32 and r.dtype == np.float64 and infos == [{}] * len(idx)
        obs[idx] = o
        alive[idx[term | trunc]] = False
        ends += [(bool(t), bool(u), float(x)) for t, u, x in zip(term, trunc, r) if t or u]
    if limit == 60:
        assert all(u for _, u, _ in ends)  # every episode met the time limit
    else:
        assert any(t and x == 100 for t, _, x in ends)  # a landing at rest ends the episode with +100


def test_lunarlander_runs_the_same_episodes_through_the_pool():
    from ifo.envs.lunar import LunarLanderStepper

    spec, seeds = get_env("lunarlander"), list(range(300, 316))
    fast_pool, slow_pool = EnvPool(spec), EnvPool(spec, batched=False)
    assert isinstance(fast_pool.stepper(2), LunarLanderStepper) and isinstance(slow_pool.stepper(2), GymStepper)
    assert isinstance(EnvPool(spec, render_mode="rgb_array").stepper(1), GymStepper)  # videos draw particles

    def act_with(rng):
        policy = _lander_policy(rng)
        return lambda obs: (policy(obs),) * 2

    fast = run_episodes(fast_pool, act_with(np.random.default_rng(2)), seeds)
    slow = run_episodes(slow_pool, act_with(np.random.default_rng(2)), seeds)
    for field in ("states", "actions", "next_states", "episode_index", "rewards", "returns", "lengths", "goals"):
        np.testing.assert_array_equal(getattr(fast, field), getattr(slow, field))
    assert fast.goals.any()


def test_lunarlander_refuses_an_action_it_does_not_have():
    from ifo.envs.lunar import LunarLanderStepper

    stepper = LunarLanderStepper([gym.make("LunarLander-v3")], 1000)
    stepper.reset([0])
    with pytest.raises(ValueError, match="actions 0-3"):
        stepper.step(np.array([0]), np.array([4]))
