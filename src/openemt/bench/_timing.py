"""Timing of the benchmarks: the best of repeated runs."""

import time

import numpy as np

__all__ = ["best_time"]


def best_time(f, repeats):
    """Best of ``repeats`` runs: (process CPU seconds, wall seconds, last output)."""
    best_cpu = best_wall = np.inf
    out = None
    for _ in range(max(1, repeats)):
        c0 = time.process_time()
        w0 = time.perf_counter()
        out = f()
        best_cpu = min(best_cpu, time.process_time() - c0)
        best_wall = min(best_wall, time.perf_counter() - w0)
    return best_cpu, best_wall, out
