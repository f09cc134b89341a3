"""A content-addressed cache of iterations, shared by every session (and process) of one machine.

Runs are deterministic: the same code, configuration, seed and history give the same iteration.
So the state after an iteration is named by its *lineage*, a hash of the code's version and of the
configuration each iteration so far was trained with (a branch's lineage forks where its switches
changed). Thirty students pressing Step on the same lesson compute each iteration once: the first
takes the key's lock and computes, the others wait on the lock and load what it stored.

    root/<key[:2]>/<key>/   entry.npz (the learner's state and the policy's weights), record.json
    root/.locks/<key>.lock   held while one process computes that key

Entries are written to a temporary folder and renamed into place (a reader never sees half of one),
read with size checks and the safe npz reader, and evicted oldest-used first once the cache is over
`max_bytes` (a rename aside, then delete: a reader mid-read just misses). A run in use keeps its own
state in memory, so eviction never breaks it.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import uuid
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from filelock import FileLock, Timeout

from ifo.data.npz import NpzError, read_npz
from ifo.io import FAST_DEFLATE, npz_bytes
from ifo.runtime import BoundedCache

MAX_RECORD_BYTES = 16 << 20
MAX_ENTRY_BYTES = 1 << 30
WAIT_SECONDS = 600.0  # how long a session waits for another one computing the same iteration


def code_version() -> str:
    """A hash of the library's source: a change of code is a change of every key."""
    global _CODE_VERSION
    if _CODE_VERSION is None:
        h = hashlib.sha256()
        root = Path(__file__).resolve().parent
        for path in sorted(root.rglob("*.py")):
            h.update(str(path.relative_to(root)).encode())
            h.update(path.read_bytes())
        _CODE_VERSION = h.hexdigest()[:16]
    return _CODE_VERSION


_CODE_VERSION: str | None = None


def lineage_start(identity: dict) -> str:
    """The key of a run before its first iteration: the code and the configuration that built it."""
    return _hash({"code": code_version(), "start": identity})


def lineage_next(previous: str, identity: dict, iteration: int) -> str:
    """The key of the state after iteration `iteration` (counted from 1) trained with `identity` (its
    configuration). The number is part of the key: a run whose saved lineage fell behind it (runs trained
    without a cache once left it at the start) gets keys of its own, never another run's past."""
    return _hash({"after": previous, "with": identity, "iteration": int(iteration)})


def _hash(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:40]


@dataclass
class Entry:
    arrays: dict[str, np.ndarray]  # the learner's state ("learner." prefix) and policy weights ("history.")
    meta: dict
    record: dict


