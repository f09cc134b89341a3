"""Probes: what the networks look at (Sec 6.4.1, Fig 6.1) and how close the policy's
samples come to the expert's (Sec 5.5.2, Fig 5.3).

Pure library code: numbers and lists for the run's records, no figures, no app.

  maze_probes / maze_probe_frames   a fixed set of maze frames, the same every iteration
  grad_cam_maps                     Grad-CAM of the policy's chosen action on those frames
  grad_cam_probe_record             both of the above, ready for record["attention"]["grad_cam"]
  action_mean_image_distances       Fig 5.3: per action, how far the policy's mean image is
                                    from the expert's, 0 = expert, 1 = random (I_pre)
  vector_attention                  the attention over state variables of a vector model
"""
from __future__ import annotations

import copy

import numpy as np
import torch
from torch import nn

from ifo.envs.maze import OPEN_BIT, ROW_STEP, COL_STEP, layout_pool, render_maze, shortest_path_actions
from ifo.nets import feature_attention_map

MAP_RESOLUTION = 16  # stored Grad-CAM maps are (16, 16): small records, still readable
DECIMALS = 3


# --------------------------------------------------------------------------- probe frames

def _open_sides(layout: np.ndarray, cell: tuple[int, int]) -> int:
    return sum(1 for bit in OPEN_BIT if layout[cell] & bit)


def _path_cells(layout: np.ndarray) -> list[tuple[int, int]]:
    """Cells of the shortest path from the start, the goal left out (the episode ends there)."""
    cells = [(0, 0)]
    for a in shortest_path_actions(layout)[:-1]:
        r, c = cells[-1]
        cells.append((r + ROW_STEP[a], c + COL_STEP[a]))
    return cells


def maze_probes(size: int, count: int = 6, loops: float = 0.0) -> list[dict]:
    """Where the probe frames come from: eval layouts, cells on their shortest paths.

    Probe k uses eval layout k (cycling when the pool is smaller than `count`) and wants a
    junction (3 or 4 open sides: the agent must choose) for even k and a corridor (2 open
    sides) for odd k, at a point along the path that moves from the start towards the goal
    as k grows. When the path has no cell of the wanted kind, any path cell serves. Cells
    already used are skipped, so the probes are distinct. Deterministic: no randomness.
    """
    size, count = int(size), int(count)
    if count < 1:
        raise ValueError(f"count must be at least 1, got {count}")
    pool = layout_pool(size, "eval", loops)
    used: set[tuple[int, int, int]] = set()
    probes: list[dict] = []
    attempt = 0
    while len(probes) < count and attempt < count * len(pool) + count:
        k = len(probes)
        index = attempt % len(pool)
        attempt += 1
        layout = pool[index]
        cells = [cell for cell in _path_cells(layout) if (index, *cell) not in used]
        if not cells:
            continue
        wanted = "junction" if k % 2 == 0 else "corridor"
        is_kind = (lambda n: n >= 3) if wanted == "junction" else (lambda n: n == 2)
        candidates = [cell for cell in cells if is_kind(_open_sides(layout, cell))] or cells
        target = (k + 1) / (count + 1) * (len(cells) - 1)  # spread along the path
        cell = min(candidates, key=lambda c: (abs(cells.index(c) - target), cells.index(c)))
        open_n = _open_sides(layout, cell)
        kind = "start" if cell == (0, 0) else "junction" if open_n >= 3 else "corridor" if open_n == 2 else "dead end"
        used.add((index, *cell))
        probes.append({"layout_index": index, "position": [int(cell[0]), int(cell[1])], "kind": kind})
    return probes


def maze_probe_frames(size: int, image_size: int, count: int = 6, loops: float = 0.0) -> np.ndarray:
    """The fixed probe set as images: uint8 (count, image_size, image_size, 3).

    The same frames every call (and so every iteration), rendered exactly as MazeEnv
    renders observations; see `maze_probes` for where they are taken.
    """
    pool = layout_pool(int(size), "eval", loops)
    return np.stack([render_maze(pool[p["layout_index"]], tuple(p["position"]), int(image_size))
                     for p in maze_probes(size, count, loops)])


