"""Process-wide settings for running on a small shared CPU machine."""
from __future__ import annotations

import os
import threading
from collections import OrderedDict
from typing import Any, Callable

import torch


def limit_threads(n: int | None = None) -> int:
    """Use `n` torch threads (default: IFO_TORCH_THREADS, else 1). Every `Run` calls it, so the library
    as the README shows it runs single-threaded too; set IFO_TORCH_THREADS (or call this with n) to change.

    The networks here are tiny: extra threads mostly spin and, with other processes or
    sessions on the same two cores, made an iteration 4-50x slower in our measurements.
    """
    n = int(n if n is not None else os.environ.get("IFO_TORCH_THREADS", "1"))
    if torch.get_num_threads() != n:
        torch.set_num_threads(n)
    return n


class BoundedCache:
    """What a process keeps for every session (I_pre's random transitions, the cache entries it read),
    oldest-used out once `size(value)` sums past `max_bytes` (the newest always stays). Thread-safe;
    a caller that computes a missing value holds `lock` around get-compute-put if it must be done once."""

    def __init__(self, max_bytes: int, size: Callable[[Any], int]):
        self.max_bytes, self.size = max_bytes, size
        self.lock = threading.RLock()
        self._values: OrderedDict = OrderedDict()  # key -> (value, its size)
        self._total = 0

    def get(self, key):
        with self.lock:
            if key not in self._values:
                return None
            self._values.move_to_end(key)
            return self._values[key][0]

    def put(self, key, value) -> None:
        with self.lock:
            if key in self._values:
                self._total -= self._values.pop(key)[1]
            self._values[key] = (value, self.size(value))
            self._total += self._values[key][1]
            while len(self._values) > 1 and self._total > self.max_bytes:
                self._total -= self._values.popitem(last=False)[1][1]

    def clear(self) -> None:
        with self.lock:
            self._values.clear()
            self._total = 0
