"""Process-wide settings for running on a small shared CPU machine."""
from __future__ import annotations

import os

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
