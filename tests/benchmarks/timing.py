"""Timing helpers shared by the benchmarks."""
import time

import numpy as np


def best_of(fn, runs: int):
    """Best wall time of ``runs`` calls of ``fn`` (least disturbed by other load) and the last result."""
    best, out = float("inf"), None
    for _ in range(runs):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def median_ms(fn, runs: int, warmup: int = 3) -> float:
    """Median wall time [ms] of ``runs`` calls of ``fn`` after ``warmup`` untimed calls (caches,
    compiled kernels)."""
    for _ in range(warmup):
        fn()
    ts = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(ts))
