"""SAIL's two extra models and the memory they learn from (thesis Ch. 9, Sec 9.1-9.2).

    Generator      G(s_{t+1} | s_t, π(s_t)): an MLP of two hidden layers of 2 x (|s| + 1) units, no
                   attention, no normalisation layers; its input is [s_t, the policy's logits] and its
                   output the next state (Eq 9.2 measures it by the squared error).
    Discriminator  D: an LSTM of two layers of 32 units (dropout 0.5 between them) over a sequence of
                   states, one teacher-or-student output per step.
    EpisodeMemory  the replay buffer RB of the policy's trajectories (Sec 9.1), as state sequences;
                   D trains each iteration on a few windows drawn from T_e and from RB.

Variable lengths are handled honestly (the published code padded the student's sequences, so
the padding itself told D which was which): sequences are packed (`pack_padded_sequence`), the
LSTM never reads a padded step, and the loss and every score count real steps only. D is causal
(one direction), so at step t it knows nothing of how long the sequence will be.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn
from torch.nn.utils.rnn import pack_padded_sequence, pad_packed_sequence

from ifo.nets import MLP, Standardize


# ----------------------------------------------------------------------------- the generator
class Generator(nn.Module):
    """G(s_{t+1} | s_t, π(s_t)) for vector states (Sec 9.2).

    Internally the MLP reads standardised states and predicts the change s_{t+1} - s_t in units of
    the typical change per variable (fixed at construction from T_e): the action's effect on a
    variable is then of the order of one unit whatever the environment's scale (MountainCar's
    velocity changes by 0.001 per step). `forward` returns s_{t+1} in the environment's units.
    """

    def __init__(self, state_dim: int, n_actions: int, hidden: int | None = None):
        super().__init__()
        width = hidden or 2 * (state_dim + 1)
        self.state_dim = state_dim
        self.net = MLP(state_dim + n_actions, state_dim, (width, width), attention="none", layer_norm=False)
        self.register_buffer("delta_mean", torch.zeros(state_dim))
        self.register_buffer("delta_std", torch.ones(state_dim))

    def fit_scaling(self, states: torch.Tensor, next_states: torch.Tensor) -> None:
        """Input scaling of the states (the logits' part stays as it is) and the typical change."""
        delta = next_states - states
        self.net.standardize.mean[: self.state_dim] = states.mean(0)
        self.net.standardize.std[: self.state_dim] = states.std(0).clamp_min(1e-6)
        self.delta_mean.copy_(delta.mean(0))
        self.delta_std.copy_(delta.std(0).clamp_min(1e-6))

    def scaled_change(self, states: torch.Tensor, logits: torch.Tensor) -> torch.Tensor:
        return self.net(torch.cat([states, logits], dim=-1))

    def forward(self, states: torch.Tensor, logits: torch.Tensor) -> torch.Tensor:
        return states + self.delta_mean + self.delta_std * self.scaled_change(states, logits)

    def losses(self, states: torch.Tensor, logits: torch.Tensor,
               next_states: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(training loss, Eq 9.2's squared error in the environment's units). The training loss is the
        squared error of the change in typical-change units, so every variable counts (same minimum)."""
        scaled = self.scaled_change(states, logits)
        target = (next_states - states - self.delta_mean) / self.delta_std
        with torch.no_grad():  # G(s, π(s)) - s' = delta_std * (scaled - target)
            error = ((scaled - target) * self.delta_std).square().mean()
        return F.mse_loss(scaled, target), error


# ----------------------------------------------------------------------------- the discriminator
class Discriminator(nn.Module):
    """D: is this sequence of states the teacher's? An LSTM (2 x 32, dropout 0.5), one logit per step."""

    def __init__(self, state_dim: int, hidden: int = 32, layers: int = 2, dropout: float = 0.5):
        super().__init__()
        self.standardize = Standardize(state_dim)
        self.lstm = nn.LSTM(state_dim, hidden, num_layers=layers, dropout=dropout if layers > 1 else 0.0,
                            batch_first=True)
        self.head = nn.Linear(hidden, 1)

    def fit_input_scaling(self, states: torch.Tensor) -> None:
        self.standardize.fit(states)

    def forward(self, padded: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
        """Per-step logits (batch, max length) of P(teacher); entries past a sequence's length are 0
        and must be masked (`step_mask`)."""
        packed = pack_padded_sequence(self.standardize(padded), lengths.cpu(), batch_first=True,
                                      enforce_sorted=False)
        out, _ = self.lstm(packed)
        out, _ = pad_packed_sequence(out, batch_first=True, total_length=padded.shape[1])
        return self.head(out).squeeze(-1) * step_mask(lengths, padded.shape[1])


def step_mask(lengths: torch.Tensor, total: int) -> torch.Tensor:
    return (torch.arange(total)[None, :] < lengths[:, None]).float()


def pad(sequences: Sequence[np.ndarray]) -> tuple[torch.Tensor, torch.Tensor]:
    """A batch of variable-length state sequences as (padded tensor, lengths). The padding is zeros,
    never read by the LSTM (packed) nor counted by any loss or score."""
    lengths = torch.as_tensor([len(s) for s in sequences], dtype=torch.long)
    out = torch.zeros(len(sequences), int(lengths.max()), sequences[0].shape[-1])
    for i, s in enumerate(sequences):
        out[i, : len(s)] = torch.as_tensor(s, dtype=torch.float32)
    return out, lengths


def masked_mean(values: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    return (values * mask).sum() / mask.sum().clamp_min(1.0)


def discriminator_loss(d: Discriminator, teacher: Sequence[np.ndarray],
                       student: Sequence[np.ndarray]) -> torch.Tensor:
    """Eq 9.1 from D's side: -[log D(teacher) + log(1 - D(student))], per real step; each side's steps
    averaged on their own, so short student sequences weigh as much as long teacher ones."""
    x, lengths = pad(list(teacher) + list(student))
    logits = d(x, lengths)
    mask = step_mask(lengths, x.shape[1])
    n = len(teacher)
    return (masked_mean(F.softplus(-logits[:n]), mask[:n])  # -log D(teacher)
            + masked_mean(F.softplus(logits[n:]), mask[n:]))  # -log(1 - D(student))


def train_discriminator(d: Discriminator, optimizer: torch.optim.Optimizer, teacher_pool: Sequence[np.ndarray],
                        student_pool: Sequence[np.ndarray], updates: int, batch: int, window: int,
                        rng: np.random.Generator) -> float:
    """`updates` Adam steps, each on `batch` windows of at most `window` states cut from randomly chosen
    teacher and student sequences (a small subset each time, Sec 9.1). Returns the mean loss."""
    d.train()
    losses = []
    for _ in range(updates):
        loss = discriminator_loss(d, sample_windows(teacher_pool, batch, window, rng),
                                  sample_windows(student_pool, batch, window, rng))
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    return float(np.mean(losses)) if losses else float("nan")


@torch.no_grad()
def teacher_probability(d: Discriminator, sequences: Sequence[np.ndarray], window: int,
                        chunk: int = 256) -> np.ndarray:
    """Per sequence: D's mean per-step probability that it is the teacher's. Long sequences are read in
    consecutive tiles of at most `window` states, the lengths D trained on."""
    if len(sequences) == 0:
        return np.zeros(0)
    d.eval()
    tiles, owner = [], []
    for k, s in enumerate(sequences):
        for start in range(0, len(s), window):
            tiles.append(s[start:start + window])
            owner.append(k)
    owner = np.asarray(owner)
    total, steps = np.zeros(len(sequences)), np.zeros(len(sequences))
    for start in range(0, len(tiles), chunk):
        x, lengths = pad(tiles[start:start + chunk])
        p = torch.sigmoid(d(x, lengths)) * step_mask(lengths, x.shape[1])
        np.add.at(total, owner[start:start + chunk], p.sum(1).numpy())
        np.add.at(steps, owner[start:start + chunk], lengths.numpy())
    return total / np.maximum(steps, 1)


def accept(d: Discriminator, sequences: Sequence[np.ndarray], window: int, threshold: float = 0.5) -> np.ndarray:
    """Line 12 of Algorithm 9.1: which sequences D takes for the teacher's (mask)."""
    return teacher_probability(d, sequences, window) >= threshold


# ----------------------------------------------------------------------------- sequences and windows
def split_episodes(states: np.ndarray, next_states: np.ndarray, episode_index: np.ndarray) -> list[np.ndarray]:
    """Transitions grouped by episode (in time order) as state sequences s_0, ..., s_T (the last next state
    closes each sequence)."""
    out = []
    if len(states) == 0:
        return out
    bounds = np.flatnonzero(np.diff(episode_index)) + 1
    for idx in np.split(np.arange(len(states)), bounds):
        out.append(np.concatenate([states[idx], next_states[idx[-1:]]]).astype(np.float32))
    return out


def sample_windows(pool: Sequence[np.ndarray], n: int, window: int, rng: np.random.Generator) -> list[np.ndarray]:
    """`n` windows of at most `window` states: a sequence drawn uniformly, then a start drawn uniformly
    among the positions that leave a full window (a shorter sequence is taken whole)."""
    picks = rng.integers(0, len(pool), n)
    out = []
    for k in picks:
        s = pool[k]
        start = int(rng.integers(0, max(1, len(s) - window + 1)))
        out.append(s[start:start + window])
    return out


class EpisodeMemory:
    """RB: the policy's trajectories as state sequences, the oldest leaving first once more than
    `capacity` states are kept (the newest sequence always stays)."""

    def __init__(self, capacity: int):
        self.capacity = int(capacity)
        self.sequences: list[np.ndarray] = []

    def __len__(self) -> int:
        """States held."""
        return int(sum(len(s) for s in self.sequences))

    def add(self, sequences: Sequence[np.ndarray]) -> None:
        self.sequences = self.sequences + [np.asarray(s, dtype=np.float32) for s in sequences]
        total = len(self)
        while len(self.sequences) > 1 and total > self.capacity:
            total -= len(self.sequences[0])
            self.sequences = self.sequences[1:]

    def sample(self, n: int, window: int, rng: np.random.Generator) -> list[np.ndarray]:
        return sample_windows(self.sequences, n, window, rng)

    def arrays(self, prefix: str) -> dict[str, np.ndarray]:
        """Copies of the contents (for checkpoints and for undoing an iteration)."""
        lengths = np.array([len(s) for s in self.sequences], dtype=np.int64)
        states = (np.concatenate(self.sequences) if self.sequences else np.zeros((0, 0), dtype=np.float32))
        return {f"{prefix}states": states.copy(), f"{prefix}lengths": lengths}

    def load_arrays(self, arrays: dict[str, np.ndarray], prefix: str) -> None:
        lengths = np.asarray(arrays[f"{prefix}lengths"], dtype=np.int64)
        states = np.asarray(arrays[f"{prefix}states"], dtype=np.float32)
        self.sequences = [s.copy() for s in np.split(states, np.cumsum(lengths)[:-1])] if len(lengths) else []
