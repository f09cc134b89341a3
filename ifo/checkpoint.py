"""Checkpoints: the one module that knows how a run folder is laid out on disk.

    <run>/
        LATEST                    the name of the current checkpoint, one line; replaced atomically
        ckpt-00012-1a2b3c4d/      a checkpoint (iteration, 8 random hex): never changed once it has its name
            config.json             the run's configuration (the truth)
            meta.json               iteration, optimizer groups, ...; "checkpoint": format, parent, demos size+sha256
            records.json            one record per iteration done
            state.npz               weights, optimizer state, I_s: plain arrays, never pickles
        ckpt-00011-9f8e7d6c/      the checkpoint before it: the last good one, kept until the next save
        config.json               a copy of the latest configuration, for people (read only for old runs)
        label.json                {"label": ...}: the name the app shows
        demos.npz                 the user's demonstrations, when the run trains on them
        .lock                     the writers' lock; readers never take it
        .ckpt-....partial/        a checkpoint being written; a crash may leave one, the next save removes it

Writers (`save`, `write_label`, `remove`) hold `<run>/.lock` (filelock, a new instance per call,
so two threads of one process exclude each other as two processes do). A save writes
`.ckpt-X.partial/` (every file fsync'ed), renames it to `ckpt-X`, swaps LATEST, and only then
removes older checkpoints, always keeping the one LATEST named before. It refuses with
`RunChanged` when someone else saved the folder since the caller's `parent` checkpoint.

Readers (`latest`, `load`, `inspect`, `snapshot`) take no lock: checkpoint folders never change
once named and a save keeps the previous one, so a reader that finds its checkpoint gone
because LATEST moved on just reads again. Every file is size-checked before it is read, and
LATEST must name a checkpoint directly inside the run folder.

Runs saved before config.json moved into the checkpoint (assets/runs/*) still load: their
configuration is read from <run>/config.json. No torch and no streamlit here.
"""
from __future__ import annotations

import errno
import hashlib
import json
import os
import re
import secrets
import shutil
import stat
import time
import zipfile
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import lru_cache
from io import BytesIO
from pathlib import Path

import numpy as np
from filelock import FileLock, Timeout

from ifo.data.npz import NpzError, read_npz
from ifo.io import FAST_DEFLATE, npz_bytes
from ifo.runtime import file_stamp

LATEST_FILE, LABEL_FILE, DEMOS_FILE, LOCK_FILE = "LATEST", "label.json", "demos.npz", ".lock"
CONFIG_FILE, META_FILE, RECORDS_FILE, STATE_FILE = "config.json", "meta.json", "records.json", "state.npz"
FORMAT = 2  # 1: config.json only at the top of the run folder (runs made before this module)
LOCK_TIMEOUT = 10.0  # seconds a writer waits for another one before RunBusy (a save takes well under 1 s)
READ_ATTEMPTS = 5  # a reader reads again when LATEST moved on while it read

# Limits, checked before anything is read (a damaged or hostile folder must not exhaust memory).
# Generous: the largest shipped run holds 0.5 MB of records and a 2 MB state.npz (5 MB of arrays).
MAX_LATEST_BYTES = 256
MAX_CONFIG_BYTES = 1 << 20  # config.json: under 1 KB in practice
MAX_META_BYTES = 4 << 20  # meta.json: optimizer param groups, a few KB
MAX_LABEL_BYTES = 64 << 10
MAX_RECORDS_BYTES = 64 << 20  # records.json: about 30 KB per maze iteration (Grad-CAM maps)
MAX_STATE_BYTES = 1 << 30  # state.npz on disk (compressed)
MAX_ARRAY_BYTES = 1 << 30  # one array of state.npz once inflated
MAX_ARRAYS_BYTES = 2 << 30  # all of them together
MAX_DEMOS_BYTES = 1 << 30  # demos.npz read whole by `snapshot` (a ZIP download, a copy)

CKPT_RE = re.compile(r"ckpt-\d{5}-[0-9a-f]{8}")
# What a crash can leave behind: a checkpoint half written or half removed, an atomic write's temporary file.
LEFTOVER_RE = re.compile(r"\.ckpt-\d{5}-[0-9a-f]{8}\.(partial|removing)"
                         r"|\.(LATEST|config\.json|label\.json|demos\.npz)\.[A-Za-z0-9_]+\.tmp")