# --------------------------------------------------------------------------- Grad-CAM

def _downsample(maps: np.ndarray, resolution: int) -> np.ndarray:
    """(B, H, W) -> (B, r, r) by area averaging, each map rescaled so its peak stays 1."""
    import cv2

    out = np.stack([cv2.resize(m.astype(np.float32), (resolution, resolution), interpolation=cv2.INTER_AREA)
                    for m in maps]) if len(maps) else np.zeros((0, resolution, resolution), np.float32)
    peak = out.reshape(len(out), -1).max(axis=1, initial=0.0)
    out = np.where(peak[:, None, None] > 0, out / np.maximum(peak, 1e-12)[:, None, None], 0.0)
    return np.clip(out, 0.0, 1.0)


def default_target_layer(policy: nn.Module) -> nn.Module:
    """The layer Grad-CAM reads for an image Policy: the output of the last residual stage.

    That is the map the global average pool (and so the head) sees; it includes the skip
    path, which `encoder.last_conv` (stage3.conv2, before its BatchNorm and the skip sum)
    leaves out. Same convention as pytorch-grad-cam's ResNet recipe (model.layer4[-1]).
    """
    encoder = getattr(policy, "encoder", None)
    if encoder is None:
        raise ValueError("Grad-CAM needs an image policy (one with a CNN encoder); vector policies have "
                         "attention over their state variables instead, see vector_attention")
    return encoder.stage3


def _find_by_identity(root: nn.Module, module: nn.Module) -> str:
    for name, m in root.named_modules():
        if m is module:
            return name
    raise ValueError("target_layer is not a submodule of the model")


def grad_cam_maps(policy: nn.Module, frames: np.ndarray, target_layer: nn.Module | None = None,
                  resolution: int = MAP_RESOLUTION) -> dict:
    """Grad-CAM (Fig 6.1) of the policy's chosen (MAP) action on each frame.

    frames: uint8 (B, H, W, 3), as the environment gives them (or float NCHW in [0, 1]).
    target_layer: defaults to `default_target_layer(policy)`; for other models, any conv
    layer (or block) of `policy`.

    Returns plain lists for a record:
      maps           B maps of (resolution, resolution) in [0, 1], row 0 = the image's top,
                     each normalised on its own (as pytorch-grad-cam does), 3 decimals
      raw_max        per frame, the largest value of the map before that normalisation
                     (ReLU of the gradient-weighted activations), to compare across iterations
      actions        the MAP action per frame (the class the map explains)
      probabilities  per frame, the policy's softmax

    Safe to call between training steps: it works on a private deep copy of the policy,
    so the live model keeps its weights, BatchNorm statistics, gradients (.grad), train or
    eval mode and hooks; the copy is in eval mode (BatchNorm uses its running statistics,
    dropout is off) and its hooks are released by the context manager. Deterministic.
    """
    from pytorch_grad_cam import GradCAM

    target_layer = default_target_layer(policy) if target_layer is None else target_layer
    layer_name = _find_by_identity(policy, target_layer)
    frames = np.asarray(frames)
    if len(frames) == 0:
        return {"maps": [], "raw_max": [], "actions": [], "probabilities": []}

    # A private copy: GradCAM calls .eval(), zero_grad() and backward() on the model it gets.
    model = copy.deepcopy(policy)
    model.eval()
    for p in model.parameters():
        p.requires_grad_(True)  # gradients must reach the target layer even if the live model is frozen
    layer = dict(model.named_modules())[layer_name]
    device = next(model.parameters()).device
    x = torch.as_tensor(frames)
    if x.dtype == torch.uint8:  # NHWC bytes -> NCHW float in [0, 1], as ImageEncoder does
        x = x.permute(0, 3, 1, 2).float() / 255.0
    x = x.to(device).float().requires_grad_(True)

    with GradCAM(model=model, target_layers=[layer]) as cam:  # releases the hooks on exit
        maps = cam(input_tensor=x, targets=None)  # None: explain each frame's MAP (argmax) action
        probs = torch.softmax(cam.outputs.detach().float(), dim=-1).cpu().numpy()
        actions = probs.argmax(axis=-1)
        # Raw Grad-CAM (before the per-map normalisation): ReLU(sum_c mean(grad_c) * A_c).
        acts = cam.activations_and_grads.activations[0].numpy()
        grads = cam.activations_and_grads.gradients[0].numpy()
        raw = np.maximum((grads.mean(axis=(2, 3), keepdims=True) * acts).sum(axis=1), 0.0)
    small = _downsample(np.asarray(maps), int(resolution))
    return {
        "maps": np.round(small, DECIMALS).tolist(),
        "raw_max": [float(f"{v:.6g}") for v in raw.reshape(len(raw), -1).max(axis=1)],
        "actions": [int(a) for a in actions],
        "probabilities": np.round(probs, 4).tolist(),
    }


