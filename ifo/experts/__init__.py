"""Expert policies: trained networks for the control tasks, shortest paths for the maze.

Experts are only used to make demonstrations and reference returns; learners never
call them. Weights are shipped as .npz arrays (see `ifo.io`), never pickles.

Levels (thesis Ch. 7, Table 7.1): `assets/experts/<env>-level<K>.npz` for K = 1..5, level 1 the
best. Levels 2-5 are checkpoints of one stable-baselines3 training run per environment, chosen so
that their AER matches the thesis's (`python -m ifo experts train --env ENV --level 2-5`);
`assets/experts/levels.json` holds what each shipped level measures (`level_info`).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch
from torch import nn

from ifo.envs import ASSETS, EnvSpec, get_env
from ifo.io import load_state_dict, save_state_dict

EXPERTS_DIR = ASSETS / "experts"
LEVELS_FILE = EXPERTS_DIR / "levels.json"
LEVELS = (1, 2, 3, 4, 5)
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


def check_level(level) -> int:
    """A level number 1..5 (ValueError in plain words otherwise)."""
    if isinstance(level, bool) or not isinstance(level, (int, np.integer)) or int(level) not in LEVELS:
        raise ValueError(f"expert level must be a whole number from 1 to 5, got {level!r}")
    return int(level)


def expert_path(spec: EnvSpec, level: int = 1) -> Path:
    return EXPERTS_DIR / f"{spec.name}-level{check_level(level)}.npz"


def load_expert(env: str | EnvSpec, level: int = 1):
    """The expert for an environment (level 1 the best, 5 the worst of Table 7.1): an object with
    `act(observations) -> actions`. The maze has one expert (shortest paths) and no levels."""
    spec = get_env(env) if isinstance(env, str) else env
    level = check_level(level)
    if spec.is_maze:
        if level != 1:
            raise ValueError(f"{spec.name} has one expert (shortest paths): no level {level}")
        from ifo.envs.maze import ShortestPathExpert

        return ShortestPathExpert()
    path = expert_path(spec, level)
    if not path.exists():
        raise FileNotFoundError(
            f"no expert weights at {path}; regenerate with "
            f"`python -m ifo experts train --env {spec.name} --level {level}`")
    return ExpertMLP.load(path)


def load_levels() -> dict:
    """What every shipped expert level measures: env -> level ("1".."5") -> dict (levels.json)."""
    return json.loads(LEVELS_FILE.read_text()) if LEVELS_FILE.exists() else {}


def level_info(env: str | EnvSpec, level: int) -> dict:
    """One shipped level's measurements: `aer`/`std` on the 100 evaluation episodes (held-out seeds 10^9 + k:
    what Performance normalises by), the thesis's `target`, the training `steps` of the checkpoint, and
    `demos_episodes`/`demos_mean_return` of its demonstrations (training seeds 0, 1, ...). {} when that
    level was not made."""
    spec = get_env(env) if isinstance(env, str) else env
    return dict(load_levels().get(spec.name, {}).get(str(check_level(level)), {}))