# ----------------------------------------------------------------------------- errors
class CheckpointError(ValueError):
    """A run folder problem; the message is one line that says what. `reason` leaves out the path."""

    def __init__(self, message: str, reason: str | None = None):
        super().__init__(message)
        self.reason = reason or message


class RunBusy(CheckpointError):
    """Another writer held the run folder's lock for longer than the timeout."""


class RunChanged(CheckpointError):
    """Another session saved this run folder since the caller loaded or saved it."""


class DamagedRun(CheckpointError):
    """The run folder cannot be read; `reason` says what is damaged."""


class NoRun(CheckpointError, FileNotFoundError):
    """No saved run there (no folder, or no LATEST)."""


def _damaged(run_dir: Path, reason: str) -> DamagedRun:
    return DamagedRun(f"{run_dir}: damaged run: {reason}", reason)


# ----------------------------------------------------------------------------- what readers get
@dataclass
class Checkpoint:
    name: str
    path: Path
    config: dict
    meta: dict
    records: list[dict]
    arrays: dict[str, np.ndarray] | None
    demos: Path | None = None  # <run>/demos.npz when the run trains on the user's demonstrations


@dataclass(frozen=True)
class RunInfo:
    """A run folder as a listing shows it: cheap, and never an exception for a damaged run."""
    path: Path
    label: str  # label.json's, else the folder's name
    damaged: str | None = None  # what is wrong, or None when the run loads
    checkpoint: str | None = None
    config: dict = field(default_factory=dict)  # for a damaged run: the top-level copy, when readable
    iterations_done: int = 0
    last: dict | None = None  # the last iteration's evaluation: aer, performance, goal_rate
    modified: float = 0.0

    @property
    def ok(self) -> bool:
        return self.damaged is None


# ----------------------------------------------------------------------------- small file helpers
def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _write_new(path: Path, data: bytes, durable: bool = True) -> None:
    """A new file, flushed to disk (inside a folder that is renamed into place later)."""
    with open(path, "xb") as fh:
        fh.write(data)
        if durable:
            fh.flush()
            os.fsync(fh.fileno())


def _atomic_write(path: Path, data: bytes, durable: bool = True) -> None:
    """Temporary file, fsync, rename over `path`, fsync the folder: the old file or the new one, never half."""
    tmp = path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp")
    try:
        _write_new(tmp, data, durable)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    if durable:
        _fsync_dir(path.parent)


def _rmtree(path: Path) -> None:
    if path.is_symlink() or not path.is_dir():
        path.unlink(missing_ok=True)
    else:
        shutil.rmtree(path, ignore_errors=True)


def _mib(n: int) -> str:
    return f"{n / 2**20:.1f} MiB" if n >= 2**20 else f"{n:,} bytes"


def _open_file(path: Path, run_dir: Path):
    """A regular file of the run opened for reading. FileNotFoundError when it is missing (a reader
    may retry: a save can have moved on); DamagedRun for a link, FIFO, device, folder or no access."""
    what = os.path.relpath(path, run_dir)
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0))
    except FileNotFoundError:
        raise
    except OSError as e:
        why = "is a link, not a file" if e.errno == errno.ELOOP else f"cannot be opened ({e.strerror})"
        raise _damaged(run_dir, f"{what} {why}") from None
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise _damaged(run_dir, f"{what} is not a regular file")
    return os.fdopen(fd, "rb")


def _read_bytes(path: Path, limit: int, run_dir: Path) -> bytes:
    what = os.path.relpath(path, run_dir)
    with _open_file(path, run_dir) as fh:
        size = os.fstat(fh.fileno()).st_size
        data = fh.read(limit + 1) if size <= limit else b""
    if size > limit or len(data) > limit:
        raise _damaged(run_dir, f"{what} is {_mib(max(size, len(data)))}, over the {_mib(limit)} limit")
    return data


def _read_json(path: Path, limit: int, run_dir: Path, kind: type | None = dict):
    data = _read_bytes(path, limit, run_dir)
    what = os.path.relpath(path, run_dir)
    try:
        value = json.loads(data)
    except (ValueError, RecursionError) as e:  # UnicodeDecodeError is a ValueError
        raise _damaged(run_dir, f"{what} is not valid JSON ({str(e)[:80]})") from None
    if kind is not None and not isinstance(value, kind):
        raise _damaged(run_dir, f"{what} holds a {type(value).__name__}, not a {kind.__name__}")
    return value


