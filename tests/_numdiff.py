"""Central differences for the Jacobian tests (one loop instead of a copy in each test)."""

from __future__ import annotations

import numpy as np


def central_differences(f, x, *, rel_step: float = 1e-6, columns=None) -> np.ndarray:
    """``d f(x) / d x[i]`` by central differences with the step ``rel_step * max(1, |x[i]|)``,
    for every ``i`` of ``columns`` (default: all of ``x``), stacked on the last axis:
    ``f(x).shape + (len(columns),)``."""
    x = np.asarray(x, dtype=np.float64)
    columns = range(x.size) if columns is None else columns
    out = []
    for i in columns:
        h = rel_step * max(1.0, abs(x[i]))
        up, dn = x.copy(), x.copy()
        up[i] += h
        dn[i] -= h
        out.append((np.asarray(f(up)) - np.asarray(f(dn))) / (2 * h))
    return np.stack(out, axis=-1)
