"""Shared pieces of the navigation fits: RANSAC over minimal sets and the covariance of a linear
least-squares fit.

RANSAC (Fischler & Bolles 1981) draws minimal sets of rows, fits each, and keeps the hypothesis
with the most support. Without a user threshold the support is scored by the least median of
squares (Rousseeuw 1984): the hypothesis with the smallest median residual distance wins, the
noise scale is read from that median, and rows farther than the chi-square quantile at ``1 - OUTLIER_P`` are
outliers (``OUTLIER_P``). The final model is refitted on the inliers, and the inlier set recomputed with the
refitted scale until it no longer changes.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.stats import chi2

__all__ = ["OUTLIER_P", "linear_covariance", "ransac"]

#: Tail probability of the chi-square(3) screen: a row whose 3-D residual distance exceeds the
#: ``1 - OUTLIER_P`` quantile of the residual distance of Gaussian noise is an outlier.
OUTLIER_P = 1e-3



def _sigmas(dof: int) -> tuple[float, float]:
    """Median and outlier threshold of the length of a ``dof``-dimensional isotropic Gaussian
    vector, in units of its per-axis sigma."""
    return float(np.sqrt(chi2.ppf(0.5, dof))), float(np.sqrt(chi2.ppf(1 - OUTLIER_P, dof)))


def linear_covariance(J: np.ndarray, r: np.ndarray, n_params: int) -> tuple[np.ndarray, float]:
    """Covariance ``s^2 (J^T J)^-1`` of a least-squares fit with Jacobian ``J`` (rows, params)
    and residuals ``r`` (rows), ``s^2 = |r|^2 / (rows - params)``; returns (cov, s)."""
    dof = max(len(r) - n_params, 1)
    s2 = float(r @ r) / dof
    cov = s2 * np.linalg.pinv(J.T @ J)
    return cov, float(np.sqrt(s2))


def ransac(n: int, minimal: int, fit: Callable, distance: Callable, *, threshold=None,
           iterations: int = 300, seed: int = 0, per_axis: Callable | None = None,
           dof: int = 3):
    """Robust fit over ``n`` rows.

    Parameters
    ----------
    n, minimal : int
        Rows, and rows per hypothesis.
    fit : callable(rows) -> model or None
        Least-squares fit on the given row indices (None: degenerate set).
    distance : callable(model) -> ndarray (n,)
        Residual distance of every row.
    threshold : float, optional
        Inlier distance; None: least median of squares with the noise scale read from the median.
    per_axis : callable(model, rows) -> float, optional
        Per-axis noise sigma of a fitted model on its rows (the refit scale); default
        ``RMS distance / sqrt(dof)``.
    dof : int
        Dimension of the residual vector whose length ``distance`` gives (3: a 3-D miss).

    Returns
    -------
    (model, inlier mask, threshold used)
    """
    rng = np.random.default_rng(seed)
    best, best_score = None, None
    for _ in range(int(iterations)):
        rows = rng.choice(n, minimal, replace=False)
        model = fit(rows)
        if model is None:
            continue
        d = distance(model)
        if threshold is None:
            score = (float(np.median(d)),)
        else:
            inl = d < threshold
            score = (-int(inl.sum()), float(np.sqrt(np.mean(d[inl] ** 2))) if inl.any() else 0.0)
        if best_score is None or score < best_score:
            best, best_score = model, score
    if best is None:
        return None, np.zeros(n, bool), threshold
    median_sigmas, outlier_sigmas = _sigmas(dof)
    if per_axis is None:
        def per_axis(model, rows):
            d = distance(model)[rows]
            return float(np.sqrt(np.mean(d ** 2) / dof))
    d = distance(best)
    thr = threshold if threshold is not None else outlier_sigmas * float(np.median(d)) / median_sigmas
    inlier = d < max(thr, 1e-12)
    model = best
    for _ in range(10):
        refit = fit(np.flatnonzero(inlier))
        if refit is None:
            break
        model = refit
        if threshold is None:
            thr = outlier_sigmas * per_axis(model, np.flatnonzero(inlier))
        new = distance(model) < max(thr, 1e-12)
        if np.array_equal(new, inlier):
            break
        inlier = new
    return model, inlier, thr
