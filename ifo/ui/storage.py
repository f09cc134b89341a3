"""Where the app keeps runs: one folder per browser user, one sub-folder per run.

A user is an id kept in the page's URL (`?user=...`), so reloading the page or opening
the same link again finds the same runs, while other people's sessions have their own.
A run folder's layout belongs to `ifo.checkpoint` (saves are atomic and locked, readers
size-check everything); a run's display name lives in `label.json`, so renaming never
moves the folder that holds the weights. A damaged run is listed with what is wrong
(`SavedRun.damaged`), never dropped silently, and can still be deleted.

    runs_root()/<user>/<run id>/   a run folder (see ifo.checkpoint): LATEST, ckpt-*/, label.json, ...
    runs_root()/<user>/demos/      <name>.npz + <name>.json (environment, summary)

IFO_LAB_RUNS sets the root (default: runs/app inside the project). Finished example runs
ship in assets/runs/<name>/ (same layout, made by scripts/make_shipped_runs.py); opening
one copies it into the user's folder. Uploaded demonstrations are written to a hidden
temporary file, validated with `ifo.data.demos.load_demonstrations` (no pickle), and only
then renamed over the final name, so a bad upload never replaces a good file.
"""
from __future__ import annotations

import io
import json
import logging
import os
import threading
import re
import time
import uuid
import zipfile
from dataclasses import dataclass
from pathlib import Path

from ifo import checkpoint
from ifo.io import atomic_write_json

log = logging.getLogger(__name__)

PROJECT = Path(__file__).resolve().parents[2]
USER_PARAM = "user"
SHIPPED_RUNS = PROJECT / "assets" / "runs"
DEMOS_FOLDER = "demos"
MAX_UPLOAD_MB = int(os.environ.get("IFO_LAB_MAX_UPLOAD_MB", "50"))
MAX_DEMOS_PER_USER = 20


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
    from ifo.envs import env_file_name

    stamp = time.strftime("%Y%m%d-%H%M%S")
    return f"{env_file_name(config.env)}-{config.method}-s{config.seed}-{stamp}-{uuid.uuid4().hex[:4]}"


@dataclass
class SavedRun:
    run_id: str
    path: Path
    label: str
    config: dict
    iterations_done: int
    modified: float
    last: dict | None = None  # the last iteration's evaluation: aer, performance, goal_rate
    damaged: str | None = None  # what is wrong with a run that cannot be opened (it can still be deleted)

    @property
    def iterations_total(self) -> int | None:
        return self.config.get("iterations")


def _safe_child(user: str, run_id: str) -> Path:
    if not re.fullmatch(r"[A-Za-z0-9._-]{1,120}", run_id or "") or run_id.startswith("."):
        raise ValueError(f"not a run id: {run_id!r}")
    return user_dir(user) / run_id


def run_path(user: str, run_id: str) -> Path:
    return _safe_child(user, run_id)


def _read_saved(path: Path) -> SavedRun | None:
    """The run in `path` (damaged ones too, with what is wrong), or None when the folder holds no run."""
    if path.name.startswith(".") or not path.is_dir():
        return None
    try:
        info = checkpoint.inspect(path)
    except checkpoint.NoRun:
        return None
    return SavedRun(path.name, path, info.label, info.config, info.iterations_done, info.modified, info.last,
                    info.damaged)


def list_runs(user: str) -> list[SavedRun]:
    """The user's saved runs, newest first; damaged ones are listed with `damaged` saying why."""
    folder = user_dir(user)
    if not folder.exists():
        return []
    runs = [r for r in map(_read_saved, folder.iterdir()) if r is not None and r.run_id != DEMOS_FOLDER]
    return sorted(runs, key=lambda r: r.modified, reverse=True)


def get_run(user: str, run_id: str) -> SavedRun:
    """One saved run; FileNotFoundError if it is gone (deleted meanwhile), DamagedRun (a ValueError)
    saying what is wrong when it cannot be opened."""
    path = _safe_child(user, run_id)
    saved = _read_saved(path) if run_id != DEMOS_FOLDER else None
    if saved is None:
        raise FileNotFoundError(f"no saved run {run_id!r} (it may have been deleted)")
    if saved.damaged:
        raise checkpoint.DamagedRun(f"the run {run_id!r} is damaged: {saved.damaged}", saved.damaged)
    return saved


