"""Supervised learning shared by the IDM (Eq 5.1) and the policy (Eq 5.2): maximum
likelihood = cross-entropy on labelled samples, Adam, mini-batches."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import torch
import torch.nn.functional as F

Forward = Callable[..., torch.Tensor]


@dataclass
class FitResult:
    loss: float
    accuracy: float


def as_tensor(x: np.ndarray) -> torch.Tensor:
    # images stay uint8 until the encoder (4x less memory); vectors become float32
    return torch.from_numpy(np.ascontiguousarray(x)) if x.dtype == np.uint8 else torch.as_tensor(x, dtype=torch.float32)


def make_optimizer(module: torch.nn.Module, lr: float) -> torch.optim.Optimizer:
    # fused: one kernel per update for all tensors, the fastest of Adam's forms on the CPU
    # (`python -m ifo bench speed`); its numbers differ from the per-tensor loop in the last digits
    return torch.optim.Adam(module.parameters(), lr=lr, fused=True)


def fit(forward: Forward, module: torch.nn.Module, optimizer: torch.optim.Optimizer,
        inputs: Sequence[np.ndarray], targets: np.ndarray, epochs: int, batch_size: int,
        generator: torch.Generator, class_weights: np.ndarray | None = None,
        clip_value: float | None = None) -> FitResult:
    """Train `forward(*inputs) -> logits` on integer `targets`; returns the last epoch's mean loss/accuracy.

    `targets` is one label per sample, or one row of labels per epoch (epochs x samples):
    labels drawn afresh for each pass, as exploration draws them from the IDM's softmax.
    `clip_value` clips every gradient component to [-clip_value, clip_value] (CRIL, Sec 8.3).
    """
    module.train()
    xs = [as_tensor(x) for x in inputs]
    per_epoch = torch.as_tensor(targets, dtype=torch.long)
    if per_epoch.ndim == 1:
        per_epoch = per_epoch.expand(max(1, epochs), -1)
    elif len(per_epoch) != max(1, epochs):
        raise ValueError(f"{len(per_epoch)} rows of targets for {epochs} epochs")
    weight = None if class_weights is None else torch.as_tensor(class_weights, dtype=torch.float32)
    n = per_epoch.shape[1]
    loss_sum, correct = torch.zeros(()), torch.zeros((), dtype=torch.long)
    for y in per_epoch:
        # summed as tensors, read once at the end: a .item() per step would wait on every step
        loss_sum, correct = torch.zeros(()), torch.zeros((), dtype=torch.long)
        order = torch.randperm(n, generator=generator)
        for start in range(0, n, batch_size):
            idx = order[start:start + batch_size]
            if len(idx) < 2 and n >= 2:
                continue  # BatchNorm cannot train on a single sample
            logits = forward(*(x[idx] for x in xs))
            target = y[idx]
            loss = F.cross_entropy(logits, target, weight=weight)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            if clip_value is not None:
                torch.nn.utils.clip_grad_value_(module.parameters(), clip_value)
            optimizer.step()
            with torch.no_grad():
                loss_sum += loss.detach() * len(idx)
                correct += (logits.argmax(-1) == target).sum()
    return FitResult(float(loss_sum) / max(n, 1), float(correct) / max(n, 1))


@torch.inference_mode()
def predict_proba(forward: Forward, module: torch.nn.Module, inputs: Sequence[np.ndarray],
                  batch_size: int = 2048) -> np.ndarray:
    # called once per environment step during runs: keep the per-call overhead small
    if module.training:
        module.eval()
    n = len(inputs[0])
    if 0 < n <= batch_size:
        return torch.softmax(forward(*(as_tensor(x) for x in inputs)), -1).numpy()
    out = []
    for start in range(0, n, batch_size):
        logits = forward(*(as_tensor(x[start:start + batch_size]) for x in inputs))
        out.append(torch.softmax(logits, -1).numpy())
    return np.concatenate(out) if out else np.zeros((0, 0), dtype=np.float32)
