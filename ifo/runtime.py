"""Process-wide settings for running on a small shared CPU machine."""
from __future__ import annotations

import os

import torch


def limit_threads() -> int:
    """Use one torch thread unless IFO_TORCH_THREADS says otherwise.

    The networks here are tiny: extra threads mostly spin and, with other processes or
    sessions on the same two cores, made an iteration 10x slower in our measurements.
    """
    n = int(os.environ.get("IFO_TORCH_THREADS", "1"))
    if torch.get_num_threads() != n:
        torch.set_num_threads(n)
    return n
