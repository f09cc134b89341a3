"""A replay memory of the policy's own transitions (s, a, r, s', done): a ring buffer of fixed
capacity, sampled uniformly (DQN's experience replay, thesis Sec 8.1.2).

Our own few lines rather than stable-baselines3's ReplayBuffer: its samples come from numpy's
global generator (ours from the run's named streams: same seed, same numbers) and its contents
must be saved with the run's checkpoint and put back when an iteration is undone.
"""
from __future__ import annotations

import numpy as np


class ReplayMemory:
    def __init__(self, capacity: int, obs_shape: tuple[int, ...], obs_dtype=np.float32):
        """`obs_dtype`: the observations' own (the maze's images are uint8, which the CNN reads as pixels)."""
        self.capacity = int(capacity)
        self.states = np.zeros((self.capacity, *obs_shape), dtype=obs_dtype)
        self.next_states = np.zeros_like(self.states)
        self.actions = np.zeros(self.capacity, dtype=np.int64)
        self.rewards = np.zeros(self.capacity, dtype=np.float32)
        self.dones = np.zeros(self.capacity, dtype=np.float32)
        self.position = 0  # where the next transition goes
        self.size = 0

    def __len__(self) -> int:
        return self.size

    def add(self, states, actions, rewards, next_states, dones) -> None:
        """Append transitions; the oldest are overwritten once the memory is full."""
        for k in range(len(actions)):
            i = self.position
            self.states[i], self.next_states[i] = states[k], next_states[k]
            self.actions[i], self.rewards[i], self.dones[i] = actions[k], rewards[k], dones[k]
            self.position = (i + 1) % self.capacity
            self.size = min(self.size + 1, self.capacity)

    def sample(self, batch_size: int, rng: np.random.Generator):
        """(states, actions, rewards, next states, dones) of `batch_size` transitions drawn uniformly."""
        idx = rng.integers(0, self.size, min(batch_size, self.size))
        return self.states[idx], self.actions[idx], self.rewards[idx], self.next_states[idx], self.dones[idx]

    def arrays(self, prefix: str) -> dict[str, np.ndarray]:
        """Copies of the contents (the memory changes in place), for checkpoints and undo."""
        n = self.size
        return {f"{prefix}states": self.states[:n].copy(), f"{prefix}next_states": self.next_states[:n].copy(),
                f"{prefix}actions": self.actions[:n].copy(), f"{prefix}rewards": self.rewards[:n].copy(),
                f"{prefix}dones": self.dones[:n].copy(), f"{prefix}position": np.array(self.position)}

    def load_arrays(self, arrays: dict[str, np.ndarray], prefix: str) -> None:
        n = len(arrays[f"{prefix}actions"])
        if n > self.capacity:
            raise ValueError(f"a replay memory of {n} transitions does not fit a capacity of {self.capacity}")
        for name in ("states", "next_states", "actions", "rewards", "dones"):
            getattr(self, name)[:n] = arrays[f"{prefix}{name}"]
        self.size, self.position = n, int(arrays[f"{prefix}position"])