class IterationCache:
    def __init__(self, root: str | os.PathLike, max_bytes: int = 1 << 30):
        self.root = Path(root)
        self.max_bytes = int(max_bytes)

    def _path(self, key: str) -> Path:
        if len(key) != 40 or not all(c in "0123456789abcdef" for c in key):
            raise ValueError(f"not a cache key: {key!r}")
        return self.root / key[:2] / key

    def lock(self, key: str, timeout: float = WAIT_SECONDS) -> FileLock:
        """The lock one process holds while it computes `key` (a new instance: threads exclude each other too)."""
        (self.root / ".locks").mkdir(parents=True, exist_ok=True)
        return FileLock(str(self.root / ".locks" / f"{key}.lock"), timeout=timeout)

    def get(self, key: str) -> Entry | None:
        """The stored iteration, or None (never stored, evicted, or unreadable: then it is recomputed)."""
        path = self._path(key)
        try:
            record_file, state_file = path / "record.json", path / "entry.npz"
            record_stat, state_stat = record_file.stat(), state_file.stat()
            if record_stat.st_size > MAX_RECORD_BYTES or state_stat.st_size > MAX_ENTRY_BYTES:
                return None
            identity = (str(path), *(getattr(st, a) for st in (record_stat, state_stat)
                                     for a in ("st_ino", "st_size", "st_mtime_ns")))
            kept = _RECENT.get(identity)
            if kept is None:
                text = record_file.read_text()
                arrays = read_npz(state_file.read_bytes(), max_array_bytes=MAX_ENTRY_BYTES,
                                  max_total_bytes=2 * MAX_ENTRY_BYTES)
                for a in arrays.values():
                    a.flags.writeable = False
                kept = arrays, text
                _RECENT.put(identity, kept)
            arrays, text = kept
            stored = json.loads(text)  # the meta and record anew for each caller: theirs to change
            os.utime(path)  # recently used: evicted last
            return Entry(arrays, stored["meta"], stored["record"])
        except (OSError, ValueError, KeyError, NpzError):
            return None

    def has(self, key: str) -> bool:
        """Whether `key` is stored (without reading it; `get` may still miss it if it is unreadable)."""
        return (self._path(key) / "record.json").exists()

    def put(self, key: str, entry: Entry) -> None:
        """Store an iteration (atomically; a key already stored is left as it is), then keep within size."""
        path = self._path(key)
        if path.exists():
            return
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.parent / f".{key}.{uuid.uuid4().hex[:8]}.tmp"
        tmp.mkdir()
        try:
            (tmp / "entry.npz").write_bytes(npz_bytes(entry.arrays, FAST_DEFLATE))
            (tmp / "record.json").write_text(json.dumps({"meta": entry.meta, "record": entry.record}))
            os.rename(tmp, path)
        except OSError:  # a full disk, a race with another writer of the same key: the cache is optional
            shutil.rmtree(tmp, ignore_errors=True)
            return
        self.evict()

    def discard(self, key: str) -> None:
        _remove(self._path(key))

    def size(self) -> int:
        return sum(f.stat().st_size for f in self.root.glob("??/*/*") if f.is_file())

    def evict(self) -> int:
        """Remove the least recently used entries until the cache is under 90% of `max_bytes`; returns
        how many went. A removal is a rename aside first, so a reader never sees half an entry."""
        entries = []
        for path in self.root.glob("??/*"):
            if path.is_dir() and not path.name.startswith("."):
                try:
                    entries.append((path.stat().st_mtime, sum(f.stat().st_size for f in path.iterdir()), path))
                except OSError:
                    continue
        total, removed = sum(size for _, size, _ in entries), 0
        for _, size, path in sorted(entries):
            if total <= 0.9 * self.max_bytes:
                break
            if _remove(path):
                total, removed = total - size, removed + 1
        return removed


# The entries this process read last: thirty students taking the teacher's iteration read the same entry,
# and reading it is a tenth of a Step from the cache. Keyed by the files' identity (inode, size,
# modification time), so an entry evicted or rewritten on disk is read again, or missed, as before.
# The arrays are shared by every caller, so they are read-only (a learner copies what it trains).
_RECENT = BoundedCache(256 << 20, size=lambda kept: sum(a.nbytes for a in kept[0].values()) + len(kept[1]))


def _remove(path: Path) -> bool:
    """Delete an entry: renamed aside first (one atomic step), so a reader never meets half of it."""
    aside = path.with_name(f".{path.name}.{uuid.uuid4().hex[:6]}.evicted")
    try:
        os.rename(path, aside)
    except OSError:
        return False
    shutil.rmtree(aside, ignore_errors=True)
    return True


def wait_or_compute(cache: IterationCache, key: str, compute, timeout: float = WAIT_SECONDS):
    """`compute()` once per key across sessions and processes: under the key's lock, load what another
    computed meanwhile, else compute and store. Returns (entry, computed_here)."""
    try:
        with cache.lock(key, timeout):
            entry = cache.get(key)
            if entry is not None:
                return entry, False
            cache.discard(key)  # an unreadable entry, if any, makes way for the new one
            entry = compute()
            cache.put(key, entry)
            return entry, True
    except Timeout:  # someone else holds it far too long: compute without sharing
        return compute(), True


__all__ = ["IterationCache", "Entry", "code_version", "lineage_start", "lineage_next", "wait_or_compute"]
