"""The discriminator of the adversarial methods (GAIL Sec 3.3, GAIfO Sec 3.4) and the reward it gives.

    D(s, x) = sigmoid(logit): the probability that the sample came from the expert
        GAIL   x = a          (state-action pairs: needs the expert's actions)
        GAIfO  x = s'         (state transitions: the expert's states only)

    trained by logistic regression, expert = 1, agent = 0 (Eq 3.7 with the labels written the
    `imitation` library's way, "expert is high"):
        L_D = -E_expert[log D] - E_agent[log(1 - D)]

    the generator's reward, one of
        "positive"  -log(1 - D) = softplus(logit)       > 0   (GAIL's reward; rewards surviving)
        "logit"     log D - log(1 - D) = logit               (AIRL-style; no sign bias)
        "negative"  log D = -softplus(-logit)           < 0   (rewards ending episodes early)

Inputs are standardised by the expert's statistics (saved with the weights) and clipped to ±10, so a
state the expert never saw cannot blow the logits up. GAIfO's second input is the change of state
s' - s rather than s' itself: the change is what an action does, and standardised on its own it is not
drowned by the much larger spread of the states.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

DISCRIMINATOR_INPUTS = ("state-action", "state-transition")
REWARDS = ("positive", "logit", "negative")
INPUT_LABELS = {"state-action": "(s, a): the expert's actions (GAIL)",
                "state-transition": "(s, s'): the expert's states only (GAIfO)"}
REWARD_LABELS = {"positive": "−log(1 − D): always positive (GAIL's; rewards surviving)",
                 "logit": "log D − log(1 − D): no sign bias (AIRL-style)",
                 "negative": "log D: always negative (rewards ending early)"}
CLIP = 10.0


class Discriminator(nn.Module):
    """D(s, x) as a logit: high when (s, x) looks like the expert's."""

    def __init__(self, obs_dim: int, n_actions: int, inputs: str, hidden=(64, 64)):
        super().__init__()
        if inputs not in DISCRIMINATOR_INPUTS:
            raise ValueError(f"discriminator inputs must be one of {DISCRIMINATOR_INPUTS}, not {inputs!r}")
        self.inputs, self.n_actions = inputs, n_actions
        in_dim = obs_dim + (n_actions if inputs == "state-action" else obs_dim)
        self.register_buffer("mean", torch.zeros(in_dim))
        self.register_buffer("std", torch.ones(in_dim))
        layers: list[nn.Module] = []
        last = in_dim
        for h in hidden:
            layers += [nn.Linear(last, h), nn.ReLU()]
            last = h
        layers.append(nn.Linear(last, 1))
        self.body = nn.Sequential(*layers)

    def features(self, s: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """[s, one-hot a] for GAIL, [s, s' - s] for GAIfO (unscaled)."""
        s = s.float()
        if self.inputs == "state-action":
            return torch.cat([s, F.one_hot(x.long().reshape(-1), self.n_actions).float()], -1)
        return torch.cat([s, x.float() - s], -1)

    def fit_input_scaling(self, s: torch.Tensor, x: torch.Tensor) -> None:
        """Standardise by the expert's statistics (one-hot actions stay as they are)."""
        f = self.features(s, x)
        mean, std = f.mean(0), f.std(0).clamp_min(1e-6) if len(f) > 1 else torch.ones(f.shape[1])
        if self.inputs == "state-action":
            mean[-self.n_actions:], std[-self.n_actions:] = 0.0, 1.0
        self.mean.copy_(mean)
        self.std.copy_(std)

    def forward(self, s: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        z = ((self.features(s, x) - self.mean) / self.std).clamp(-CLIP, CLIP)
        return self.body(z).squeeze(-1)


def reward_from_logits(logits: torch.Tensor, kind: str) -> torch.Tensor:
    """The generator's reward for each sample (see the module docstring)."""
    if kind == "positive":
        return F.softplus(logits)
    if kind == "logit":
        return logits
    if kind == "negative":
        return -F.softplus(-logits)
    raise ValueError(f"reward must be one of {REWARDS}, not {kind!r}")


@torch.inference_mode()
def logits_of(d: Discriminator, s: np.ndarray, x: np.ndarray, batch: int = 8192) -> np.ndarray:
    d.eval()
    out = [d(torch.as_tensor(s[i:i + batch]), torch.as_tensor(x[i:i + batch])).numpy()
           for i in range(0, len(s), batch)]
    return np.concatenate(out) if out else np.zeros(0, dtype=np.float32)


@dataclass
class DiscriminatorFit:
    loss: float
    accuracy_expert: float  # share of expert samples D calls expert (after this training)
    accuracy_agent: float  # share of agent samples D calls agent


def train_discriminator(d: Discriminator, optimizer: torch.optim.Optimizer, expert: tuple[np.ndarray, np.ndarray],
                        agent: tuple[np.ndarray, np.ndarray], updates: int, batch_size: int,
                        rng: np.random.Generator) -> DiscriminatorFit:
    """`updates` Adam steps, each on `batch_size` expert and `batch_size` agent samples drawn at random
    (the two halves weigh the same however many samples each side has)."""
    es, ex = (torch.as_tensor(a) for a in expert)
    as_, ax = (torch.as_tensor(a) for a in agent)
    ones, zeros = torch.ones(batch_size), torch.zeros(batch_size)
    d.train()
    losses = []
    for _ in range(updates):
        ie = torch.as_tensor(rng.integers(0, len(es), batch_size))
        ia = torch.as_tensor(rng.integers(0, len(as_), batch_size))
        loss = 0.5 * (F.binary_cross_entropy_with_logits(d(es[ie], ex[ie]), ones)
                      + F.binary_cross_entropy_with_logits(d(as_[ia], ax[ia]), zeros))
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    return DiscriminatorFit(float(np.mean(losses)) if losses else float("nan"),
                            float(np.mean(logits_of(d, *expert) > 0)), float(np.mean(logits_of(d, *agent) < 0)))