def last_records(saved: SavedRun) -> list[dict]:
    """The records of a saved run's latest checkpoint ([] if unreadable)."""
    try:
        return checkpoint.read_records(saved.path)
    except (checkpoint.CheckpointError, OSError):
        return []


def folder_bytes(path: Path) -> int:
    return sum(f.stat().st_size for f in Path(path).rglob("*") if f.is_file())


def rename_run(user: str, run_id: str, label: str) -> None:
    label = label.strip()
    if not label:
        raise ValueError("a run needs a name")
    if len(label) > 120:
        raise ValueError("names are at most 120 characters")
    path = _safe_child(user, run_id)
    try:
        checkpoint.write_label(path, label)
    except checkpoint.NoRun:
        raise FileNotFoundError(f"no saved run {run_id!r}") from None


def delete_run(user: str, run_id: str) -> None:
    """Delete a run, damaged ones too (renamed aside under the run's lock: it leaves the list at once)."""
    path = _safe_child(user, run_id)
    if run_id == DEMOS_FOLDER:
        raise ValueError(f"not a run id: {run_id!r}")
    try:
        checkpoint.remove(path)
    except checkpoint.NoRun:
        raise FileNotFoundError(f"no saved run {run_id!r}") from None


def zip_run(user: str, run_id: str) -> bytes:
    """The run as a ZIP of a run folder: its latest checkpoint, configuration, label and demonstrations."""
    get_run(user, run_id)
    files = checkpoint.snapshot(_safe_child(user, run_id))
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for rel in sorted(files):
            zf.writestr(str(Path(run_id) / rel), files[rel])
    return buf.getvalue()


# ---------------------------------------------------------------------- shipped example runs
def shipped_root() -> Path:
    return Path(os.environ.get("IFO_LAB_SHIPPED_RUNS", SHIPPED_RUNS))


def list_shipped_runs() -> list[SavedRun]:
    """The finished example runs in assets/runs, in name order (a damaged one is logged and left out)."""
    root = shipped_root()
    if not root.exists():
        return []
    runs = [r for r in map(_read_saved, root.iterdir()) if r is not None]
    for r in runs:
        if r.damaged:
            log.warning("example run %s is damaged: %s", r.path, r.damaged)
    return sorted((r for r in runs if not r.damaged), key=lambda r: r.run_id)


def copy_shipped_run(user: str, name: str) -> str:
    """Copy an example run into the user's folder (so it can be trained further); returns the new run id."""
    if not re.fullmatch(r"[A-Za-z0-9._-]{1,120}", name or "") or name.startswith("."):
        raise ValueError(f"not an example run: {name!r}")
    source = _read_saved(shipped_root() / name)
    if source is None:
        raise FileNotFoundError(f"no example run {name!r}")
    run_id = f"{name}-{time.strftime('%Y%m%d-%H%M%S')}-{uuid.uuid4().hex[:4]}"
    checkpoint.copy_run(source.path, _safe_child(user, run_id))  # appears in the list only once complete
    return run_id


# ---------------------------------------------------------------------- shared iterations
CACHE_FOLDER = ".cache"


def iteration_cache():
    """The server's cache of computed iterations (ifo.iteration_cache), shared by every session: students
    following one lesson compute each iteration once. IFO_LAB_CACHE_MB bounds it (default 1024; 0: off)."""
    from ifo.iteration_cache import IterationCache

    mb = int(os.environ.get("IFO_LAB_CACHE_MB", "1024"))
    return IterationCache(runs_root() / CACHE_FOLDER, mb * 2**20) if mb > 0 else None


_TRAINER_LOCK = threading.Lock()
_TRAINER: dict = {}


def trainer():
    """Where this server's iterations train (ifo.remote): IFO_LAB_RAY unset, here; else the address of a
    running Ray cluster (`ray start --head` prints it; "auto" finds one started on this machine). One per
    process, connected at the first Step. Raise IFO_LAB_MAX_TRAININGS to the cluster's CPUs.
    (The server never starts a Ray of its own: a Ray whose driver is the Streamlit process lost its object
    store connection as soon as two sessions ran, so the cluster must be a separate one.)"""
    where = os.environ.get("IFO_LAB_RAY", "").strip()
    if not where:
        return None
    with _TRAINER_LOCK:
        if where not in _TRAINER:
            from ifo.remote import RemoteTrainer

            _TRAINER[where] = RemoteTrainer(where)
        return _TRAINER[where]


