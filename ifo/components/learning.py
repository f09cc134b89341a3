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
    # images stay uint8 until the encoder (4x less memory); vectors become float32. Read-only arrays (data
    # shared between sessions: the iteration cache's, I_pre's) are copied: torch has no read-only tensors.
    if isinstance(x, np.ndarray) and not x.flags.writeable:
        x = np.array(x)
    return torch.from_numpy(np.ascontiguousarray(x)) if x.dtype == np.uint8 else torch.as_tensor(x, dtype=torch.float32)


def make_optimizer(module: torch.nn.Module, lr: float) -> torch.optim.Optimizer:
    # fused: one kernel per update for all tensors, the fastest of Adam's forms on the CPU
    # (`python -m ifo bench speed`); its numbers differ from the per-tensor loop in the last digits
    return torch.optim.Adam(module.parameters(), lr=lr, fused=True)


def warm_up() -> None:
    """Pay a process's one-time cost of training now: torch loads its compiler (torch._dynamo) at the
    first Adam step of a process, 1-4 s on this machine. The app calls this once its first page is
    drawn, so the class's first Step does not wait for it. No random numbers are drawn."""
    weight = torch.nn.Parameter(torch.zeros(1))
    weight.grad = torch.zeros(1)
    torch.optim.Adam([weight], lr=1e-3, fused=True).step()  # as `make_optimizer`'s Adam steps


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
    per_epoch = torch.tensor(targets, dtype=torch.long)  # a copy: the labels may be shared, read-only
    if per_epoch.ndim == 1:
        per_epoch = per_epoch.expand(max(1, epochs), -1)
    elif len(per_epoch) != max(1, epochs):
        raise ValueError(f"{len(per_epoch)} rows of targets for {epochs} epochs")
    weight = None if class_weights is None else torch.as_tensor(class_weights, dtype=torch.float32)
    n = per_epoch.shape[1]
    mlp = _hand_trainable_mlp(forward, module)
    if mlp is not None:  # vector models: the MLP's input once, gradients by hand (the same numbers, faster)
        xs = [module.mlp_input(*xs)]
    step = optimizer_step(optimizer)
    loss_sum, correct = torch.zeros(()), torch.zeros((), dtype=torch.long)
    for y in per_epoch:
        # summed as tensors, read once at the end: a .item() per step would wait on every step
        loss_sum, correct = torch.zeros(()), torch.zeros((), dtype=torch.long)
        order = torch.randperm(n, generator=generator)
        if mlp is not None:  # shuffled once per pass, then contiguous slices: the same batches, no gather per step
            xs_epoch, y_epoch = [x[order] for x in xs], y[order]
        for start in range(0, n, batch_size):
            if min(batch_size, n - start) < 2 <= n:
                continue  # BatchNorm cannot train on a single sample
            if mlp is not None:
                target = y_epoch[start:start + batch_size]
                loss, logits = mlp.loss_and_gradients(xs_epoch[0][start:start + batch_size], target, weight)
            else:
                idx = order[start:start + batch_size]
                logits = forward(*(x[idx] for x in xs))
                target = y[idx]
                loss = F.cross_entropy(logits, target, weight=weight)
                optimizer.zero_grad(set_to_none=True)
                loss.backward()
            if clip_value is not None:
                torch.nn.utils.clip_grad_value_(module.parameters(), clip_value)
            step()
            with torch.no_grad():
                loss_sum += loss.detach() * len(target)
                correct += (logits.argmax(-1) == target).sum()
    return FitResult(float(loss_sum) / max(n, 1), float(correct) / max(n, 1))


def _hand_trainable_mlp(forward: Forward, module: torch.nn.Module):
    """The module's MLP when `fit` may train it by hand (`MLP.loss_and_gradients`): a vector IDM or policy
    trained through its own forward, every layer one the hand-written backward pass knows."""
    mlp = getattr(module, "mlp", None)  # image models have none
    if forward is not module or mlp is None or not hasattr(module, "mlp_input") or not mlp.has_manual_gradients():
        return None
    return mlp if all(p.requires_grad for p in module.parameters()) else None


def optimizer_step(optimizer: torch.optim.Optimizer) -> Callable[[], None]:
    """`optimizer.step`, or for `make_optimizer`'s fused Adam the same two kernels it runs without its
    per-call bookkeeping (the floor line of `python -m ifo bench speed`; identical numbers, tests/test_nets.py)."""
    groups = optimizer.param_groups
    group = groups[0] if len(groups) == 1 else {}
    plain_fused_adam = (type(optimizer) is torch.optim.Adam and group.get("fused") and not group["amsgrad"]
                        and not group["maximize"] and not group["capturable"] and not group["differentiable"]
                        and not group.get("decoupled_weight_decay", False) and group["weight_decay"] == 0
                        and isinstance(group["lr"], float) and not optimizer._optimizer_step_pre_hooks
                        and not optimizer._optimizer_step_post_hooks)
    if not plain_fused_adam or not hasattr(torch, "_fused_adam_"):
        return optimizer.step
    params = group["params"]
    lists = []

    def step() -> None:
        if not lists:  # the first step through Adam itself: it creates the state as it always does
            optimizer.step()
            states = [optimizer.state.get(p, {}) for p in params]
            if all("step" in st for st in states) and all(p.grad is not None for p in params):
                lists.extend([[st["exp_avg"] for st in states], [st["exp_avg_sq"] for st in states],
                              [st["step"] for st in states]])
            return
        grads = [p.grad for p in params]
        if any(g is None for g in grads):  # a parameter this step did not reach: Adam skips it, so must we
            optimizer.step()
            return
        exp_avgs, exp_avg_sqs, steps = lists
        beta1, beta2 = group["betas"]
        torch._foreach_add_(steps, 1)
        torch._fused_adam_(params, grads, exp_avgs, exp_avg_sqs, [], steps, amsgrad=False,
                           lr=group["lr"], beta1=beta1, beta2=beta2, weight_decay=0.0, eps=group["eps"],
                           maximize=False, grad_scale=None, found_inf=None)

    return step


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