def grad_cam_probe_record(policy: nn.Module, size: int, image_size: int, count: int = 6,
                          loops: float = 0.0) -> dict:
    """record["attention"]["grad_cam"] for a maze run: the maps on the fixed probe frames (of the
    run's maze world: perfect, or braided with `loops`), plus where the probes are (so the app can
    redraw the frames with `maze_probe_frames`)."""
    out = grad_cam_maps(policy, maze_probe_frames(size, image_size, count, loops))
    out["probes"] = maze_probes(size, count, loops)
    out["size"], out["image_size"], out["loops"] = int(size), int(image_size), float(loops)
    return out


# --------------------------------------------------------------------------- Fig 5.3

def _class_means(states: np.ndarray, actions: np.ndarray, n_actions: int, chunk: int = 1024):
    """Mean state (flattened, float64) and sample count per action, in chunks (bounded memory)."""
    states = np.asarray(states)
    actions = np.asarray(actions).astype(np.int64).ravel()
    if len(states) != len(actions):
        raise ValueError(f"{len(states)} states but {len(actions)} actions")
    dim = int(np.prod(states.shape[1:])) if states.ndim > 1 else 1
    sums = np.zeros((n_actions, dim))
    counts = np.bincount(actions[(actions >= 0) & (actions < n_actions)], minlength=n_actions)[:n_actions]
    for start in range(0, len(states), chunk):
        block = states[start:start + chunk].reshape(-1, dim).astype(np.float64)
        acts = actions[start:start + chunk]
        one_hot = (acts[:, None] == np.arange(n_actions)).astype(np.float64)
        sums += one_hot.T @ block  # per-action sums as one matrix product
    means = [sums[a] / counts[a] if counts[a] else None for a in range(n_actions)]
    return means, counts


def action_mean_image_distances(pre_states, pre_actions, pos_states, pos_actions, expert_states, expert_actions,
                                n_actions: int) -> dict:
    """Fig 5.3 (Sec 5.5.2): per action, how close the policy's runs come to the expert's images.

    For action a, with m_X(a) the mean image (state) of the samples of a in set X:

        distance[a] = || m_pos(a) - m_expert(a) ||_2 / || m_pre(a) - m_expert(a) ||_2

    so 0 is the expert's mean image and 1 the random policy's (I_pre). I_pos is the
    policy's runs of this iteration. None when I_pos, I_pre or the expert has no sample of
    a, or when I_pre's mean already equals the expert's (nothing to normalise by).

    `expert_actions` are the expert's hidden TRUE actions. They are used only here, for a
    diagnostic figure shown to people; nothing learns from them (IfO never sees them).

    Returns {"distance": [per action float or None], "pos_counts": [samples per action in I_pos]}.
    """
    n_actions = int(n_actions)
    pre, _ = _class_means(pre_states, pre_actions, n_actions)
    pos, pos_counts = _class_means(pos_states, pos_actions, n_actions)
    exp, _ = _class_means(expert_states, expert_actions, n_actions)
    distance: list[float | None] = []
    for a in range(n_actions):
        if pos[a] is None or pre[a] is None or exp[a] is None:
            distance.append(None)
            continue
        scale = float(np.linalg.norm(pre[a] - exp[a]))
        distance.append(None if scale <= 1e-12 else round(float(np.linalg.norm(pos[a] - exp[a])) / scale, 4))
    return {"distance": distance, "pos_counts": [int(c) for c in pos_counts]}


