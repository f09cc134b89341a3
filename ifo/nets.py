"""Networks: the inverse dynamics model M(a | s, s') and the policy pi(a | s).

Vector states use small MLPs (thesis Ch. 7: two hidden layers of 32). Image states
(the maze) use a compact residual CNN with two SAGAN self-attention modules after
its first two stages (Sec 5.4.1, Eqs 5.6-5.7). The IDM encodes s_t and s_{t+1} with
the same weights and concatenates the features.

Attention for vector states comes in two forms (`attention=`):
  "gated"    the authors' published module: on a C x 1 map its softmax runs over one
             element, so it reduces to x + gamma * (W_v x + b), gamma starting at 0.
  "features" real self-attention across the input's state variables (each variable is
             a token); its weights say which variables the model looks at.
Both start as the identity (gamma = 0), as in SAGAN.
"""
from __future__ import annotations

from contextlib import contextmanager
from contextvars import ContextVar

import torch
from torch import nn
import torch.nn.functional as F

ATTENTION_KINDS = ("none", "gated", "features")
_aten = torch.ops.aten


class Standardize(nn.Module):
    """Fixed input scaling from the data the model first sees (saved with the weights)."""

    def __init__(self, dim: int):
        super().__init__()
        self.register_buffer("mean", torch.zeros(dim))
        self.register_buffer("std", torch.ones(dim))

    def fit(self, x: torch.Tensor) -> None:
        self.mean.copy_(x.mean(0))
        self.std.copy_(x.std(0).clamp_min(1e-6))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.mean) / self.std


