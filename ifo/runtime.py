"""Process-wide settings for running on a small shared CPU machine."""
from __future__ import annotations

import os
import threading
from collections import OrderedDict
from typing import Any, Callable


def limit_threads(n: int | None = None) -> int:
    """Use `n` torch threads (default: IFO_TORCH_THREADS, else 1). Every `Run` calls it, so the library
    as the README shows it runs single-threaded too; set IFO_TORCH_THREADS (or call this with n) to change.

    The networks here are tiny: extra threads mostly spin and, with other processes or
    sessions on the same two cores, made an iteration 4-50x slower in our measurements.
    """
    import torch  # here, so the caches below come without torch (the maze environment uses them)

    n = int(n if n is not None else os.environ.get("IFO_TORCH_THREADS", "1"))
    if torch.get_num_threads() != n:
        torch.set_num_threads(n)
    return n


def file_stamp(path: str | os.PathLike) -> tuple | None:
    """What tells a file's versions apart (path, inode, size, modification time), None when it is missing:
    the key of what a process keeps read from a file, so a rewritten file is read again."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return str(path), st.st_ino, st.st_size, st.st_mtime_ns


class BoundedCache:
    """What a process keeps for every session (I_pre's random transitions, the cache entries it read,
    figures, maze backgrounds), oldest-used out once `size(value)` sums past `limit` (the newest always
    stays). Without `size` each value counts 1, so `limit` is a number of entries. Thread-safe;
    `get_or_build` builds a missing value once however many callers ask for it at once."""

    def __init__(self, limit: int, size: Callable[[Any], int] = lambda value: 1):
        self.limit, self.size = limit, size
        self.lock = threading.RLock()
        self._values: OrderedDict = OrderedDict()  # key -> (value, its size)
        self._building: dict = {}  # key -> the lock its one builder holds
        self._total = 0

    def get(self, key, default=None):
        with self.lock:
            if key not in self._values:
                return default
            self._values.move_to_end(key)
            return self._values[key][0]

    def put(self, key, value) -> None:
        with self.lock:
            if key in self._values:
                self._total -= self._values.pop(key)[1]
            self._values[key] = (value, self.size(value))
            self._total += self._values[key][1]
            while len(self._values) > 1 and self._total > self.limit:
                self._total -= self._values.popitem(last=False)[1][1]

    def get_or_build(self, key, build: Callable[[], Any]):
        """The value kept for `key`, else `build()`'s, kept. Different keys build in parallel; callers
        asking for the same missing key at once wait for the first one's build and take its value (a
        class of thirty opening the same iteration draws its figures once, not thirty times)."""
        missing = object()
        value = self.get(key, missing)
        if value is not missing:
            return value
        with self.lock:
            building = self._building.setdefault(key, threading.Lock())
        try:
            with building:
                value = self.get(key, missing)  # built by the caller we waited for
                if value is missing:
                    value = build()
                    self.put(key, value)
                return value
        finally:
            with self.lock:
                if self._building.get(key) is building and not building.locked():
                    del self._building[key]

    def __len__(self) -> int:
        return len(self._values)

    def clear(self) -> None:
        with self.lock:
            self._values.clear()
            self._total = 0
