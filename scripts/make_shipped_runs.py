"""Train the finished example runs the app ships, so a class starts with results on screen.

    PYTHONPATH=. SDL_VIDEODRIVER=dummy .venv/bin/python scripts/make_shipped_runs.py [--only NAME ...] [--out DIR]

Each run is the thesis's main configuration with the environment's default number of
iterations, seed 0, trained from scratch and saved with `Run.save` into
`assets/runs/<name>/` (config.json, LATEST, ckpt-*/) plus a `label.json` holding its
display name. The app's run list shows them as "Example runs"; opening one copies it
into the user's own folder, so a teacher can scrub through it and continue training.

The whole set takes a few minutes on one core; the script prints each run's time, final
AER/Performance and folder size, and checks that `Run.load` reads it back.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ifo.config import RunConfig  # noqa: E402
from ifo.io import atomic_write_json, atomic_write_text  # noqa: E402
from ifo.run import Run  # noqa: E402
from ifo.runtime import limit_threads  # noqa: E402
from ifo.ui.storage import SHIPPED_RUNS, folder_bytes  # noqa: E402

# name -> (configuration, display name). Seed 0, default iterations (a full run).
SHIPPED: dict[str, tuple[RunConfig, str]] = {
    "cartpole-iupe": (RunConfig(env="cartpole", method="iupe"), "IUPE on CartPole"),
    "cartpole-bco-alpha": (RunConfig(env="cartpole", method="bco-alpha"), "BCO(α) on CartPole"),
    "cartpole-bc": (RunConfig(env="cartpole", method="bc"), "BC on CartPole (uses the expert's actions)"),
    "acrobot-iupe": (RunConfig(env="acrobot", method="iupe"), "IUPE on Acrobot"),
    "acrobot-bco-alpha": (RunConfig(env="acrobot", method="bco-alpha"), "BCO(α) on Acrobot"),
    "mountaincar-iupe": (RunConfig(env="mountaincar", method="iupe"), "IUPE on MountainCar"),
    "mountaincar-bco-alpha": (RunConfig(env="mountaincar", method="bco-alpha"), "BCO(α) on MountainCar"),
    # evaluated as the thesis's authors did: an episode ends with return -1 on the 4th visit to a cell
    # (without the guard a lost agent walks 1,000 steps and scores about -11, which hides an 80% goal rate)
    "maze3-iupe": (RunConfig(env="maze3", method="iupe", deadlock_guard=True),
                   "IUPE on Maze 3×3 (images; thesis's deadlock guard in evaluation)"),
    # the thesis authors' protocol: the demonstrations' 100 layouts are the whole world
    "maze5-iupe-thesis": (RunConfig(env="maze5", method="iupe", maze_eval_layouts="demonstration", deadlock_guard=True),
                          "IUPE on Maze 5×5 (images; the thesis's protocol: demonstrated layouts, deadlock guard)"),
}


def make(name: str, config: RunConfig, label: str, out: Path) -> dict:
    start = time.perf_counter()
    run = Run(config)
    run.run()
    seconds = time.perf_counter() - start
    target = out / name
    tmp = out / f".{name}.partial"
    shutil.rmtree(tmp, ignore_errors=True)
    run.save(tmp)
    for records in tmp.glob("ckpt-*/records.json"):  # same data, no indentation: a third smaller
        atomic_write_text(records, json.dumps(json.loads(records.read_text()), separators=(",", ":")))
    atomic_write_json(tmp / "label.json", {
        "label": label, "made_by": "scripts/make_shipped_runs.py", "train_seconds": round(seconds, 1),
        "note": "A finished run shipped with the app: open it to scrub through its iterations."})
    shutil.rmtree(target, ignore_errors=True)
    tmp.rename(target)
    loaded = Run.load(target)  # the app must be able to read it back
    if loaded.iteration != run.iteration or loaded.config != run.config:
        raise RuntimeError(f"{target}: Run.load did not read back the run it saved")
    ev = run.records[-1]["evaluation"]
    return {"name": name, "iterations": run.iteration, "seconds": seconds, "aer": ev["aer"],
            "performance": ev["performance"], "bytes": folder_bytes(target)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", nargs="*", choices=sorted(SHIPPED), help="make only these runs")
    parser.add_argument("--out", type=Path, default=SHIPPED_RUNS, help="where to write (default assets/runs)")
    args = parser.parse_args(argv)
    limit_threads()
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for name in args.only or SHIPPED:
        config, label = SHIPPED[name]
        r = make(name, config, label, args.out)
        rows.append(r)
        perf = "n/a" if r["performance"] is None else f"{r['performance']:.3f}"
        print(f"{name}: {r['iterations']} iterations in {r['seconds']:.0f} s, AER {r['aer']:.3f}, P {perf}, "
              f"{r['bytes'] / 1024:.0f} KiB", flush=True)
    total = sum(r["bytes"] for r in rows)
    print(f"\n| run | iterations | seconds | AER | P | KiB |\n|---|---|---|---|---|---|")
    for r in rows:
        perf = "n/a" if r["performance"] is None else f"{r['performance']:.3f}"
        print(f"| {r['name']} | {r['iterations']} | {r['seconds']:.0f} | {r['aer']:.3f} | {perf} "
              f"| {r['bytes'] / 1024:.0f} |")
    print(f"\ntotal: {total / 1024:.0f} KiB, {sum(r['seconds'] for r in rows):.0f} s of training")
    return 0


if __name__ == "__main__":
    sys.exit(main())