class GatedResidual(nn.Module):
    """The authors' vector 'self-attention': x + gamma * (W_v x + b), gamma = 0 at start."""

    def __init__(self, dim: int):
        super().__init__()
        self.value = nn.Linear(dim, dim)
        self.gamma = nn.Parameter(torch.zeros(1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.gamma * self.value(x)


class FeatureAttention(nn.Module):
    """Self-attention over state variables (Eqs 5.6-5.7 with the variables as positions).

    Each variable x_i becomes a token e_i = x_i * w_i + p_i; queries, keys and values are
    linear maps of the tokens; beta = softmax over variables; the attended value of each
    token is read back to one number and added: x + gamma * y, gamma = 0 at start.
    """

    def __init__(self, n_features: int, token_dim: int = 8):
        super().__init__()
        self.scale_embed = nn.Parameter(torch.randn(n_features, token_dim) * 0.5)
        self.position = nn.Parameter(torch.randn(n_features, token_dim) * 0.5)
        self.query = nn.Linear(token_dim, token_dim, bias=False)
        self.key = nn.Linear(token_dim, token_dim, bias=False)
        self.value = nn.Linear(token_dim, token_dim)
        self.readout = nn.Linear(token_dim, 1)
        self.gamma = nn.Parameter(torch.zeros(1))
        self.last_weights: torch.Tensor | None = None  # (batch, features, features)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        tokens = x.unsqueeze(-1) * self.scale_embed + self.position  # (B, n, k)
        q, k, v = self.query(tokens), self.key(tokens), self.value(tokens)
        beta = torch.softmax(q @ k.transpose(1, 2) / k.shape[-1] ** 0.5, dim=-1)  # Eq 5.6 + softmax
        self.last_weights = beta.detach()
        attended = self.readout(beta @ v).squeeze(-1)  # Eq 5.7
        return x + self.gamma * attended


class MLP(nn.Module):
    def __init__(self, in_dim: int, out_dim: int, hidden=(32, 32), attention: str = "none",
                 layer_norm: bool = False):
        super().__init__()
        if attention not in ATTENTION_KINDS:
            raise ValueError(f"attention must be one of {ATTENTION_KINDS}, not {attention!r}")
        self.standardize = Standardize(in_dim)
        self.feature_attention = FeatureAttention(in_dim) if attention == "features" else None
        layers: list[nn.Module] = []
        last = in_dim
        for h in hidden:
            layers.append(nn.Linear(last, h))
            if layer_norm:
                layers.append(nn.LayerNorm(h))
            layers.append(nn.ReLU())
            if attention == "gated":
                layers.append(GatedResidual(h))
            last = h
        layers.append(nn.Linear(last, out_dim))
        self.body = nn.Sequential(*layers)
        self.gate_effects: list | None = None  # gate_report() collects each gated block's effect here
        self._plan: list[tuple] | None = None

    # The body as a list of (kind, tensors...) built once. For layers this small, walking the modules
    # (isinstance, attribute lookups) costs as much as the arithmetic, at every environment step.
    # Parameters are updated in place (Adam, load_state_dict), so the plan stays valid; _apply
    # (module.to(), .double(), ...) may replace them, so it drops the plan.
    _LINEAR, _RELU, _GATED, _OTHER = range(4)

    def _layers(self) -> list[tuple]:
        if self._plan is None:
            plan = []
            for layer in self.body:
                if isinstance(layer, nn.Linear):
                    plan.append((self._LINEAR, layer.weight, layer.bias))
                elif isinstance(layer, nn.ReLU):
                    plan.append((self._RELU,))
                elif isinstance(layer, GatedResidual):
                    plan.append((self._GATED, layer.value.weight, layer.value.bias, layer.gamma))
                else:
                    plan.append((self._OTHER, layer))  # LayerNorm
            self._plan = plan
        return self._plan

    def _apply(self, fn, recurse=True):
        self._plan = None
        return super()._apply(fn, recurse)

    def forward(self, x: torch.Tensor, saved: list | None = None) -> torch.Tensor:
        """The logits. `saved`, when given, collects what `loss_and_gradients`' backward pass needs."""
        x = (x - self.standardize.mean) / self.standardize.std
        if self.feature_attention is not None:
            x = self.feature_attention(x)
        for layer in self._layers():
            kind = layer[0]
            if kind == self._LINEAR:
                if saved is not None:
                    saved.append((layer, x))
                x = F.linear(x, layer[1], layer[2])
            elif kind == self._RELU:
                x = F.relu(x)
                if saved is not None:
                    saved.append((layer, x))
            elif kind == self._GATED:  # x + gamma * (W_v x + b)
                value = F.linear(x, layer[1], layer[2])
                added = layer[3] * value
                if self.gate_effects is not None:
                    self.gate_effects.append(float(added.abs().mean() / x.abs().mean().clamp_min(1e-12)))
                if saved is not None:
                    saved.append((layer, (x, value)))
                x = x + added
            else:
                x = layer[1](x)
        return x

    def has_manual_gradients(self) -> bool:
        """True when `loss_and_gradients` knows every layer (Linear, ReLU, the gated block)."""
        return self.feature_attention is None and all(layer[0] != self._OTHER for layer in self._layers())

    @torch.no_grad()
    def loss_and_gradients(self, x: torch.Tensor, target: torch.Tensor,
                           weight: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Cross-entropy of `forward(x)` against `target`, its gradients written to each parameter's
        `.grad`; returns (loss, logits). Without autograd: for layers this small its bookkeeping costs
        more than the arithmetic. The backward pass calls the ATen kernels autograd would, on the same
        operands, so the gradients are identical to `loss.backward()`'s, bit for bit (tests/test_nets.py)."""
        saved: list = []
        logits = self.forward(x, saved)
        log_probs = torch.log_softmax(logits, 1)
        loss, total_weight = _aten.nll_loss_forward(log_probs, target, weight, 1, -100)  # 1: mean
        grad = _aten.nll_loss_backward(torch.ones_like(loss), log_probs, target, weight, 1, -100, total_weight)
        grad = _aten._log_softmax_backward_data(grad, log_probs, 1, log_probs.dtype)
        for k in range(len(saved) - 1, -1, -1):  # backward, as autograd's AddmmBackward etc. compute it
            layer, kept = saved[k]
            kind = layer[0]
            if kind == self._LINEAR:
                weight_, bias = layer[1], layer[2]
                weight_.grad = grad.t().mm(kept)
                bias.grad = grad.sum(0, keepdim=True).view(-1)
                if k:  # the input's gradient; none for the data
                    grad = grad.mm(weight_)
            elif kind == self._RELU:
                grad = _aten.threshold_backward(grad, kept, 0)
            else:
                value_weight, value_bias, gamma = layer[1], layer[2], layer[3]
                inner, value = kept
                gamma.grad = (grad * value).sum((0, 1), keepdim=True).view(1)
                grad_value = grad * gamma
                value_weight.grad = grad_value.t().mm(inner)
                value_bias.grad = grad_value.sum(0, keepdim=True).view(-1)
                grad = grad + grad_value.mm(value_weight)
        return loss, logits


# ----------------------------------------------------------------------------- images
class SelfAttention2d(nn.Module):
    """SAGAN self-attention (Eqs 5.6-5.7): 1x1 query/key to C/8, value; softmax over
    positions; output gamma * attention + x with gamma starting at 0."""

    def __init__(self, channels: int, reduction: int = 8):
        super().__init__()
        inner = max(1, channels // reduction)
        self.query = nn.Conv2d(channels, inner, 1)
        self.key = nn.Conv2d(channels, inner, 1)
        self.value = nn.Conv2d(channels, channels, 1)
        self.gamma = nn.Parameter(torch.zeros(1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, c, h, w = x.shape
        q = self.query(x).flatten(2).transpose(1, 2)  # (B, N, C')
        k = self.key(x).flatten(2)  # (B, C', N)
        beta = torch.softmax(q @ k, dim=-1)  # s_ij = f(x_i)^T g(x_j), softmax over positions
        v = self.value(x).flatten(2)  # (B, C, N)
        out = (v @ beta.transpose(1, 2)).view(b, c, h, w)
        return x + self.gamma * out


class ResBlock(nn.Module):
    def __init__(self, cin: int, cout: int, stride: int):
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(cout)
        self.conv2 = nn.Conv2d(cout, cout, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(cout)
        self.skip = (nn.Sequential(nn.Conv2d(cin, cout, 1, stride, bias=False), nn.BatchNorm2d(cout))
                     if stride != 1 or cin != cout else nn.Identity())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu(self.bn1(self.conv1(x)))
        return F.relu(self.bn2(self.conv2(y)) + self.skip(x))


class ImageEncoder(nn.Module):
    """Compact residual CNN: stem, three stages; SA after the first two stages."""

    def __init__(self, channels=(16, 32, 64), attention: bool = True):
        super().__init__()
        c1, c2, c3 = channels
        self.stem = nn.Sequential(nn.Conv2d(3, c1, 3, 2, 1, bias=False), nn.BatchNorm2d(c1), nn.ReLU())
        self.stage1 = ResBlock(c1, c1, 2)
        self.attn1 = SelfAttention2d(c1) if attention else nn.Identity()
        self.stage2 = ResBlock(c1, c2, 2)
        self.attn2 = SelfAttention2d(c2) if attention else nn.Identity()
        self.stage3 = ResBlock(c2, c3, 2)
        self.out_dim = c3

    def forward(self, img: torch.Tensor) -> torch.Tensor:
        x = img.permute(0, 3, 1, 2).float() / 255.0 if img.dtype == torch.uint8 else img
        x = self.attn1(self.stage1(self.stem(x)))
        x = self.attn2(self.stage2(x))
        return F.adaptive_avg_pool2d(self.stage3(x), 1).flatten(1)

    @property
    def last_conv(self) -> nn.Module:
        return self.stage3.conv2


_DROPOUT_MASKS: ContextVar[torch.Generator | None] = ContextVar("dropout_masks", default=None)


@contextmanager
def dropout_masks_from(generator: torch.Generator):
    """Within it, every `RunDropout` of this thread draws its masks from `generator` (a run's own)."""
    token = _DROPOUT_MASKS.set(generator)
    try:
        yield
    finally:
        _DROPOUT_MASKS.reset(token)


class RunDropout(nn.Dropout):
    """nn.Dropout whose masks come from the generator of `dropout_masks_from`, the training run's own, not
    torch's process-wide one: two maze runs' steps (the app's sessions, in threads of one process) then
    train at once and each keeps its numbers. The masks are nn.Dropout's from a generator in the same state
    (torch's CPU dropout: bernoulli_(1 - p) divided by 1 - p); outside that context it is nn.Dropout."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        generator = _DROPOUT_MASKS.get()
        if generator is None or not self.training or not 0 < self.p < 1:
            return super().forward(x)
        return x * torch.empty_like(x).bernoulli_(1 - self.p, generator=generator).div_(1 - self.p)


def uses_dropout(module: nn.Module) -> bool:
    """Whether training `module` draws random masks from torch's global generator (torch's nn.Dropout, or
    an RNN's dropout between its layers; not `RunDropout`, whose masks come from the run's generator)."""
    return any((isinstance(m, nn.modules.dropout._DropoutNd) and not isinstance(m, RunDropout) and m.p > 0)
               or (isinstance(m, nn.RNNBase) and m.dropout > 0) for m in module.modules())


def _head(in_dim: int, n_actions: int, hidden: int = 128) -> nn.Module:
    return nn.Sequential(nn.Linear(in_dim, hidden), nn.LeakyReLU(), RunDropout(0.5), nn.Linear(hidden, n_actions))


# ----------------------------------------------------------------------------- models
class _StateModel(nn.Module):
    """The shape the IDM and the policy share: image states through the residual encoder and a dropout
    head, vector states through an MLP; `frames` states side by side (the IDM's two, the policy's one)."""

    def __init__(self, obs_shape: tuple[int, ...], n_actions: int, frames: int, hidden=(32, 32),
                 attention: str = "none", layer_norm: bool = False):
        super().__init__()
        self.is_image = len(obs_shape) == 3
        if self.is_image:
            self.encoder = ImageEncoder(attention=attention != "none")
            self.head = _head(frames * self.encoder.out_dim, n_actions)
        else:
            self.mlp = MLP(frames * obs_shape[0], n_actions, hidden, attention, layer_norm)

    def mlp_input(self, *states: torch.Tensor) -> torch.Tensor:
        """What the MLP sees (vector states): `fit` trains it on this by hand."""
        raise NotImplementedError

    def fit_input_scaling(self, *states: torch.Tensor) -> None:
        if not self.is_image:
            self.mlp.standardize.fit(self.mlp_input(*states))


class InverseDynamics(_StateModel):
    """M_theta(a | s_t, s_{t+1}). Vector input: [s_t, s_{t+1} - s_t] (the change carries the action)."""

    def __init__(self, obs_shape: tuple[int, ...], n_actions: int, hidden=(32, 32), attention: str = "none",
                 layer_norm: bool = False):
        super().__init__(obs_shape, n_actions, 2, hidden, attention, layer_norm)

    def mlp_input(self, s: torch.Tensor, s2: torch.Tensor) -> torch.Tensor:
        return torch.cat([s, s2 - s], dim=-1)

    def forward(self, s: torch.Tensor, s2: torch.Tensor) -> torch.Tensor:
        if self.is_image:
            both = self.encoder(torch.cat([s, s2]))  # shared weights on both frames
            return self.head(torch.cat(both.split(len(s)), dim=-1))
        return self.mlp(self.mlp_input(s, s2))


class Policy(_StateModel):
    """pi_phi(a | s)."""

    def __init__(self, obs_shape: tuple[int, ...], n_actions: int, hidden=(32, 32), attention: str = "none",
                 layer_norm: bool = False):
        super().__init__(obs_shape, n_actions, 1, hidden, attention, layer_norm)

    def mlp_input(self, s: torch.Tensor) -> torch.Tensor:
        return s

    def forward(self, s: torch.Tensor) -> torch.Tensor:
        if self.is_image:
            return self.head(self.encoder(s))
        return self.mlp(s)


def feature_attention_map(model: nn.Module) -> torch.Tensor | None:
    """Mean attention each state variable receives in the last forward pass (vector models)."""
    mlp = getattr(model, "mlp", None)
    att = getattr(mlp, "feature_attention", None) if mlp is not None else None
    if att is None or att.last_weights is None:
        return None
    return att.last_weights.mean(dim=(0, 1))


@torch.no_grad()
def gate_report(model: nn.Module, *inputs: torch.Tensor, max_samples: int = 512) -> list[dict] | None:
    """What each gated attention block (attention="gated") does on these inputs: its gamma, and
    the size of what it adds, mean |gamma * (W_v h + b)| over mean |h| (0: the block is the
    identity). None for models without such blocks. Runs the model on at most `max_samples`."""
    blocks = [m for m in model.modules() if isinstance(m, GatedResidual)]
    mlp = getattr(model, "mlp", None)
    if not blocks or mlp is None:
        return None
    was_training = model.training
    mlp.gate_effects = seen = []
    try:
        model.eval()
        model(*(torch.as_tensor(x[:max_samples], dtype=torch.float32) for x in inputs))
    finally:
        mlp.gate_effects = None
        model.train(was_training)
    return [{"block": k, "gamma": round(float(b.gamma), 6), "effect": round(seen[k] if k < len(seen) else 0.0, 6)}
            for k, b in enumerate(blocks)]
