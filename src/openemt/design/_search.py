"""The search shared by the layout optimisations (docs/design.md#optimize): the statistic
of the position bound over a map's poses, its smooth stand-in, the penalised objective keeping
the best feasible layout, and scipy's bounded Powell method over it."""

from __future__ import annotations

import numpy as np

from ._orient import map_poses

__all__ = []

#: The search's smooth stand-in for a statistic: the mean above this percentile.
SMOOTH_PERCENTILE = {"p95": 90.0, "max": 98.0}


class _Search:
    """What every layout search shares: the statistic of the position bound over the map's
    poses, its smooth stand-in, and the penalised objective keeping the best feasible
    layout. A subclass gives ``position_std(x)`` and ``penalty(x)``."""

    def __init__(self, points, rotations, sigma, statistic):
        self.points, self.rotations, self.sigma = points, rotations, sigma
        self.statistic = statistic
        self.poses = map_poses(points, rotations)
        self.evaluations = 0
        self.best = (None, np.inf)

    def stat(self, values) -> float:
        v = np.asarray(values).ravel()
        if not np.all(np.isfinite(v)):
            return np.inf
        return float({"median": np.median, "p95": lambda a: np.percentile(a, 95),
                      "max": np.max}[self.statistic](v))

    def smooth(self, values) -> float:
        """What the search minimises: the statistic itself for the median; for the 95th
        percentile and the maximum, the mean of the values above the 90th / 98th percentile
        (an upper bound of the statistic's neighbourhood that does not jump when another
        point becomes the percentile)."""
        v = np.asarray(values).ravel()
        if not np.all(np.isfinite(v)):
            return np.inf
        if self.statistic == "median":
            return float(np.median(v))
        q = np.percentile(v, SMOOTH_PERCENTILE[self.statistic])
        return float(np.mean(v[v >= q]))

    def objective(self, x) -> float:
        """The smooth statistic, raised by the constraint penalty; the best layout that meets
        the constraints is kept as the search goes (``best``)."""
        self.evaluations += 1
        pen = self.penalty(x)
        f = self.smooth(self.position_std(x))
        if pen == 0 and f < self.best[1]:
            self.best = (np.array(x, dtype=np.float64), f)
        return f * (1.0 + 100.0 * pen / 0.01)

    def search(self, x0, scale, lo, hi, free, opts, jitter):
        """scipy's Powell method over the ``free`` entries of ``x`` in units of ``scale``,
        bounded to ``[lo, hi]``, from ``x0`` and ``opts.starts - 1`` copies perturbed by
        ``jitter`` standard deviations; ``opts.max_evaluations`` evaluations in all."""
        from scipy.optimize import minimize

        rng = np.random.default_rng(opts.seed)
        self.objective(x0)
        per_start = max(1, (opts.max_evaluations - 1) // opts.starts)
        f = np.flatnonzero(free)

        def full(u):
            x = x0.copy()
            x[f] = x0[f] + u * scale[f]
            return x

        for k in range(opts.starts):
            xs = x0 if k == 0 else np.clip(x0 + jitter * rng.standard_normal(x0.size), lo, hi)
            if k and self.penalty(xs) > 0:
                xs = x0
            b = list(zip((lo[f] - x0[f]) / scale[f], (hi[f] - x0[f]) / scale[f]))
            minimize(lambda u: self.objective(full(u)), (xs[f] - x0[f]) / scale[f],
                     method="Powell", bounds=b,
                     options={"maxfev": per_start, "xtol": 1e-3, "ftol": 1e-4})
        return self.best[0]
