"""Held-out splits, defined once for every calibration (docs/calibration.md#held-out-splits).

A calibration is scored on rows it never fitted. The schemes:

* ``random`` -- a fraction of the rows, drawn with a seed (reference collections);
* ``checkerboard`` -- the "white" squares of a grid of points: every held-out point has fitted
  neighbours on all sides (planar grids);
* ``location`` -- whole regions of the volume: the positions' bounding box cut into 2 x 2 x 2
  cells and the cells of odd index sum held out, so a held-out point's neighbourhood was not
  fitted (a stricter test of interpolation than ``random``);
* ``ld`` -- the paper's test rows (pattern ``ld`` of an ILEMT collection; MacLachlan et al. 2025
  §VI), the calibration's rows being the ``md`` ones.

:func:`holdout_split` returns the boolean mask of the held-out rows.
"""

from __future__ import annotations

import numpy as np

from .._errors import InputError

__all__ = ["HOLDOUT_SCHEMES", "checkerboard_split", "holdout_split", "location_split"]

#: The named schemes of :func:`holdout_split` (a number is a ``random`` fraction).
HOLDOUT_SCHEMES = ("random", "checkerboard", "location", "ld")


def checkerboard_split(points, tolerance: float = 1e-3) -> np.ndarray:
    """Boolean mask of the "black" squares of a grid (fit points); the rest are held out.

    Along each of x, y and z the sorted coordinates are grouped into grid lines wherever
    neighbours differ by more than ``tolerance`` (m), which absorbs a slightly tilted or noisy
    grid; a point is black when the sum of its three line indices is even, so every held-out
    point has fitted neighbours on all sides.
    """
    P = np.asarray(points, dtype=np.float64)
    idx = np.zeros(len(P), dtype=np.int64)
    for a in range(3):
        order = np.argsort(P[:, a], kind="stable")
        line = np.concatenate([[0], np.cumsum(np.diff(P[order, a]) > tolerance)])
        idx[order] += line
    return idx % 2 == 0


def location_split(points, cells: int = 2) -> np.ndarray:
    """Boolean mask of the held-out rows of the ``location`` scheme: the bounding box of
    ``points (N, 3)`` cut into ``cells`` per axis (along axes that vary), cells of odd index
    sum held out."""
    P = np.asarray(points, dtype=np.float64)
    lo, hi = P.min(axis=0), P.max(axis=0)
    span = np.where(hi > lo, hi - lo, 1.0)
    k = np.clip(np.floor((P - lo) / span * cells), 0, cells - 1).astype(np.int64)
    k[:, hi <= lo] = 0
    return k.sum(axis=1) % 2 == 1


def holdout_split(scheme, n: int, *, points=None, patterns=None, seed: int = 0,
                  min_train: int = 1, what: str = "rows") -> np.ndarray:
    """Boolean mask ``(n,)`` of the held-out rows.

    Parameters
    ----------
    scheme : float or str
        A fraction in [0, 1) (``random``: that fraction of the rows, at least one when it is
        non-zero), or ``'checkerboard'`` / ``'location'`` (need ``points (n, 3)``) or ``'ld'``
        (needs ``patterns (n,)``).
    seed : int
        Seed of the ``random`` draw.
    min_train : int
        Fewest rows left to fit; fewer is a one-line InputError naming them ``what``.
    """
    if isinstance(scheme, str) and scheme not in HOLDOUT_SCHEMES[1:]:
        try:
            scheme = float(scheme)
        except ValueError:
            raise InputError(f"expected a held-out fraction in [0, 1) or a scheme in "
                             f"{list(HOLDOUT_SCHEMES[1:])}, got {scheme!r}") from None
    if isinstance(scheme, str):
        if scheme in ("checkerboard", "location"):
            if points is None or np.shape(points) != (n, 3):
                raise InputError(f"expected positions ({n}, 3) for the {scheme!r} hold-out, "
                                 f"got {None if points is None else np.shape(points)}")
            test = (~checkerboard_split(points) if scheme == "checkerboard"
                    else location_split(points))
        else:
            if patterns is None or len(patterns) != n:
                raise InputError("expected the rows' patterns for the 'ld' hold-out, got none")
            test = np.asarray(patterns) == "ld"
    else:
        h = float(scheme)
        if not 0.0 <= h < 1.0:
            raise InputError(f"expected a held-out fraction in [0, 1), got {scheme!r}")
        n_test = round(h * n)
        if h > 0 and n_test == 0:
            n_test = 1
        test = np.zeros(n, bool)
        test[np.random.default_rng(seed).permutation(n)[:n_test]] = True
    if n - int(test.sum()) < min_train:
        raise InputError(f"expected at least {min_train} training {what}, got "
                         f"{n - int(test.sum())} of {n} (held out by {scheme!r})")
    return test