def run_services() -> dict:
    """What every Run the app builds or opens gets: the shared iteration cache and the trainer."""
    return {"cache": iteration_cache(), "trainer": trainer()}


# ---------------------------------------------------------------------- read-only shares
# A teacher shares a run to watch: the link holds a token, never the teacher's user id (which is
# what gives write access). The token is an HMAC of the run's address under a secret kept in the
# runs root, so sharing the same run twice gives the same link, and nobody can make one up.
SHARE_PARAM = "share"
SHARES_FOLDER = ".shares"
MAX_SHARE_BYTES = 4096


def _share_secret() -> bytes:
    path = runs_root() / SHARES_FOLDER / "secret"
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        try:
            with open(path, "xb") as fh:  # the first writer wins; everyone reads that one
                fh.write(os.urandom(32))
        except FileExistsError:
            pass
    secret = path.read_bytes()
    if len(secret) != 32:
        raise OSError(f"{path} is damaged; delete it to make new share links (old ones stop working)")
    return secret


def share_run(user: str, run_id: str) -> str:
    """A read-only token for one of the user's saved runs (the same token every time)."""
    import hashlib
    import hmac

    get_run(user, run_id)  # it exists and is readable
    token = hmac.new(_share_secret(), f"{user}/{run_id}".encode(), hashlib.sha256).hexdigest()[:32]
    atomic_write_json(runs_root() / SHARES_FOLDER / f"{token}.json", {"user": user, "run_id": run_id})
    return token


def shared_run(token: str) -> SavedRun:
    """The run a share token names; ValueError for a malformed token, FileNotFoundError when the
    share or its run is gone."""
    if not re.fullmatch(r"[0-9a-f]{32}", token or ""):
        raise ValueError("this share link is not valid (it should end with 32 hexadecimal characters)")
    path = runs_root() / SHARES_FOLDER / f"{token}.json"
    if not path.is_file() or path.stat().st_size > MAX_SHARE_BYTES:
        raise FileNotFoundError("this share link points to nothing: the run was never shared here, or it moved")
    where = json.loads(path.read_text())
    return get_run(str(where.get("user")), str(where.get("run_id")))


def copy_shared_run(token: str, user: str) -> str:
    """Copy a shared run into `user`'s own runs (to train it further); returns the new run id."""
    source = shared_run(token)
    run_id = f"{source.run_id[:80]}-copy-{time.strftime('%Y%m%d-%H%M%S')}-{uuid.uuid4().hex[:4]}"
    checkpoint.copy_run(source.path, _safe_child(user, run_id))
    return run_id


# ---------------------------------------------------------------------- uploaded demonstrations
@dataclass
class SavedDemos:
    name: str  # file stem, unique per user
    path: Path
    env: str
    original_name: str
    summary: dict  # episodes, transitions, mean_return, has_actions
    modified: float


def demos_settings(demos: SavedDemos) -> dict:
    """The run settings that train on saved demonstrations: the file, how its states look, all its episodes."""
    return {"demos": str(demos.path), "obs_mode": demos_obs_mode(demos.path),
            "expert_episodes": demos.summary.get("episodes")}


def demos_dir(user: str) -> Path:
    return user_dir(user) / DEMOS_FOLDER


def demos_name(env: str, filename: str) -> str:
    """The stored name for an upload: environment + a cleaned-up file stem."""
    from ifo.envs import env_file_name

    stem = re.sub(r"[^A-Za-z0-9_-]+", "-", Path(filename or "demos").stem).strip("-_")[:60] or "demos"
    return f"{env_file_name(env)}-{stem}"


def demo_obs_shapes(env: str) -> list[tuple[tuple[int, ...], str]]:
    """The state shapes a demonstrations file may have for `env`, with the obs_mode each means."""
    from ifo.config import RunConfig
    from ifo.envs import get_env
    from ifo.envs.rollout import EnvPool

    spec = get_env(env)
    if not spec.is_maze:
        return [(tuple(spec.make().observation_space.shape), "vector")]
    shapes = []
    for mode in ("image", "vector"):
        pool = EnvPool(spec, obs_mode=mode, image_size=RunConfig().image_size, split="train")
        shapes.append((tuple(pool.envs(1)[0].observation_space.shape), mode))
    return shapes


