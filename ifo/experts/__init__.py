"""Expert policies: trained networks for the control tasks, shortest paths for the maze.

Experts are only used to make demonstrations and reference returns; learners never
call them. Weights are shipped as .npz arrays (see `ifo.io`), never pickles.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import nn

from ifo.envs import ASSETS, EnvSpec, get_env
from ifo.io import load_state_dict, save_state_dict

EXPERTS_DIR = ASSETS / "experts"
ACTIVATIONS = {"tanh": nn.Tanh, "relu": nn.ReLU}


class ExpertMLP(nn.Module):
    """The expert's network: an MLP whose argmax output is the greedy action.

    Outputs are action logits (PPO) or Q-values (DQN); either way the expert acts greedily.
    """

    def __init__(self, in_dim: int, hidden: list[int], n_actions: int, activation: str = "tanh"):
        super().__init__()
        layers: list[nn.Module] = []
        last = in_dim
        for h in hidden:
            layers += [nn.Linear(last, h), ACTIVATIONS[activation]()]
            last = h
        layers.append(nn.Linear(last, n_actions))
        self.net = nn.Sequential(*layers)
        self.meta = {"in_dim": in_dim, "hidden": list(hidden), "n_actions": n_actions, "activation": activation}

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)

    @torch.no_grad()
    def act(self, obs: np.ndarray) -> np.ndarray:
        x = torch.as_tensor(np.asarray(obs, dtype=np.float32))
        return self(x).argmax(-1).numpy()

    def save(self, path: str | Path, extra_meta: dict | None = None) -> None:
        save_state_dict(path, self.state_dict(), {**self.meta, **(extra_meta or {})})

    @classmethod
    def load(cls, path: str | Path) -> "ExpertMLP":
        state, meta = load_state_dict(path)
        model = cls(meta["in_dim"], meta["hidden"], meta["n_actions"], meta["activation"])
        model.load_state_dict(state)
        model.meta = meta
        return model.eval()


def expert_path(spec: EnvSpec, level: int = 1) -> Path:
    return EXPERTS_DIR / f"{spec.name}-level{level}.npz"


def load_expert(env: str | EnvSpec, level: int = 1):
    """The expert for an environment: an object with `act(observations) -> actions`."""
    spec = get_env(env) if isinstance(env, str) else env
    if spec.is_maze:
        from ifo.envs.maze import ShortestPathExpert

        return ShortestPathExpert()
    path = expert_path(spec, level)
    if not path.exists():
        raise FileNotFoundError(
            f"no expert weights at {path}; regenerate with `python -m ifo experts train --env {spec.name}`")
    return ExpertMLP.load(path)