# --------------------------------------------------------------------------- vector attention

def vector_attention(model: nn.Module) -> list | None:
    """Mean attention per state variable in the model's last forward pass (attention="features"),
    as a list for records; None for models without feature attention or before any forward pass.
    For the IDM the variables are [s, s' - s]."""
    att = feature_attention_map(model)
    return None if att is None else [float(v) for v in att.tolist()]


__all__ = ["maze_probes", "maze_probe_frames", "default_target_layer", "grad_cam_maps", "grad_cam_probe_record",
           "action_mean_image_distances", "vector_attention", "MAP_RESOLUTION"]


# --------------------------------------------------------------------------- Figs 8.2, 8.3, Table 8.1

POLICY_MAP_CELLS = 20  # the thesis discretised MountainCar into a 20 x 20 table


def _softmax(x: np.ndarray) -> np.ndarray:
    z = np.exp(x - x.max(-1, keepdims=True))
    return z / z.sum(-1, keepdims=True)


def policy_map_record(probabilities, axes, reference: nn.Module | None = None, cells: int = POLICY_MAP_CELLS) -> dict:
    """record["policy_map"]: the policy over a cells x cells grid of two state variables.

    `probabilities(states) -> (n, |A|)` is the learner's policy; `axes` is ((index, name, low, high),
    (index, name, low, high)) from the EnvSpec (other variables 0). `reference` is a network whose
    outputs are Q-values or logits (the shipped DQN expert): its softmax is pi*, as Table 8.1 uses.

        kl        mean over the grid of KL(pi* || pi)
        onehot_kl mean of KL(onehot(argmax pi*) || pi) = -log pi(argmax pi* | s): the greedy comparison
    """
    (ix, x_name, x_lo, x_hi), (iy, y_name, y_lo, y_hi) = axes
    xs, ys = np.linspace(x_lo, x_hi, cells), np.linspace(y_lo, y_hi, cells)
    gx, gy = np.meshgrid(xs, ys)  # rows: y, columns: x
    states = np.zeros((cells * cells, max(ix, iy) + 1), dtype=np.float32)
    states[:, ix], states[:, iy] = gx.ravel(), gy.ravel()
    p = np.clip(np.asarray(probabilities(states), dtype=np.float64), 1e-8, 1.0)
    out = {"x_name": x_name, "y_name": y_name, "x": [round(float(v), 5) for v in xs],
           "y": [round(float(v), 5) for v in ys],
           "action": p.argmax(-1).reshape(cells, cells).tolist(),
           "probability": np.round(p.max(-1), 4).reshape(cells, cells).tolist(),
           "reference_action": None, "kl": None, "onehot_kl": None}
    if reference is not None:
        with torch.no_grad():
            q = reference(torch.as_tensor(states)).numpy().astype(np.float64)
        ref = np.clip(_softmax(q), 1e-8, 1.0)
        best = ref.argmax(-1)
        out["reference_action"] = best.reshape(cells, cells).tolist()
        out["kl"] = round(float(np.mean(np.sum(ref * (np.log(ref) - np.log(p)), -1))), 5)
        out["onehot_kl"] = round(float(np.mean(-np.log(p[np.arange(len(p)), best]))), 5)
    return out
