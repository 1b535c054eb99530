"""Timing helpers shared by the benchmarks."""
import time


def best_of(fn, runs: int):
    """Best wall time of ``runs`` calls of ``fn`` (least disturbed by other load) and the last result."""
    best, out = float("inf"), None
    for _ in range(runs):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out
