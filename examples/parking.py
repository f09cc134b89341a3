"""Your own environment in IfO Lab, end to end: a car on a track that must stop on a marked spot.

Importing this module registers the environment with gymnasium and with IfO Lab
(`ifo.envs.register_env`), so it is named `examples.parking:parking` everywhere: on the
command line, in a `RunConfig` and in the runs saved with it. A method learns it from
demonstrations you bring; this module also makes some, from a hand-written controller:

    python -m examples.parking runs/parking-demos.npz --episodes 50
    python -m ifo train --env examples.parking:parking --method iupe --demos runs/parking-demos.npz

    from ifo.config import RunConfig
    from ifo.run import Run
    run = Run(RunConfig(env="examples.parking:parking", method="iupe", demos="runs/parking-demos.npz"))
"""
from __future__ import annotations

import argparse
from pathlib import Path

import gymnasium as gym
import numpy as np

from ifo.envs import reached_terminal, register_env

GYM_ID = "ifo-examples/Parking-v0"
MAX_STEPS = 200


class Parking(gym.Env):
    """State: (position, velocity, the spot's position), all in [0, 1] but the velocity. Actions:
    0 brake / reverse, 1 coast, 2 accelerate. The episode ends when the car stands on the spot
    (+1); every other step costs 0.01."""

    observation_space = gym.spaces.Box(np.array([0.0, -0.1, 0.0], np.float32), np.array([1.0, 0.1, 1.0], np.float32))
    action_space = gym.spaces.Discrete(3)
    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(self, render_mode: str | None = None):
        self.render_mode = render_mode

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.x, self.v = float(self.np_random.uniform(0.0, 1.0)), 0.0
        self.spot = float(self.np_random.uniform(0.1, 0.9))
        while abs(self.x - self.spot) < 0.2:  # start away from the spot
            self.x = float(self.np_random.uniform(0.0, 1.0))
        return self._obs(), {}

    def step(self, action):
        self.v = float(np.clip(0.9 * self.v + 0.02 * (int(action) - 1), -0.1, 0.1))
        self.x = self.x + self.v
        if not 0.0 <= self.x <= 1.0:  # the track's ends stop the car
            self.x, self.v = float(np.clip(self.x, 0.0, 1.0)), 0.0
        parked = abs(self.x - self.spot) < 0.03 and abs(self.v) < 0.01
        return self._obs(), (1.0 if parked else -0.01), parked, False, {}

    def _obs(self) -> np.ndarray:
        return np.array([self.x, self.v, self.spot], dtype=np.float32)

    def render(self) -> np.ndarray:
        """The track (grey), the spot (green) and the car (blue) on it, 400 x 100 pixels."""
        frame = np.full((100, 400, 3), 255, np.uint8)
        frame[58:62] = 170
        spot, car = (int(10 + 380 * p) for p in (self.spot, self.x))
        frame[36:58, spot - 7:spot + 7] = (60, 170, 80)
        frame[42:56, car - 10:car + 10] = (40, 90, 200)
        return frame


def controller(obs: np.ndarray) -> int:
    """The demonstrator: head for the spot, braking ahead of it."""
    x, v, spot = (float(o) for o in obs)
    push = (spot - x) - 2.0 * v
    return 2 if push > 0.01 else 0 if push < -0.01 else 1


def demonstrations(episodes: int = 50, seed: int = 0) -> dict[str, np.ndarray]:
    """The controller's episodes in the layout `ifo` reads (obs, next_obs, actions, rewards,
    episode_starts; the actions are only shown against, never learnt from, by the IfO methods)."""
    env = gym.make(GYM_ID)
    arrays: dict[str, list] = {k: [] for k in ("obs", "next_obs", "actions", "rewards", "episode_starts")}
    for episode in range(episodes):
        obs, _ = env.reset(seed=seed + episode)
        done, first = False, True
        while not done:
            action = controller(obs)
            next_obs, reward, terminated, truncated, _ = env.step(action)
            for key, value in zip(arrays, (obs, next_obs, action, reward, first)):
                arrays[key].append(value)
            obs, done, first = next_obs, terminated or truncated, False
    env.close()
    return {"obs": np.array(arrays["obs"], np.float32), "next_obs": np.array(arrays["next_obs"], np.float32),
            "actions": np.array(arrays["actions"], np.int64), "rewards": np.array(arrays["rewards"], np.float32),
            "episode_starts": np.array(arrays["episode_starts"], bool)}


if GYM_ID not in gym.registry:
    gym.register(GYM_ID, entry_point=Parking, max_episode_steps=MAX_STEPS)
register_env("parking", GYM_ID, goal=reached_terminal, action_names=("brake", "coast", "accelerate"),
             feature_names=("position", "velocity", "spot"), title="Parking")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description="write the parking controller's demonstrations as .npz")
    parser.add_argument("out", type=Path)
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    d = demonstrations(args.episodes, args.seed)
    np.savez(args.out, **d)
    print(f"wrote {args.out}: {args.episodes} episodes, {len(d['obs'])} transitions, "
          f"mean return {d['rewards'].sum() / args.episodes:.3f}")