def _json_bytes(value, what: str, limit: int, compact: bool = False) -> bytes:
    text = json.dumps(value, separators=(",", ":")) if compact else json.dumps(value, indent=1, sort_keys=True)
    data = text.encode("utf-8")
    if len(data) > limit:  # never write what `load` would refuse to read
        raise CheckpointError(f"{what} would be {_mib(len(data))}, over the {_mib(limit)} a checkpoint may hold")
    return data


# ----------------------------------------------------------------------------- state.npz
def _npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    total = 0
    for key, value in arrays.items():
        a = np.asarray(value)
        if not isinstance(key, str) or a.dtype.hasobject:
            raise CheckpointError(f"state array {key!r} is not a plain numeric array (no pickles in checkpoints)")
        total += a.nbytes
    if total > MAX_ARRAYS_BYTES:
        raise CheckpointError(f"the state arrays are {_mib(total)}, over the {_mib(MAX_ARRAYS_BYTES)} limit")
    data = npz_bytes(arrays, FAST_DEFLATE)
    if len(data) > MAX_STATE_BYTES:
        raise CheckpointError(f"state.npz would be {_mib(len(data))}, over the {_mib(MAX_STATE_BYTES)} limit")
    return data


def _check_npz(fh, run_dir: Path, what: str) -> None:
    """The cheap check of a listing: state.npz's size and its ZIP directory (a cut-short file has none).
    `load` reads it through the safe reader, which checks every array's header too."""
    size = os.fstat(fh.fileno()).st_size
    if size > MAX_STATE_BYTES:
        raise _damaged(run_dir, f"{what} is {_mib(size)}, over the {_mib(MAX_STATE_BYTES)} limit")
    try:
        with zipfile.ZipFile(fh) as zf:
            total = sum(info.file_size for info in zf.infolist())
    except (zipfile.BadZipFile, ValueError, EOFError, OSError) as e:
        raise _damaged(run_dir, f"{what} is not a readable array archive ({str(e)[:80]})") from None
    if total > MAX_ARRAYS_BYTES:
        raise _damaged(run_dir, f"{what} holds {_mib(total)} of arrays, over the {_mib(MAX_ARRAYS_BYTES)} limit")


def _read_arrays(path: Path, run_dir: Path) -> dict[str, np.ndarray]:
    """state.npz as plain arrays, through the safe reader (ifo.data.npz): every .npy header is checked
    against the limits before anything is inflated, and nothing is ever unpickled."""
    what = os.path.relpath(path, run_dir)
    data = _read_bytes(path, MAX_STATE_BYTES, run_dir)  # FileNotFoundError passes: a save may have moved on
    try:
        return read_npz(data, max_array_bytes=MAX_ARRAY_BYTES, max_total_bytes=MAX_ARRAYS_BYTES)
    except NpzError as e:
        raise _damaged(run_dir, f"{what} is not a readable array archive ({e})") from None


# ----------------------------------------------------------------------------- demonstrations
def _hash_copy(src, dst=None) -> dict:
    """Size and sha256 of what `src` holds, copied to `dst` on the way when given (tests break it here)."""
    h, n = hashlib.sha256(), 0
    while chunk := src.read(1 << 20):
        if dst is not None:
            dst.write(chunk)
        h.update(chunk)
        n += len(chunk)
    return {"size": n, "sha256": h.hexdigest()}


@lru_cache(maxsize=64)
def _digest_of(path: str, dev: int, ino: int, size: int, mtime_ns: int) -> tuple:
    with open(path, "rb") as fh:
        return tuple(_hash_copy(fh).items())


def _digest(path: Path) -> dict:
    """{"size", "sha256"} of a file, remembered while the file is unchanged (autosaves hash it once)."""
    st = os.stat(path)
    return dict(_digest_of(os.path.realpath(path), st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns))


