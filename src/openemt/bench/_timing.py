"""Timing of the benchmarks: the best of repeated runs."""

import time

__all__ = ["best_time", "cpu_us_per_item"]


def best_time(f, repeats, stat=min):
    """Best (or ``stat``, e.g. ``np.median``) of ``repeats`` runs: (process CPU seconds, wall
    seconds, the output of the run fastest by the wall clock)."""
    cpu, wall, out = [], [], None
    for _ in range(max(1, repeats)):
        c0 = time.process_time()
        w0 = time.perf_counter()
        value = f()
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
        if wall[-1] <= min(wall):
            out = value
    return stat(cpu), stat(wall), out


def cpu_us_per_item(fn, items: int, reps: int = 200, repeats: int = 1) -> float:
    """Process CPU microseconds per item of ``fn``, which handles ``items`` per call: the best
    of ``repeats`` runs of ``reps`` calls."""
    def calls():                    # outputs dropped at once, as a caller would
        for _ in range(reps):
            fn()

    cpu, _, _ = best_time(calls, repeats)
    return 1e6 * cpu / (reps * items)
