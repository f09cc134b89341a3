"""Safe reading and writing: atomic replaces, and weights as plain arrays (no pickle)."""
from __future__ import annotations

import copy
import json
import os
import tempfile
from pathlib import Path

import numpy as np
import torch

from ifo.data.npz import NPY_HEADER_LOCK


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write to a temporary file in the same folder, fsync, then rename over `path`.

    A crash at any moment leaves either the old file or the new one, never half of one.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; saved files should read like any other
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path: str | os.PathLike, obj, compact: bool = False) -> None:
    text = json.dumps(obj, separators=(",", ":")) if compact else json.dumps(obj, indent=1, sort_keys=True)
    atomic_write_text(path, text)


# zlib's level for what is written all the time (a Step's autosave, the iteration cache): the maze's
# images (I_s: 43 MB for 10x10) deflate in 0.14 s at 1 against 0.34 s at 6, a Step's whole wait when a
# student takes a ready iteration, for files half again as large (3.8 -> 5.7 MiB). Shipped files keep 6.
FAST_DEFLATE = 1


def npz_bytes(arrays: dict[str, np.ndarray], level: int = 6) -> bytes:
    """Arrays as an .npz (what numpy.load and ifo.data.npz read), without pickles. Floating-point arrays
    (weights, vector states) are stored: deflate shrinks them by a fifth at seven times the cost, and
    a Step's autosave and the iteration cache write them all the time. The rest (images, actions,
    counters) is deflated at zlib's `level`: the maze's images shrink many times."""
    import io
    import zipfile

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", allowZip64=True) as zf:
        for name, value in arrays.items():
            a = np.asanyarray(value)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))  # same arrays, same bytes
            if a.dtype.kind in "fc":
                info.compress_type = zipfile.ZIP_STORED
            else:
                info.compress_type = zipfile.ZIP_DEFLATED
                info._compresslevel = level  # the writer reads it here (public as compress_level from 3.13)
            with zf.open(info, "w", force_zip64=True) as f:
                np.lib.format.write_array(f, a, allow_pickle=False)
    return buf.getvalue()


def save_state_dict(path: str | os.PathLike, state: dict[str, torch.Tensor], meta: dict | None = None) -> None:
    """A torch state dict as a compressed .npz of arrays, plus an optional JSON `__meta__`."""
    arrays = {k: v.detach().cpu().numpy() for k, v in state.items()}
    if meta is not None:
        arrays["__meta__"] = np.array(json.dumps(meta))
    atomic_write_bytes(path, npz_bytes(arrays))


def load_state_dict(path: str | os.PathLike) -> tuple[dict[str, torch.Tensor], dict]:
    with NPY_HEADER_LOCK, np.load(path, allow_pickle=False) as data:  # each member's header is parsed as it is read
        meta = json.loads(str(data["__meta__"])) if "__meta__" in data.files else {}
        state = {k: torch.from_numpy(data[k].copy()) for k in data.files if k != "__meta__"}
    return state, meta


def module_arrays(prefix: str, module: torch.nn.Module) -> dict[str, np.ndarray]:
    """Copies (not views): training on afterwards must not change what was taken."""
    return {f"{prefix}.{k}": v.detach().cpu().numpy().copy() for k, v in module.state_dict().items()}


def load_module_arrays(prefix: str, module: torch.nn.Module, arrays: dict[str, np.ndarray]) -> None:
    start = prefix + "."
    state = {k[len(start):]: torch.from_numpy(np.array(v)) for k, v in arrays.items() if k.startswith(start)}
    module.load_state_dict(state)


def optimizer_arrays(prefix: str, optimizer: torch.optim.Optimizer) -> tuple[dict[str, np.ndarray], dict]:
    """An optimizer's tensors as arrays, and the rest (param groups) as JSON-able data."""
    sd = optimizer.state_dict()
    arrays = {}
    for idx, slots in sd["state"].items():
        for key, value in slots.items():
            arrays[f"{prefix}.{idx}.{key}"] = torch.as_tensor(value).detach().cpu().numpy().copy()
    return arrays, {"param_groups": copy.deepcopy(sd["param_groups"])}


def load_optimizer_arrays(prefix: str, optimizer: torch.optim.Optimizer, arrays: dict[str, np.ndarray],
                          meta: dict) -> None:
    state: dict[int, dict] = {}
    start = prefix + "."
    for k, v in arrays.items():
        if k.startswith(start):
            idx, key = k[len(start):].split(".", 1)
            state.setdefault(int(idx), {})[key] = torch.from_numpy(np.array(v))
    optimizer.load_state_dict({"state": state, "param_groups": meta["param_groups"]})
