"""Where the app keeps runs: one folder per browser user, one sub-folder per run.

A user is an id kept in the page's URL (`?user=...`), so reloading the page or opening
the same link again finds the same runs, while other people's sessions have their own.
Runs are saved with `Run.save` (atomic); a run's display name lives in `label.json`,
so renaming never moves the folder that holds the weights.

    runs_root()/<user>/<run id>/   config.json, LATEST, ckpt-*/, label.json

IFO_LAB_RUNS sets the root (default: runs/app inside the project).
"""
from __future__ import annotations

import json
import os
import re
import shutil
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

from ifo.io import atomic_write_json

PROJECT = Path(__file__).resolve().parents[2]
USER_PARAM = "user"


def runs_root() -> Path:
    return Path(os.environ.get("IFO_LAB_RUNS", PROJECT / "runs" / "app"))


def valid_user(user: str | None) -> bool:
    return bool(user) and re.fullmatch(r"[a-z0-9]{6,32}", user) is not None


def new_user() -> str:
    return uuid.uuid4().hex[:12]


def user_dir(user: str) -> Path:
    if not valid_user(user):
        raise ValueError(f"not a user id: {user!r}")
    return runs_root() / user


def new_run_id(config) -> str:
    stamp = time.strftime("%Y%m%d-%H%M%S")
    return f"{config.env}-{config.method}-s{config.seed}-{stamp}-{uuid.uuid4().hex[:4]}"


@dataclass
class SavedRun:
    run_id: str
    path: Path
    label: str
    config: dict
    iterations_done: int
    modified: float


def _safe_child(user: str, run_id: str) -> Path:
    if not re.fullmatch(r"[A-Za-z0-9._-]{1,120}", run_id or "") or run_id.startswith("."):
        raise ValueError(f"not a run id: {run_id!r}")
    return user_dir(user) / run_id


def run_path(user: str, run_id: str) -> Path:
    return _safe_child(user, run_id)


def list_runs(user: str) -> list[SavedRun]:
    """The user's saved runs, newest first. Folders without a complete save are skipped."""
    folder = user_dir(user)
    if not folder.exists():
        return []
    runs = []
    for path in folder.iterdir():
        latest = path / "LATEST"
        if not path.is_dir() or path.name.startswith(".") or not latest.exists():
            continue
        try:
            config = json.loads((path / "config.json").read_text())
            ckpt = path / latest.read_text().strip()
            done = len(json.loads((ckpt / "records.json").read_text()))
            label_file = path / "label.json"
            label = json.loads(label_file.read_text())["label"] if label_file.exists() else path.name
        except (OSError, ValueError, KeyError):
            continue
        runs.append(SavedRun(path.name, path, label, config, done, latest.stat().st_mtime))
    return sorted(runs, key=lambda r: r.modified, reverse=True)


def rename_run(user: str, run_id: str, label: str) -> None:
    label = label.strip()
    if not label:
        raise ValueError("a run needs a name")
    if len(label) > 120:
        raise ValueError("names are at most 120 characters")
    path = _safe_child(user, run_id)
    if not (path / "LATEST").exists():
        raise FileNotFoundError(f"no saved run {run_id!r}")
    atomic_write_json(path / "label.json", {"label": label})


def delete_run(user: str, run_id: str) -> None:
    path = _safe_child(user, run_id)
    if not path.exists():
        raise FileNotFoundError(f"no saved run {run_id!r}")
    trash = path.with_name(f".deleted-{run_id}-{uuid.uuid4().hex[:6]}")
    path.rename(trash)  # one atomic step: the run disappears from the list at once
    shutil.rmtree(trash, ignore_errors=True)


def save_run(run, user: str, run_id: str, label: str | None = None) -> Path:
    path = _safe_child(user, run_id)
    run.save(path)
    if label is not None and not (path / "label.json").exists():
        atomic_write_json(path / "label.json", {"label": label})
    return path
