"""Numpy implementations of classic-control dynamics that step every episode at once.

CartPole-v1, Acrobot-v1 and MountainCar-v0 are a few lines of float64 arithmetic per
step; stepping them one gymnasium environment at a time costs ~10 µs of Python per
episode-step, one array operation over all episodes costs about as much per *batch*.

Each stepper follows gymnasium's source (gymnasium/envs/classic_control) with the same
constants and the same order of floating-point operations, so trajectories are bit for
bit those of the real environments, Acrobot's included (whose chaotic dynamics would
amplify any last-bit difference). That holds while numpy's vectorised float64 sin/cos/pow
round like the scalar calls gymnasium makes: they are the same libm calls on builds
without AVX-512; AVX-512 builds use SVML and may differ in the last bit.

Initial states come from a real gymnasium environment reset with each episode's seed,
so they are exactly gymnasium's without re-implementing its seeding.
"""
from __future__ import annotations

import functools
import math
import threading
from typing import Sequence

import gymnasium as gym
import numpy as np


# Held while using a shared environment: Streamlit sessions train in threads of one process.
_SHARED_ENV_LOCK = threading.Lock()


@functools.cache
def _gym_env(gym_id: str, render_mode: str | None = None) -> gym.Env:
    """One unwrapped environment per id, shared: only used to draw initial states and render.

    Shared because `gym.make` costs ~0.2 ms and a stepper is made per `run_episodes` call.
    """
    env = gym.make(gym_id, render_mode=render_mode).unwrapped
    env.reset(seed=0)  # so render() has a state before the first episode
    return env


class _BatchedStepper:
    """Common part: per-episode float64 state and step counts, reset, time limit, render.

    Subclasses give `gym_id`, `state_dim` and `_dynamics(state, actions) -> (state,
    rewards, terminated)` for the rows of the episodes being stepped, and `_obs(state)`.
    """

    gym_id: str
    state_dim: int

    def __init__(self, n: int):
        self.n = n
        self.step_limit: int = gym.spec(self.gym_id).max_episode_steps
        self.state = np.zeros((n, self.state_dim), dtype=np.float64)
        self.steps = np.zeros(n, dtype=np.int64)
        self._no_infos = [{}] * n  # gymnasium's info dicts, empty here (read only: run_episodes copies them)

    def reset(self, seeds: Sequence[int]) -> np.ndarray:
        if len(seeds) != self.n:
            raise ValueError(f"stepper made for {self.n} episodes, got {len(seeds)} seeds")
        obs = []
        with _SHARED_ENV_LOCK:
            env = _gym_env(self.gym_id)
            for k, seed in enumerate(seeds):
                o, _ = env.reset(seed=int(seed))
                self.state[k] = env.state  # Acrobot's is float32: exact in float64, as its first step makes it
                obs.append(o)  # gymnasium's own first observation (Acrobot computes it in float32)
        self.steps[:] = 0
        return np.stack(obs)

    def step(self, idx: np.ndarray, actions: np.ndarray):
        idx = np.asarray(idx, dtype=np.int64)
        actions = np.asarray(actions, dtype=np.int64)
        if len(idx) == self.n:  # every episode steps (idx is sorted and distinct): no gathers, no scatters
            state, rewards, terminated = self._dynamics(self.state, actions)
            self.state = state
            self.steps += 1
            steps = self.steps
        else:
            state, rewards, terminated = self._dynamics(self.state[idx], actions)
            self.state[idx] = state
            self.steps[idx] += 1
            steps = self.steps[idx]
        # gymnasium's TimeLimit sets truncated at the limit even when that step also terminates
        truncated = steps >= self.step_limit
        return self._obs(state), rewards, terminated, truncated, self._no_infos[:len(idx)]

    def render(self, i: int) -> np.ndarray:
        from ifo.envs.drawing import render_frame  # pygame ready for drawing from threads

        with _SHARED_ENV_LOCK:
            env = _gym_env(self.gym_id, "rgb_array")
            env.state = self.state[i].copy()
            return render_frame(env)

    def _dynamics(self, state: np.ndarray, actions: np.ndarray):
        raise NotImplementedError

    def _obs(self, state: np.ndarray) -> np.ndarray:
        return state.astype(np.float32)


