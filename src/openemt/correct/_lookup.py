"""Lookup-table corrections: trilinear grid table and scattered thin-plate-spline RBF.

Both tables store offsets as functions of the *measured* position: the position offset
``reference - measured`` (m) and, if orientations are given, the rotation offset
``rho = log(R_ref R_meas^T)`` (rad, source frame), applied as ``exp([rho]x) R_meas``.

* Grid (classic calibration table, Kindratenko 1999 (survey of lookup-table methods)): node values on a regular grid
  spanning the measured positions, read back by trilinear interpolation. The node values are
  the least-squares fit of the trilinear interpolant to the scattered pairs, with a small
  second-difference penalty so that nodes without nearby data are filled smoothly (the penalty
  is zero for linear offset fields, which are reproduced exactly). Outside the grid the
  position is clamped to the grid box.
* RBF: ``scipy.interpolate.RBFInterpolator`` with a thin-plate-spline kernel and a linear
  polynomial term on centred and scaled positions; ``smoothing`` trades interpolation for
  noise rejection.

``smoothing=None`` selects the penalty by k-fold cross-validation over :data:`SMOOTHING_GRID`
(grid) or :data:`SMOOTHING_RBF` (RBF).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.interpolate import RBFInterpolator
from scipy.sparse.linalg import spsolve

from .._errors import InputError, check_nonnegative
from ._crossval import (
    ROTATION_MOMENT_M,
    apply_rotation_offsets,
    held_out_poses,
    location_kfold,
    normalizer,
    pair_errors,
    rotation_offsets,
    take_rows,
)

#: largest lookup grid (nodes) a fit may ask for: 46 x 46 x 46; a larger grid has more unknowns
#: than any realistic set of pose pairs can determine, and memory grows with it
MAX_GRID_NODES = 100_000

#: most centres of an RBF correction: its fit and its evaluation build a dense matrix of
#: (centres + 4)^2 numbers (32 MB at 2000); a fit on more pairs uses a random subsample of
#: this many as centres, a file with more is refused when read
MAX_RBF_CENTRES = 2000

__all__ = [
    "MAX_GRID_NODES",
    "MAX_RBF_CENTRES",
    "SMOOTHING_GRID",
    "SMOOTHING_RBF",
    "GridCorrection",
    "RbfCorrection",
    "fit_grid",
    "fit_rbf",
]

SMOOTHING_GRID = (1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0)
SMOOTHING_RBF = (1e-8, 1e-6, 1e-4, 1e-2, 1.0, 10.0, 100.0)
#: Fewest pairs of an RBF fit: its linear part has 4 terms per coordinate.
_RBF_MIN_PAIRS = 5
#: Rows of one RBF evaluation block.
_RBF_BLOCK = 4096


def _targets(m, d, Rm, Rd):
    off = d - m
    if Rm is None or Rd is None:
        return off
    return np.hstack([off, rotation_offsets(Rm, Rd)])


def _apply_offsets(xyz, R, values):
    out = xyz + values[:, :3]
    if R is None or values.shape[1] < 6:
        return out, R
    return out, apply_rotation_offsets(values[:, 3:6], R)


def _cv_score(m, d, Rm, Rd, predict_rows) -> float:
    """Held-out score: RMS position error (m) + RMS rotation error (rad) x 0.1 m.

    The 0.1 m moment (:data:`ROTATION_MOMENT_M`) puts 1 mrad of rotation on the same footing
    as 0.1 mm of position.
    """
    xyz, R = predict_rows
    et, er = pair_errors(xyz, R, d, Rd)
    s = np.sqrt(np.mean(et ** 2))
    if er is not None:
        s += ROTATION_MOMENT_M * np.sqrt(np.mean(er ** 2))
    return float(s)


def _choose_smoothing(fit_one, m, d, Rm, Rd, grid, k, seed, min_train: int = 1
                      ) -> tuple[float, dict]:
    splits = location_kfold(m, k, seed=seed)
    smallest = min(len(train) for train, _ in splits)
    if smallest < min_train:
        raise InputError(f"expected at least {min_train} pairs in every training fold of the "
                         f"smoothing selection, got {smallest} of {len(m)} pairs")
    scores = {}
    for s in grid:
        held = held_out_poses(lambda train, s=s: fit_one(train, s), m, Rm, splits)
        scores[repr(float(s))] = _cv_score(m, d, Rm, Rd, held)
    best = min(scores, key=scores.get)
    return float(best), {"held_out_score": scores}


# ----------------------------------------------------------------------------- grid table

def _trilinear(xyz, lower, upper, shape):
    """Node indices (N, 8) and weights (N, 8) of the trilinear interpolant."""
    shape = np.asarray(shape)
    step = (upper - lower) / (shape - 1)
    g = (np.clip(xyz, lower, upper) - lower) / step
    i0 = np.clip(np.floor(g).astype(np.int64), 0, shape - 2)
    f = g - i0
    idx = np.empty((len(xyz), 8), dtype=np.int64)
    w = np.empty((len(xyz), 8))
    c = 0
    for a in (0, 1):
        for b in (0, 1):
            for e in (0, 1):
                ii = i0 + np.array([a, b, e])
                idx[:, c] = np.ravel_multi_index(ii.T, tuple(shape))
                w[:, c] = ((f[:, 0] if a else 1 - f[:, 0]) * (f[:, 1] if b else 1 - f[:, 1])
                           * (f[:, 2] if e else 1 - f[:, 2]))
                c += 1
    return idx, w


def _second_differences(shape) -> sp.csr_matrix:
    rows = []
    n = int(np.prod(shape))
    ids = np.arange(n).reshape(shape)
    for ax in range(3):
        if shape[ax] < 3:
            continue
        a = np.moveaxis(ids, ax, 0)
        lo, mid, hi = a[:-2].ravel(), a[1:-1].ravel(), a[2:].ravel()
        m = len(mid)
        r = np.repeat(np.arange(m), 3)
        cidx = np.stack([lo, mid, hi], axis=1).ravel()
        vals = np.tile([1.0, -2.0, 1.0], m)
        rows.append(sp.csr_matrix((vals, (r, cidx)), shape=(m, n)))
    if not rows:
        return sp.csr_matrix((0, n))
    return sp.vstack(rows).tocsr()


@dataclass(frozen=True)
class GridCorrection:
    """Regular-grid lookup table read by trilinear interpolation.

    Attributes
    ----------
    lower, upper : ndarray, shape (3,)
        Corners of the grid box (m).
    shape : tuple of int
        Nodes per axis (each >= 2).
    values : ndarray, shape (nx, ny, nz, 3 or 6)
        Position offsets (m) and, if 6 columns, rotation-vector offsets (rad) at the nodes.
    smoothing : float
        Weight of the second-difference penalty used in the fit.
    selection : dict
        Cross-validation scores if the smoothing was selected.
    """

    lower: np.ndarray
    upper: np.ndarray
    shape: tuple
    values: np.ndarray
    smoothing: float
    selection: dict = field(default_factory=dict)

    def predict(self, xyz, R=None):
        """Corrected positions (N, 3) and rotations (N, 3, 3) (``None`` if ``R`` is None)."""
        xyz = np.asarray(xyz, dtype=np.float64)
        idx, w = _trilinear(xyz, self.lower, self.upper, self.shape)
        flat = self.values.reshape(-1, self.values.shape[-1])
        vals = np.einsum("nk,nkc->nc", w, flat[idx])
        return _apply_offsets(xyz, R, vals)

    def to_params(self) -> dict:
        return {"lower": self.lower, "upper": self.upper, "shape": list(self.shape),
                "values": self.values, "smoothing": self.smoothing, "selection": self.selection}

    @classmethod
    def from_params(cls, p: dict) -> GridCorrection:
        shape = tuple(int(s) for s in p["shape"])
        vals = np.asarray(p["values"], float)
        return cls(lower=np.asarray(p["lower"], float), upper=np.asarray(p["upper"], float),
                   shape=shape, values=vals.reshape(shape + (vals.shape[-1],)),
                   smoothing=float(p["smoothing"]), selection=dict(p.get("selection") or {}))


#: Nodes per axis of the default grid at most (16^3 = 4096 nodes, reached at about 33,000
#: pairs): one sparse solve of the smoothing selection then takes a fraction of a second, where
#: 30^3 nodes took seconds each (hundreds per fit with its cross-validation).
MAX_DEFAULT_GRID_AXIS = 16


def _default_shape(n: int) -> tuple:
    k = int(np.clip(round((n / 8.0) ** (1.0 / 3.0)), 2, MAX_DEFAULT_GRID_AXIS))
    return (k, k, k)


def _fit_grid_once(m, y, shape, smoothing, lower, upper):
    n_nodes = int(np.prod(shape))
    idx, w = _trilinear(m, lower, upper, shape)
    W = sp.csr_matrix((w.ravel(), (np.repeat(np.arange(len(m)), 8), idx.ravel())),
                      shape=(len(m), n_nodes))
    D = _second_differences(shape)
    lam = smoothing * max(len(m), 1) / n_nodes
    A = (W.T @ W + lam * (D.T @ D) + 1e-12 * sp.identity(n_nodes)).tocsc()
    sol = spsolve(A, np.asarray(W.T @ y))
    return np.asarray(sol).reshape(tuple(shape) + (y.shape[1],))


def fit_grid(measured_xyz, reference_xyz, measured_R=None, reference_R=None, *, shape=None,
             smoothing: float | None = None, padding: float = 0.05, k: int = 5,
             seed: int = 0) -> GridCorrection:
    """Fit a regular-grid lookup table (trilinear interpolation) to pose pairs.

    Parameters
    ----------
    measured_xyz, reference_xyz : ndarray, shape (N, 3)
        Positions (m).
    measured_R, reference_R : ndarray, shape (N, 3, 3), optional
        Rotations; if given the table also corrects orientation.
    shape : tuple of 3 int, optional
        Nodes per axis; default ``round((N / 8) ** (1/3))`` per axis (at least 2, at most
        ``MAX_DEFAULT_GRID_AXIS`` = 16; a larger grid is given explicitly).
    smoothing : float, optional
        Second-difference penalty weight; ``None`` selects it by k-fold cross-validation.
    padding : float
        Fraction of the measured extent added on each side of the grid box.
    k, seed : int
        Folds and seed of the smoothing selection.
    """
    m = np.asarray(measured_xyz, dtype=np.float64)
    d = np.asarray(reference_xyz, dtype=np.float64)
    Rm = None if measured_R is None or reference_R is None else np.asarray(measured_R, float)
    Rd = None if Rm is None else np.asarray(reference_R, float)
    if smoothing is not None:
        smoothing = check_nonnegative(smoothing, "`smoothing`")
    shape = _default_shape(len(m)) if shape is None else tuple(int(s) for s in shape)
    if len(shape) != 3 or min(shape) < 2:
        raise InputError(f"expected a grid shape of 3 ints >= 2, got {shape}")
    if int(np.prod(shape, dtype=np.float64)) > MAX_GRID_NODES:
        raise InputError(f"expected a grid of at most MAX_GRID_NODES = {MAX_GRID_NODES} nodes, "
                         f"got {shape} = {int(np.prod(shape, dtype=np.float64))} nodes")
    lo, hi = m.min(axis=0), m.max(axis=0)
    ext = np.maximum(hi - lo, 1e-9)
    lower, upper = lo - padding * ext, hi + padding * ext
    y = _targets(m, d, Rm, Rd)
    selection = {}
    if smoothing is None:
        def fit_one(rows, s):
            yr = _targets(*take_rows(rows, m, d, Rm, Rd))
            return GridCorrection(lower, upper, shape,
                                  _fit_grid_once(m[rows], yr, shape, s, lower, upper), s)
        smoothing, selection = _choose_smoothing(fit_one, m, d, Rm, Rd, SMOOTHING_GRID, k, seed)
    values = _fit_grid_once(m, y, shape, float(smoothing), lower, upper)
    return GridCorrection(lower=lower, upper=upper, shape=shape, values=values,
                          smoothing=float(smoothing), selection=selection)


# ----------------------------------------------------------------------------- scattered RBF

@dataclass(frozen=True)
class RbfCorrection:
    """Scattered-data thin-plate-spline interpolation of the offsets.

    Attributes
    ----------
    center : ndarray, shape (3,)
    scale : float
        Positions are mapped to ``(xyz - center) / scale`` before interpolation.
    points : ndarray, shape (N, 3)
        Scaled measured positions of the calibration pairs.
    values : ndarray, shape (N, 3 or 6)
        Offsets at the points (m; rad for the rotation columns).
    smoothing : float
    kernel : str
    selection : dict
    """

    center: np.ndarray
    scale: float
    points: np.ndarray
    values: np.ndarray
    smoothing: float
    kernel: str = "thin_plate_spline"
    selection: dict = field(default_factory=dict)
    #: pairs the centres were drawn from when a fit subsampled them (0: all pairs are centres)
    n_centres_of: int = field(default=0, compare=False)

    def _interp(self):
        cache = self.__dict__.get("_cache")
        if cache is None:
            cache = RBFInterpolator(self.points, self.values, kernel=self.kernel,
                                    smoothing=self.smoothing, degree=1)
            object.__setattr__(self, "_cache", cache)
        return cache

    def predict(self, xyz, R=None):
        """Corrected positions (N, 3) and rotations (N, 3, 3) (``None`` if ``R`` is None),
        evaluated in blocks of rows (memory bounded by the block times the centres)."""
        xyz = np.asarray(xyz, dtype=np.float64)
        interp = self._interp()
        vals = np.empty((len(xyz), self.values.shape[1]))
        for s in range(0, len(xyz), _RBF_BLOCK):
            vals[s:s + _RBF_BLOCK] = interp((xyz[s:s + _RBF_BLOCK] - self.center) / self.scale)
        return _apply_offsets(xyz, R, vals)

    def to_params(self) -> dict:
        return {"center": self.center, "scale": self.scale, "points": self.points,
                "values": self.values, "smoothing": self.smoothing, "kernel": self.kernel,
                "selection": self.selection}

    @classmethod
    def from_params(cls, p: dict) -> RbfCorrection:
        vals = np.asarray(p["values"], float)
        return cls(center=np.asarray(p["center"], float), scale=float(p["scale"]),
                   points=np.asarray(p["points"], float).reshape(-1, 3),
                   values=vals.reshape(len(vals), -1), smoothing=float(p["smoothing"]),
                   kernel=str(p.get("kernel", "thin_plate_spline")),
                   selection=dict(p.get("selection") or {}))


def fit_rbf(measured_xyz, reference_xyz, measured_R=None, reference_R=None, *,
            smoothing: float | None = None, kernel: str = "thin_plate_spline", k: int = 5,
            seed: int = 0, max_centres: int = MAX_RBF_CENTRES) -> RbfCorrection:
    """Fit a scattered-data RBF correction (thin-plate spline by default) to pose pairs.

    ``smoothing=None`` selects the smoothing by k-fold cross-validation over
    :data:`SMOOTHING_RBF`. With more than ``max_centres`` (at most :data:`MAX_RBF_CENTRES`)
    pairs, a random subsample (``seed``) of that many is fitted: the centres
    (``n_centres_of`` records how many pairs there were). Other arguments as :func:`fit_grid`.
    """
    m = np.asarray(measured_xyz, dtype=np.float64)
    d = np.asarray(reference_xyz, dtype=np.float64)
    Rm = None if measured_R is None or reference_R is None else np.asarray(measured_R, float)
    Rd = None if Rm is None else np.asarray(reference_R, float)
    if not 1 <= int(max_centres) <= MAX_RBF_CENTRES:
        raise InputError(f"expected max_centres 1..MAX_RBF_CENTRES = {MAX_RBF_CENTRES}, got "
                         f"{max_centres}")
    n_all = len(m)
    if n_all > max_centres:
        keep = np.sort(np.random.default_rng(seed).choice(n_all, int(max_centres),
                                                          replace=False))
        m, d, Rm, Rd = take_rows(keep, m, d, Rm, Rd)
    center, scale = normalizer(m)
    pts = (m - center) / scale
    y = _targets(m, d, Rm, Rd)
    if smoothing is not None:
        smoothing = check_nonnegative(smoothing, "`smoothing`")
    if len(m) < _RBF_MIN_PAIRS:
        raise InputError(f"expected at least {_RBF_MIN_PAIRS} pairs for an RBF correction, "
                         f"got {len(m)}")
    selection = {}
    if smoothing is None:
        def fit_one(rows, s):
            return RbfCorrection(center, scale, pts[rows], y[rows], s, kernel)
        smoothing, selection = _choose_smoothing(fit_one, m, d, Rm, Rd, SMOOTHING_RBF, k, seed,
                                                 min_train=_RBF_MIN_PAIRS)
    return RbfCorrection(center=center, scale=scale, points=pts, values=y,
                         smoothing=float(smoothing), kernel=kernel, selection=selection,
                         n_centres_of=n_all if n_all > len(m) else 0)