def _place_demos(run_dir: Path, source: Path, previous: dict | None) -> dict:
    """Make <run>/demos.npz a complete copy of `source` (atomically) unless it already is one;
    returns its size and sha256 for the checkpoint's meta."""
    target = run_dir / DEMOS_FILE
    try:
        want = _digest(source)
    except FileNotFoundError:  # the upload was deleted meanwhile: the run's own intact copy will do
        if previous and target.is_file() and _digest(target) == previous:
            return previous
        raise CheckpointError(f"the demonstrations {source} are gone, and {run_dir} holds no intact copy") from None
    if target.is_file() and (os.path.samefile(source, target) or _digest(target) == want):
        return want
    tmp = target.with_name(f".{DEMOS_FILE}.{secrets.token_hex(4)}.tmp")
    try:
        with open(source, "rb") as src, open(tmp, "xb") as dst:
            got = _hash_copy(src, dst)
            dst.flush()
            os.fsync(dst.fileno())
        if got != want:
            raise CheckpointError(f"the demonstrations {source} changed while they were copied; save again")
        os.replace(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _fsync_dir(run_dir)
    return want


def _check_demos(run_dir: Path, meta: dict, full: bool) -> Path:
    demos = run_dir / DEMOS_FILE
    if not demos.is_file():
        raise _damaged(run_dir, f"the run trains on demonstrations and {DEMOS_FILE} is missing")
    want = (meta.get("checkpoint") or {}).get("demos")
    if isinstance(want, dict) and isinstance(want.get("size"), int):
        size = demos.stat().st_size
        if size != want.get("size"):
            raise _damaged(run_dir, f"{DEMOS_FILE} is {size:,} bytes, not the {want.get('size'):,} its checkpoint "
                                    "recorded (a copy cut short?)")
        if full and _digest(demos).get("sha256") != want.get("sha256"):
            raise _damaged(run_dir, f"{DEMOS_FILE} is not the file its checkpoint recorded (sha256 differs)")
    return demos


# ----------------------------------------------------------------------------- the lock
@contextmanager
def _locked(run_dir: Path, timeout: float):
    # A new instance per call: two threads of one process exclude each other as two processes do.
    lock = FileLock(run_dir / LOCK_FILE, timeout=timeout, poll_interval=0.01)
    try:
        lock.acquire()
    except Timeout:
        raise RunBusy(f"{run_dir}: another session is saving this run (waited {timeout:g} s); try again") from None
    except FileNotFoundError:
        raise NoRun(f"{run_dir} was deleted meanwhile") from None
    try:
        yield
    finally:
        lock.release()


# ----------------------------------------------------------------------------- reading
def _read_latest(run_dir: Path) -> str:
    if not run_dir.is_dir():
        raise NoRun(f"{run_dir} is not a run folder")
    try:
        raw = _read_bytes(run_dir / LATEST_FILE, MAX_LATEST_BYTES, run_dir)
    except FileNotFoundError:
        raise NoRun(f"{run_dir} holds no saved run (no LATEST file)") from None
    name = raw.decode("utf-8", "replace").strip()
    if not CKPT_RE.fullmatch(name):
        raise _damaged(run_dir, f"LATEST does not name a checkpoint of this folder ({name[:60]!r})")
    return name


def _latest_or_none(run_dir: Path) -> str | None:
    try:
        return _read_latest(run_dir)
    except (CheckpointError, OSError):
        return None


def latest(run_dir) -> str:
    """The name of the run's current checkpoint: a folder directly inside `run_dir` (never a path
    elsewhere, never a link). NoRun without LATEST, DamagedRun when it names no such folder."""
    run_dir = Path(run_dir)
    for _ in range(READ_ATTEMPTS):
        name = _read_latest(run_dir)
        path = run_dir / name
        if path.is_dir() and not path.is_symlink():
            return name
        if _latest_or_none(run_dir) == name:
            what = "is a link" if path.is_symlink() else "is not a folder" if path.exists() else "is missing"
            raise _damaged(run_dir, f"LATEST names {name}, which {what}")
    raise RunBusy(f"{run_dir}: LATEST moved {READ_ATTEMPTS} times while it was read; try again")


def _at_latest(run_dir: Path, read):
    """read(name) on the latest checkpoint, again if a save moved LATEST on while it read."""
    for _ in range(READ_ATTEMPTS):
        name = latest(run_dir)
        try:
            return read(name)
        except NoRun:
            raise
        except FileNotFoundError as e:
            if _latest_or_none(run_dir) != name:
                continue  # our checkpoint was replaced twice over while we read it: read the new one
            missing = os.path.relpath(e.filename, run_dir) if e.filename else "a file"
            raise _damaged(run_dir, f"{missing} is missing") from None
    raise RunBusy(f"{run_dir}: LATEST moved {READ_ATTEMPTS} times while it was read; try again")


def _read_checkpoint(run_dir: Path, name: str, with_arrays: bool) -> Checkpoint:
    path = run_dir / name
    meta = _read_json(path / META_FILE, MAX_META_BYTES, run_dir)
    try:
        config = _read_json(path / CONFIG_FILE, MAX_CONFIG_BYTES, run_dir)
    except FileNotFoundError:
        if "checkpoint" in meta:  # a format-2 checkpoint always holds its configuration
            raise
        config = _read_json(run_dir / CONFIG_FILE, MAX_CONFIG_BYTES, run_dir)  # format 1 (assets/runs)
    records = _read_json(path / RECORDS_FILE, MAX_RECORDS_BYTES, run_dir, kind=list)
    if not all(isinstance(r, dict) for r in records):
        raise _damaged(run_dir, f"{name}/{RECORDS_FILE} is not a list of records")
    demos = _check_demos(run_dir, meta, full=with_arrays) if config.get("demos") else None
    arrays = _read_arrays(path / STATE_FILE, run_dir) if with_arrays else None
    return Checkpoint(name, path, config, meta, records, arrays, demos)


def load(run_dir, *, with_arrays: bool = True) -> Checkpoint:
    """The run's latest checkpoint, every file size-checked (arrays only `with_arrays`).
    NoRun when there is no saved run, DamagedRun (saying what) when it cannot be read."""
    run_dir = Path(run_dir)
    return _at_latest(run_dir, lambda name: _read_checkpoint(run_dir, name, with_arrays))


def read_records(run_dir) -> list[dict]:
    return load(run_dir, with_arrays=False).records


def read_config(run_dir) -> dict:
    return load(run_dir, with_arrays=False).config


def read_label(run_dir) -> str | None:
    """label.json's label; None without one; DamagedRun when it is unreadable."""
    run_dir = Path(run_dir)
    try:
        data = _read_json(run_dir / LABEL_FILE, MAX_LABEL_BYTES, run_dir)
    except FileNotFoundError:
        return None
    label = data.get("label")
    if not isinstance(label, str) or not label.strip():
        raise _damaged(run_dir, f"{LABEL_FILE} holds no label")
    return label


@lru_cache(maxsize=1024)
def _summary(run_dir: str, name: str, signature: tuple) -> tuple:
    """("ok", config JSON, iterations, last evaluation) or ("damaged", reason) for one checkpoint.
    Checkpoint folders never change, and `signature` (the files' stat) catches anyone who edits
    one by hand, so each is read once, not on every listing."""
    path = Path(run_dir)
    try:
        ckpt = _read_checkpoint(path, name, with_arrays=False)
        with _open_file(ckpt.path / STATE_FILE, path) as fh:
            _check_npz(fh, path, f"{name}/{STATE_FILE}")
    except DamagedRun as e:
        return "damaged", e.reason
    records = ckpt.records
    ev = records[-1].get("evaluation") if records else None
    last = tuple((k, ev.get(k)) for k in ("aer", "performance", "goal_rate")) if isinstance(ev, dict) else None
    return "ok", json.dumps(ckpt.config), len(records), last


def _loose_config(run_dir: Path) -> dict:
    try:
        return _read_json(run_dir / CONFIG_FILE, MAX_CONFIG_BYTES, run_dir)
    except (CheckpointError, OSError):
        return {}


def inspect(run_dir) -> RunInfo:
    """What a listing shows of a run folder: ok, or damaged with the reason; iterations done, the last
    evaluation, the configuration, the label. NoRun when the folder holds no run at all."""
    run_dir = Path(run_dir)
    try:
        label = read_label(run_dir) or run_dir.name
    except (CheckpointError, OSError):
        label = run_dir.name  # a damaged label never hides the run
    try:
        modified = (run_dir / LATEST_FILE).stat().st_mtime
    except OSError:
        modified = run_dir.stat().st_mtime if run_dir.is_dir() else 0.0

    def damaged(reason: str) -> RunInfo:
        return RunInfo(run_dir, label, damaged=reason, config=_loose_config(run_dir), modified=modified)

    def read(name: str) -> tuple:
        ck = run_dir / name
        signature = tuple(file_stamp(p) for p in (ck / META_FILE, ck / CONFIG_FILE, ck / RECORDS_FILE,
                                                  ck / STATE_FILE, run_dir / CONFIG_FILE, run_dir / DEMOS_FILE))
        return (name, *_summary(str(run_dir), name, signature))  # a missing file raises, and is not cached

    try:
        name, status, *rest = _at_latest(run_dir, read)
    except NoRun:
        if (run_dir / CONFIG_FILE).is_file() or (run_dir / LABEL_FILE).is_file():
            return damaged("LATEST is missing: no checkpoint is marked as the current one")
        raise
    except CheckpointError as e:
        return damaged(e.reason)
    except OSError as e:
        return damaged(f"cannot be read ({e.strerror or e})")
    if status == "damaged":
        return damaged(rest[0])
    config, done, last = rest
    return RunInfo(run_dir, label, None, name, json.loads(config), done, dict(last) if last else None, modified)


def snapshot(run_dir) -> dict[str, bytes]:
    """The run's latest checkpoint as the files of a complete run folder, relative path -> bytes:
    LATEST, config.json, label.json (when readable), demos.npz (when the run has one), ckpt-*/."""
    run_dir = Path(run_dir)

    def read(name: str) -> dict[str, bytes]:
        ckpt = _read_checkpoint(run_dir, name, with_arrays=False)
        files = {f"{name}/{f}": _read_bytes(ckpt.path / f, limit, run_dir)
                 for f, limit in ((META_FILE, MAX_META_BYTES), (RECORDS_FILE, MAX_RECORDS_BYTES),
                                  (STATE_FILE, MAX_STATE_BYTES))}
        try:  # a copy of a run that would not load is no copy
            read_npz(files[f"{name}/{STATE_FILE}"], max_array_bytes=MAX_ARRAY_BYTES, max_total_bytes=MAX_ARRAYS_BYTES)
        except NpzError as e:
            raise _damaged(run_dir, f"{name}/{STATE_FILE} is not a readable array archive ({e})") from None
        files[CONFIG_FILE] = files[f"{name}/{CONFIG_FILE}"] = _json_bytes(ckpt.config, "config", MAX_CONFIG_BYTES)
        files[LATEST_FILE] = name.encode()
        try:
            label = read_label(run_dir)
        except CheckpointError:
            label = None
        if label is not None:
            files[LABEL_FILE] = _json_bytes({"label": label}, "label", MAX_LABEL_BYTES)
        if ckpt.demos is not None:
            files[DEMOS_FILE] = _read_bytes(ckpt.demos, MAX_DEMOS_BYTES, run_dir)
            want = (ckpt.meta.get("checkpoint") or {}).get("demos")
            if isinstance(want, dict) and _hash_copy(BytesIO(files[DEMOS_FILE])) != want:
                raise _damaged(run_dir, f"{DEMOS_FILE} is not the file its checkpoint recorded")
        return files

    return _at_latest(run_dir, read)


# ----------------------------------------------------------------------------- writing
def blocking_file(path) -> Path | None:
    """What stops `path` from being a folder: `path` itself when it is a file, else the nearest
    existing ancestor that is not a folder; None when nothing does."""
    p = Path(path).absolute()
    for q in (p, *p.parents):
        if q.is_dir():
            return None
        if q.exists() or q.is_symlink():
            # another writer may have made the folder between the two checks
            return None if q.is_dir() and not q.is_symlink() else q
    return None


def _refuse_blocked(path: Path) -> None:
    blocker = blocking_file(path)
    if blocker is not None:
        where = "is a file" if blocker == Path(path).absolute() else f"lies under {blocker}, which is a file"
        raise CheckpointError(f"{path} {where}, not a folder")


def _is_ours(path: Path) -> bool:
    """A checkpoint folder this module wrote: the name, a real folder, and a meta.json of ours."""
    if not CKPT_RE.fullmatch(path.name) or path.is_symlink() or not path.is_dir():
        return False
    try:
        meta = _read_json(path / META_FILE, MAX_META_BYTES, path.parent)
    except (CheckpointError, OSError):
        return False
    return "iteration" in meta or "checkpoint" in meta


def _tidy(run_dir: Path, keep: set[str]) -> None:
    """Remove older checkpoints (except `keep`) and what crashes left behind. Under the lock only."""
    for entry in os.scandir(run_dir):
        path = Path(entry.path)
        try:
            if CKPT_RE.fullmatch(entry.name) and entry.name not in keep and _is_ours(path):
                aside = run_dir / f".{entry.name}.removing"  # one atomic step, then the slow part
                os.rename(path, aside)
                _rmtree(aside)
            elif LEFTOVER_RE.fullmatch(entry.name):
                _rmtree(path)
        except OSError:
            pass  # the save itself succeeded; the next one tries again


def _write_checkpoint(run_dir: Path, name: str, files: dict[str, bytes]) -> None:
    tmp = run_dir / f".{name}.partial"
    tmp.mkdir()
    try:
        for fname, data in files.items():
            _write_new(tmp / fname, data)
        _fsync_dir(tmp)
        os.rename(tmp, run_dir / name)
    except BaseException:
        _rmtree(tmp)
        raise
    _fsync_dir(run_dir)


def save(run_dir, *, config: dict, records: list[dict], arrays: dict[str, np.ndarray], meta: dict,
         parent: str | None, demos_source=None, overwrite: bool = False, lock_timeout: float = LOCK_TIMEOUT) -> str:
    """Save a new checkpoint of `run_dir` and make it the latest; returns its name (the caller's
    next `parent`). `parent` is the checkpoint the caller loaded or last saved here (None: a new run).

    RunChanged when LATEST names another checkpoint than `parent` (another session saved since),
    DamagedRun when LATEST is unreadable, unless `overwrite`; RunBusy when another writer keeps the
    lock longer than `lock_timeout`. A failure at any point leaves the previous checkpoint the latest.
    `demos_source`: the demonstrations the run trains on, copied to <run>/demos.npz when missing or different."""
    run_dir = Path(run_dir)
    _refuse_blocked(run_dir)
    # The slow part (JSON, compression) before taking the lock.
    files = {CONFIG_FILE: _json_bytes(config, "the configuration", MAX_CONFIG_BYTES),
             RECORDS_FILE: _json_bytes(records, "the records", MAX_RECORDS_BYTES, compact=True),
             STATE_FILE: _npz_bytes(arrays)}
    iteration = int(meta.get("iteration", len(records)))
    name = f"ckpt-{min(max(iteration, 0), 99999):05d}-{secrets.token_hex(4)}"
    for attempt in range(2):
        run_dir.mkdir(parents=True, exist_ok=True)
        try:
            with _locked(run_dir, lock_timeout):
                return _save_locked(run_dir, name, files, meta, parent, demos_source, overwrite)
        except NoRun:
            if attempt:  # the folder was removed while we waited for its lock: make it again, once
                raise
    raise AssertionError("unreachable")


def _save_locked(run_dir: Path, name: str, files: dict, meta: dict, parent: str | None, demos_source,
                 overwrite: bool) -> str:
    try:
        current = latest(run_dir)  # under the lock LATEST cannot move
    except NoRun:
        current = None
    except DamagedRun as e:
        if not overwrite:
            raise _damaged(run_dir, f"{e.reason}; not saving over it") from None
        current = None
    if current is not None and current != parent and not overwrite:
        since = f"since this session had {parent}" if parent else "and this session started a new run there"
        raise RunChanged(f"{run_dir}: another session saved this run (now {current}) {since}; "
                         "reload the run to go on from its latest save", "another session saved this run meanwhile")
    previous_demos = None
    if current is not None:
        try:
            previous_demos = (_read_json(run_dir / current / META_FILE, MAX_META_BYTES, run_dir)
                              .get("checkpoint") or {}).get("demos")
        except (CheckpointError, OSError):
            pass
    demos = _place_demos(run_dir, Path(demos_source), previous_demos) if demos_source else None
    meta = {**meta, "checkpoint": {"format": FORMAT, "parent": current, "saved": round(time.time(), 3),
                                   "demos": demos}}
    files = {**files, META_FILE: _json_bytes(meta, "the meta data", MAX_META_BYTES)}
    _write_checkpoint(run_dir, name, files)
    _atomic_write(run_dir / LATEST_FILE, name.encode())  # the moment the new checkpoint becomes the run
    try:
        _atomic_write(run_dir / CONFIG_FILE, files[CONFIG_FILE], durable=False)  # for people; the truth is in ckpt
    except OSError:
        pass
    _tidy(run_dir, keep={name, current})
    return name


def write_label(run_dir, label: str, *, replace: bool = True, lock_timeout: float = LOCK_TIMEOUT) -> None:
    """Set label.json (atomically, under the lock). `replace=False` keeps a readable existing label."""
    run_dir = Path(run_dir)
    if not (run_dir / LATEST_FILE).is_file():
        raise NoRun(f"{run_dir} holds no saved run (no LATEST file)")
    data = _json_bytes({"label": label}, "the label", MAX_LABEL_BYTES)
    with _locked(run_dir, lock_timeout):
        if not replace:
            try:
                if read_label(run_dir) is not None:
                    return
            except (CheckpointError, OSError):
                pass  # a damaged label: write a good one
        _atomic_write(run_dir / LABEL_FILE, data)


def _looks_like_run(path: Path) -> bool:
    return any((path / f).exists() for f in (LATEST_FILE, CONFIG_FILE, LABEL_FILE)) or any(
        _is_ours(p) for p in path.glob("ckpt-*"))


def remove(run_dir, *, lock_timeout: float = LOCK_TIMEOUT) -> None:
    """Delete a run folder, damaged ones too: renamed aside in one atomic step under the lock
    (it leaves every listing at once), then removed. Refuses folders that hold no run of ours."""
    run_dir = Path(run_dir)
    if run_dir.is_symlink():
        run_dir.unlink()
        return
    if not run_dir.is_dir() or not _looks_like_run(run_dir):
        raise NoRun(f"{run_dir} holds no saved run")
    trash = run_dir.with_name(f".deleted-{run_dir.name}-{secrets.token_hex(4)}")
    with _locked(run_dir, lock_timeout):
        os.rename(run_dir, trash)
    shutil.rmtree(trash, ignore_errors=True)


def copy_run(src, dst) -> None:
    """Copy a run's latest checkpoint (with its label and demonstrations) into the new folder `dst`:
    written beside it under a hidden name and renamed into place, so `dst` appears complete or not at all.
    The copy has the current layout even when `src` has the old one."""
    dst = Path(dst)
    files = snapshot(src)
    if dst.exists() or dst.is_symlink():
        raise CheckpointError(f"{dst} already exists")
    _refuse_blocked(dst.parent)
    dst.parent.mkdir(parents=True, exist_ok=True)
    tmp = dst.with_name(f".{dst.name}.{secrets.token_hex(4)}.partial")
    try:
        tmp.mkdir()
        for rel, data in files.items():
            (tmp / rel).parent.mkdir(exist_ok=True)
            _write_new(tmp / rel, data)
        for folder in {(tmp / rel).parent for rel in files}:
            _fsync_dir(folder)
        os.rename(tmp, dst)
    except BaseException:
        _rmtree(tmp)
        raise
    _fsync_dir(dst.parent)


def prepare_out_dir(path, overwrite: bool = False) -> None:
    """Check (and make) the folder `train --out` will save into, before any training: refuses a file,
    a path under a file, a folder holding anything that is not a run of ours, and an existing run;
    the last two only without `overwrite` (which never deletes files that are not ours)."""
    path = Path(path)
    _refuse_blocked(path)
    if path.is_dir():
        is_run = (path / LATEST_FILE).exists()
        ours = {LATEST_FILE, CONFIG_FILE, LABEL_FILE, DEMOS_FILE} if is_run else set()
        foreign = sorted(n for n in os.listdir(path) if not (
            n == LOCK_FILE or n in ours or LEFTOVER_RE.fullmatch(n) or _is_ours(path / n)))
        if foreign and not overwrite:
            shown = ", ".join(foreign[:3]) + (f" and {len(foreign) - 3} more" if len(foreign) > 3 else "")
            raise CheckpointError(f"{path} holds files that are not a saved run ({shown}): choose a new or empty "
                                  "folder, or pass --overwrite to save the run there anyway")
        if is_run and not overwrite:
            raise CheckpointError(f"{path} already holds a saved run: choose another folder, "
                                  "or pass --overwrite to replace it")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise CheckpointError(f"cannot make the folder {path} ({e.strerror})") from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise CheckpointError(f"cannot write into {path}")


__all__ = ["CheckpointError", "RunBusy", "RunChanged", "DamagedRun", "NoRun", "Checkpoint", "RunInfo",
           "save", "latest", "load", "read_records", "read_config", "read_label", "write_label", "inspect",
           "snapshot", "copy_run", "remove", "prepare_out_dir", "blocking_file", "DEMOS_FILE", "LATEST_FILE",
           "CONFIG_FILE", "LABEL_FILE"]