class CartPoleStepper(_BatchedStepper):
    """CartPole-v1 (gymnasium CartPoleEnv, Euler integrator, reward 1 on every step)."""

    gym_id = "CartPole-v1"
    state_dim = 4
    gravity = 9.8
    masspole = 0.1
    total_mass = masspole + 1.0  # + masscart
    length = 0.5  # half the pole's length
    polemass_length = masspole * length
    force_mag = 10.0
    tau = 0.02
    theta_threshold_radians = 12 * 2 * math.pi / 360
    x_threshold = 2.4

    def _dynamics(self, state, actions):
        x, x_dot, theta, theta_dot = state.T
        force = np.where(actions == 1, self.force_mag, -self.force_mag)
        costheta = np.cos(theta)
        sintheta = np.sin(theta)
        temp = (force + self.polemass_length * np.square(theta_dot) * sintheta) / self.total_mass
        thetaacc = (self.gravity * sintheta - costheta * temp) / (
            self.length * (4.0 / 3.0 - self.masspole * np.square(costheta) / self.total_mass))
        xacc = temp - self.polemass_length * thetaacc * costheta / self.total_mass
        x = x + self.tau * x_dot
        x_dot = x_dot + self.tau * xacc
        theta = theta + self.tau * theta_dot
        theta_dot = theta_dot + self.tau * thetaacc
        terminated = ((x < -self.x_threshold) | (x > self.x_threshold)
                      | (theta < -self.theta_threshold_radians) | (theta > self.theta_threshold_radians))
        rewards = np.ones(len(state))  # the terminating step included
        return np.stack((x, x_dot, theta, theta_dot), axis=1), rewards, terminated


class MountainCarStepper(_BatchedStepper):
    """MountainCar-v0 (gymnasium MountainCarEnv, goal_velocity 0, reward -1 per step)."""

    gym_id = "MountainCar-v0"
    state_dim = 2
    min_position = -1.2
    max_position = 0.6
    max_speed = 0.07
    goal_position = 0.5
    goal_velocity = 0
    force = 0.001
    gravity = 0.0025

    def _dynamics(self, state, actions):
        position, velocity = state.T
        # gymnasium uses math.cos here; numpy's float64 cos is the same libm result (see module doc)
        velocity = velocity + ((actions - 1) * self.force + np.cos(3 * position) * (-self.gravity))
        velocity = np.clip(velocity, -self.max_speed, self.max_speed)
        position = position + velocity
        position = np.clip(position, self.min_position, self.max_position)
        velocity = np.where((position == self.min_position) & (velocity < 0), 0.0, velocity)  # inelastic wall
        terminated = (position >= self.goal_position) & (velocity >= self.goal_velocity)
        return np.stack((position, velocity), axis=1), np.full(len(state), -1.0), terminated


