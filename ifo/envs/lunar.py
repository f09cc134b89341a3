"""LunarLander-v3 stepped without gymnasium's per-step overhead, on gymnasium's own Box2D worlds.

No batched Box2D exists, so each episode keeps its own `LunarLander` (reset by gymnasium with the
episode's seed: the same terrain, the same initial push, the same random stream). What is left out
of a step is what does not move the lander: the wrappers (order check, passive checker, time limit:
counted here instead), the action-space check, the numpy scalars of the state and the reward, and
the decorative particles (gymnasium adds none without a render mode either). What stays is
gymnasium's arithmetic in its own order (`gymnasium/envs/box2d/lunar_lander.py`, `step`), so the
observations, rewards and ends are bit for bit the real environment's (tests/test_batched.py).

For the discrete, windless LunarLander-v3 only (the one the thesis uses); other settings step gymnasium.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from gymnasium.envs.box2d import lunar_lander as ll

_MAIN_Y = ll.MAIN_ENGINE_Y_LOCATION / ll.SCALE
_HALF_W = ll.VIEWPORT_W / ll.SCALE / 2
_HALF_H = ll.VIEWPORT_H / ll.SCALE / 2
_DT = 1.0 / ll.FPS


def supports(env) -> bool:
    """Whether `env` (a made LunarLander) steps the way this module does: discrete actions, no wind."""
    inner = env.unwrapped
    return isinstance(inner, ll.LunarLander) and not inner.continuous and not inner.enable_wind


class LunarLanderStepper:
    """Steps episodes `idx` of `envs` (one gymnasium LunarLander per episode); see the module's docstring."""

    def __init__(self, envs: list, step_limit: int):
        self.envs = envs
        self.landers = [env.unwrapped for env in envs]
        self.step_limit = step_limit
        self.steps = np.zeros(len(envs), dtype=np.int64)

    def reset(self, seeds: Sequence[int]) -> np.ndarray:
        if len(seeds) != len(self.envs):
            raise ValueError(f"stepper made for {len(self.envs)} episodes, got {len(seeds)} seeds")
        self.steps[:] = 0
        return np.stack([env.reset(seed=int(s))[0] for env, s in zip(self.envs, seeds)])

    def step(self, idx, actions):
        n = len(idx)
        obs = np.empty((n, 8), dtype=np.float32)
        rewards = np.empty(n, dtype=np.float64)
        terminated = np.zeros(n, dtype=bool)
        for j, (i, a) in enumerate(zip(idx.tolist(), actions.tolist())):
            if not 0 <= a < 4:
                raise ValueError(f"LunarLander has actions 0-3, got {a}")
            obs[j], rewards[j], terminated[j] = _step(self.landers[i], a)
        self.steps[idx] += 1
        truncated = self.steps[idx] >= self.step_limit  # gymnasium's TimeLimit, also on a terminating step
        return obs, rewards, terminated, truncated, [{}] * n

    def render(self, i: int) -> np.ndarray:
        from ifo.envs.drawing import render_frame

        return render_frame(self.envs[i])


def _step(env, action: int):
    """`LunarLander.step` for a discrete action without wind, operation for operation."""
    lander = env.lander
    angle = lander.angle
    tip = (math.sin(angle), math.cos(angle))
    side = (-tip[1], tip[0])
    d0, d1 = env.np_random.uniform(-1.0, +1.0, 2).tolist()  # the two draws gymnasium makes one at a time
    dispersion = (d0 / ll.SCALE, d1 / ll.SCALE)

    m_power = 0.0
    if action == 2:
        m_power = 1.0
        ox = tip[0] * (_MAIN_Y + 2 * dispersion[0]) + side[0] * dispersion[1]
        oy = -tip[1] * (_MAIN_Y + 2 * dispersion[0]) - side[1] * dispersion[1]
        position = lander.position
        impulse_pos = (position[0] + ox, position[1] + oy)
        lander.ApplyLinearImpulse((-ox * ll.MAIN_ENGINE_POWER * m_power, -oy * ll.MAIN_ENGINE_POWER * m_power),
                                  impulse_pos, True)

    s_power = 0.0
    if action == 1 or action == 3:
        direction = action - 2
        s_power = 1.0
        ox = tip[0] * dispersion[0] + side[0] * (3 * dispersion[1] + direction * ll.SIDE_ENGINE_AWAY / ll.SCALE)
        oy = -tip[1] * dispersion[0] - side[1] * (3 * dispersion[1] + direction * ll.SIDE_ENGINE_AWAY / ll.SCALE)
        position = lander.position
        impulse_pos = (position[0] + ox - tip[0] * 17 / ll.SCALE,
                       position[1] + oy + tip[1] * ll.SIDE_ENGINE_HEIGHT / ll.SCALE)
        lander.ApplyLinearImpulse((-ox * ll.SIDE_ENGINE_POWER * s_power, -oy * ll.SIDE_ENGINE_POWER * s_power),
                                  impulse_pos, True)

    env.world.Step(_DT, 6 * 30, 2 * 30)

    pos = lander.position
    vel = lander.linearVelocity
    s0 = (pos.x - _HALF_W) / _HALF_W
    s1 = (pos.y - (env.helipad_y + ll.LEG_DOWN / ll.SCALE)) / _HALF_H
    s2 = vel.x * _HALF_W / ll.FPS
    s3 = vel.y * _HALF_H / ll.FPS
    s4 = lander.angle
    s5 = 20.0 * lander.angularVelocity / ll.FPS
    s6 = 1.0 if env.legs[0].ground_contact else 0.0
    s7 = 1.0 if env.legs[1].ground_contact else 0.0

    shaping = (-100 * math.sqrt(s0 * s0 + s1 * s1) - 100 * math.sqrt(s2 * s2 + s3 * s3)
               - 100 * abs(s4) + 10 * s6 + 10 * s7)
    reward = 0
    if env.prev_shaping is not None:
        reward = shaping - env.prev_shaping
    env.prev_shaping = shaping
    reward -= m_power * 0.30
    reward -= s_power * 0.03

    terminated = False
    if env.game_over or abs(s0) >= 1.0:
        terminated, reward = True, -100
    if not lander.awake:
        terminated, reward = True, +100
    return (s0, s1, s2, s3, s4, s5, s6, s7), reward, terminated
