"""Writer processes for tests/test_checkpoint.py (a helper, not a test file).

    python tests/checkpoint_worker.py pairs ROOT FOLDERS SAVES WORKER OVERWRITE
        one of two writers (WORKER 0 or 1) that meet on ROOT/run000, run001, ... (a file barrier
        per folder) and save SAVES times each; on RunChanged it "reloads" (goes on from the other
        writer's latest save), as a user would. Prints its counts as JSON.
    python tests/checkpoint_worker.py loop RUN
        saves RUN over and over until killed; prints "go" once it starts.
"""
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from ifo import checkpoint  # noqa: E402

SIZE = 16_384


def payload(i: int, rng: np.random.Generator | None = None, size: int = SIZE) -> dict:
    """A synthetic checkpoint whose parts agree: i records, meta iteration i, arrays["i"] == [i]."""
    rng = rng if rng is not None else np.random.default_rng(i)
    return {"config": {"env": "cartpole", "method": "bco", "seed": 0, "iterations": 10_000},
            "records": [{"iteration": k + 1, "evaluation": {"aer": float(k), "performance": None, "goal_rate": 0.5}}
                        for k in range(i)],
            "arrays": {"w": rng.random(size, dtype=np.float32), "i": np.array([i])},
            "meta": {"iteration": i}}


def consistent(ckpt: checkpoint.Checkpoint) -> bool:
    """All parts of one checkpoint come from the same save (nothing mixed, nothing half-written)."""
    i = ckpt.meta["iteration"]
    ok = len(ckpt.records) == i
    if ckpt.arrays is not None:
        ok = ok and int(ckpt.arrays["i"][0]) == i and ckpt.arrays["w"].dtype == np.float32
    return ok


def _wait_for(path: Path, timeout: float = 30.0) -> None:
    end = time.monotonic() + timeout
    while not path.exists():
        if time.monotonic() > end:
            raise TimeoutError(path)
        time.sleep(0.0005)


def pairs(root: Path, folders: int, saves: int, worker: int, overwrite: bool) -> dict:
    counts = {"ok": 0, "changed": 0, "busy": 0}
    rng = np.random.default_rng(worker)
    for k in range(folders):
        run = root / f"run{k:03d}"
        (root / f"ready{k}.{worker}").touch()
        _wait_for(root / f"ready{k}.{1 - worker}")
        parent, i = None, 0
        for _ in range(saves):
            i += 1
            try:
                parent = checkpoint.save(run, **payload(i, rng), parent=parent, overwrite=overwrite, lock_timeout=5)
                counts["ok"] += 1
            except checkpoint.RunChanged:
                counts["changed"] += 1
                ckpt = checkpoint.load(run, with_arrays=False)  # the user reloads the run
                parent, i = ckpt.name, len(ckpt.records)
            except checkpoint.RunBusy:
                counts["busy"] += 1
    return counts


def loop(run: Path) -> None:
    rng = np.random.default_rng()
    ckpt = checkpoint.load(run, with_arrays=False)
    parent, i = ckpt.name, len(ckpt.records)
    print("go", flush=True)
    while True:
        i += 1
        parent = checkpoint.save(run, **payload(i, rng, size=4 * SIZE), parent=parent)


if __name__ == "__main__":
    if sys.argv[1] == "pairs":
        root, folders, saves, worker, overwrite = sys.argv[2:7]
        print(json.dumps(pairs(Path(root), int(folders), int(saves), int(worker), overwrite == "1")))
    else:
        loop(Path(sys.argv[2]))