class AcrobotStepper(_BatchedStepper):
    """Acrobot-v1 (gymnasium AcrobotEnv: book dynamics, RK4 over one dt, no torque noise).

    Reward -1 per step and 0 on the terminating step.
    """

    gym_id = "Acrobot-v1"
    state_dim = 4
    dt = 0.2
    LINK_LENGTH_1 = 1.0
    LINK_MASS_1 = 1.0
    LINK_MASS_2 = 1.0
    LINK_COM_POS_1 = 0.5
    LINK_COM_POS_2 = 0.5
    LINK_MOI = 1.0
    MAX_VEL_1 = 4 * np.pi
    MAX_VEL_2 = 9 * np.pi
    AVAIL_TORQUE = np.array([-1.0, 0.0, +1])

    def _dynamics(self, state, actions):
        torque = self.AVAIL_TORQUE[actions]
        # Rows are the state variables (theta1, theta2, dtheta1, dtheta2, torque), columns episodes,
        # so `_dsdt` reads exactly like gymnasium's scalar version.
        s_augmented = np.vstack((state.T, torque))
        ns = _rk4(self._dsdt, s_augmented, [0, self.dt])
        ns[0] = _wrap(ns[0], -np.pi, np.pi)
        ns[1] = _wrap(ns[1], -np.pi, np.pi)
        ns[2] = _bound(ns[2], -self.MAX_VEL_1, self.MAX_VEL_1)
        ns[3] = _bound(ns[3], -self.MAX_VEL_2, self.MAX_VEL_2)
        terminated = -np.cos(ns[0]) - np.cos(ns[1] + ns[0]) > 1.0
        rewards = np.where(terminated, 0.0, -1.0)
        return ns.T.copy(), rewards, terminated

    def _obs(self, state):
        t1, t2, dt1, dt2 = state.T
        return np.stack((np.cos(t1), np.sin(t1), np.cos(t2), np.sin(t2), dt1, dt2), axis=1).astype(np.float32)

    def _dsdt(self, s_augmented):
        m1 = self.LINK_MASS_1
        m2 = self.LINK_MASS_2
        l1 = self.LINK_LENGTH_1
        lc1 = self.LINK_COM_POS_1
        lc2 = self.LINK_COM_POS_2
        I1 = self.LINK_MOI
        I2 = self.LINK_MOI
        g = 9.8
        pi = np.pi
        a = s_augmented[-1]
        theta1, theta2, dtheta1, dtheta2 = s_augmented[:-1]
        d1 = m1 * lc1**2 + m2 * (l1**2 + lc2**2 + 2 * l1 * lc2 * np.cos(theta2)) + I1 + I2
        d2 = m2 * (lc2**2 + l1 * lc2 * np.cos(theta2)) + I2
        phi2 = m2 * lc2 * g * np.cos(theta1 + theta2 - pi / 2.0)
        phi1 = (
            -m2 * l1 * lc2 * _pow2(dtheta2) * np.sin(theta2)
            - 2 * m2 * l1 * lc2 * dtheta2 * dtheta1 * np.sin(theta2)
            + (m1 * lc1 + m2 * l1) * g * np.cos(theta1 - pi / 2)
            + phi2
        )
        ddtheta2 = (
            a + d2 / d1 * phi1 - m2 * l1 * lc2 * _pow2(dtheta1) * np.sin(theta2) - phi2
        ) / (m2 * lc2**2 + I2 - _pow2(d2) / d1)
        ddtheta1 = -(d2 * ddtheta2 + phi1) / d1
        return np.stack((dtheta1, dtheta2, ddtheta1, ddtheta2, np.zeros_like(a)))


def _pow2(x: np.ndarray) -> np.ndarray:
    """`x**2` as gymnasium gets it on numpy scalars: libm pow, which differs from the exact
    x*x in the last bit for ~0.1% of inputs. Array `x**2` is turned into x*x by numpy, so
    pass the exponent as an array to keep the elementwise pow."""
    return np.power(x, np.full_like(x, 2.0))


def _rk4(derivs, y0: np.ndarray, t: list) -> np.ndarray:
    """gymnasium's `rk4` for the single interval [t0, t1], on columns of episodes; returns the 4 state rows."""
    dt = t[1] - t[0]
    dt2 = dt / 2.0
    k1 = derivs(y0)
    k2 = derivs(y0 + dt2 * k1)
    k3 = derivs(y0 + dt2 * k2)
    k4 = derivs(y0 + dt * k3)
    return (y0 + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4))[:4]


def _wrap(x: np.ndarray, m: float, M: float) -> np.ndarray:
    """gymnasium's `wrap`: shift by whole periods (not a modulo, whose rounding differs)."""
    diff = M - m
    while (above := x > M).any():
        x = np.where(above, x - diff, x)
    while (below := x < m).any():
        x = np.where(below, x + diff, x)
    return x


def _bound(x: np.ndarray, m: float, M: float) -> np.ndarray:
    return np.minimum(np.maximum(x, m), M)


_STEPPERS = {cls.gym_id: cls for cls in (CartPoleStepper, AcrobotStepper, MountainCarStepper)}


def batched_stepper(spec, n: int) -> _BatchedStepper | None:
    """A numpy stepper for `spec` if its dynamics are implemented here (default kwargs only), else None."""
    cls = _STEPPERS.get(spec.gym_id)
    if cls is None or spec.kwargs:
        return None
    return cls(n)
