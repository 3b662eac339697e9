"""Timing shared by the benchmark scripts (run as `python benchmarks/NAME.py`, so importable as `_timing`)."""

from __future__ import annotations

import time

import jax
import numpy as np


def timed(fn, repeat: int = 1):
    """`(out, first, best)`: the result of `fn()`, the wall time of the first call (compile + run) and
    the best of `repeat` further calls, each until its arrays are ready."""
    start = time.perf_counter()
    out = jax.block_until_ready(fn())
    first = time.perf_counter() - start
    best = np.inf
    for _ in range(repeat):
        start = time.perf_counter()
        out = jax.block_until_ready(fn())
        best = min(best, time.perf_counter() - start)
    return out, first, best