def save_demos(user: str, env: str, filename: str, data: bytes) -> SavedDemos:
    """Validate uploaded demonstrations and keep them under the user's demos/ folder.

    Raises DemoError (its message says what is wrong, naming the uploaded file) and leaves any
    earlier file of the same name untouched; the new file replaces it only once it is valid."""
    from ifo.data.demos import DemoError, load_demonstrations, summarize
    from ifo.envs import get_env

    spec = get_env(env)
    if len(data) > MAX_UPLOAD_MB * 2**20:
        raise DemoError(f"{filename}: {len(data) / 2**20:.1f} MiB is over the {MAX_UPLOAD_MB} MiB upload limit")
    folder = demos_dir(user)
    folder.mkdir(parents=True, exist_ok=True)
    name = demos_name(spec.name, filename)
    final = folder / f"{name}.npz"
    if not final.exists() and len(list_demos(user)) >= MAX_DEMOS_PER_USER:
        raise DemoError(f"you already keep {MAX_DEMOS_PER_USER} demonstration files; delete one first")
    tmp = folder / f".upload-{uuid.uuid4().hex[:8]}.npz"
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        demos, mode, first_error = None, None, None
        for shape, mode in demo_obs_shapes(spec.name):
            try:
                demos = load_demonstrations(tmp, spec, shape)
                break
            except DemoError as e:
                msg = str(e).replace(str(tmp), filename)
                first_error = first_error or DemoError(msg)
                if "shape" not in msg:  # not a shape mismatch: another state shape will not help
                    break
        if demos is None:
            raise first_error
        os.replace(tmp, final)
    finally:
        if tmp.exists():
            tmp.unlink()
    meta = {"env": spec.name, "original_name": filename, "obs_mode": mode, "summary": summarize(demos)}
    atomic_write_json(folder / f"{name}.json", meta)
    return _read_demos(final)


def _read_demos(path: Path) -> SavedDemos | None:
    try:
        meta = json.loads(path.with_suffix(".json").read_text())
        return SavedDemos(path.stem, path, meta["env"], meta.get("original_name", path.name), meta.get("summary", {}),
                          path.stat().st_mtime)
    except (OSError, ValueError, KeyError, TypeError):
        return None


def list_demos(user: str) -> list[SavedDemos]:
    """The user's validated demonstration files, newest first."""
    folder = demos_dir(user)
    if not folder.exists():
        return []
    found = [_read_demos(p) for p in folder.glob("*.npz") if not p.name.startswith(".")]
    return sorted((d for d in found if d is not None), key=lambda d: d.modified, reverse=True)


def demos_obs_mode(path: Path) -> str:
    try:
        return json.loads(Path(path).with_suffix(".json").read_text()).get("obs_mode") or "image"
    except (OSError, ValueError):
        return "image"


def delete_demos(user: str, name: str) -> None:
    if not re.fullmatch(r"[A-Za-z0-9_-]{1,120}", name or ""):
        raise ValueError(f"not a demonstrations file: {name!r}")
    path = demos_dir(user) / f"{name}.npz"
    if not path.exists():
        raise FileNotFoundError(f"no demonstrations file {name!r}")
    path.unlink()
    path.with_suffix(".json").unlink(missing_ok=True)


# ---------------------------------------------------------------------- the user in the URL
def current_user() -> str:
    """The browser user's id: from `?user=` (a valid one), else the one this session already had,
    else a new one. Always written back to the URL, so the link finds the same runs later."""
    import streamlit as st

    user = st.query_params.get(USER_PARAM)
    if not valid_user(user):
        user = st.session_state.get("ifo.user")
        if not valid_user(user):
            user = new_user()
    st.session_state["ifo.user"] = user
    if st.query_params.get(USER_PARAM) != user:
        st.query_params[USER_PARAM] = user
    return user


def save_run(run, user: str, run_id: str, label: str | None = None) -> Path:
    """Save `run` as the user's run `run_id`. checkpoint.RunChanged (a ValueError) when another
    session saved that run meanwhile, RunBusy when another one keeps saving it."""
    path = _safe_child(user, run_id)
    run.save(path)
    if label is not None:
        checkpoint.write_label(path, label, replace=False)
    return path
