"""Tensor-product Bernstein polynomial correction of position and orientation in a box.

The measured positions are mapped into the unit cube of a box ``[lower, upper]`` (the data's
bounding box widened by ``margin`` of its span on every side) and the offsets are fitted by
linear least squares in the tensor-product Bernstein basis of degree ``D`` per axis,
``B_i,D(u) B_j,D(v) B_k,D(w)`` with ``B_i,D(u) = C(D, i) u^i (1 - u)^(D - i)``: ``(D + 1)^3``
terms (8, 27, 64, 125, 216, 343 for D = 1-6). Unlike the total-degree monomials of
:mod:`._poly` (Kindratenko 1999), the tensor basis holds products such as ``x^2 y^2 z^2``
at D = 2, and the Bernstein form stays well conditioned at high degree (its basis functions
are non-negative and sum to one on the box).

The rotation offset ``rho = log(R_ref R_meas^T)`` is fitted with the same basis and applied as
``exp([rho]x) R_meas`` (as the polynomial correction does). Degrees are chosen separately for
position and orientation by k-fold cross-validation over ``BERNSTEIN_DEGREES`` unless given;
a degree is tried only when every training part holds ``MIN_PAIRS_FACTOR`` pairs per term
(docs/correction.md#how-many-pairs): D = 4 needs 375, D = 6 1029 training pairs.

Outside its box the basis extrapolates wildly, so :meth:`BernsteinCorrection.predict` refuses
positions outside the box with an ``InputError`` instead of clipping them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from math import comb

import numpy as np

from .._errors import InputError
from ._crossval import location_kfold
from ._dof import MIN_PAIRS_FACTOR
from ._poly import fit_offset_terms, predict_offsets

__all__ = ["BERNSTEIN_DEGREES", "BOX_MARGIN", "MAX_BERNSTEIN_DEGREE", "BernsteinCorrection",
           "bernstein_basis", "data_box", "fit_bernstein"]

#: Degrees per axis tried by the cross-validated selection.
BERNSTEIN_DEGREES = (1, 2, 3, 4, 5, 6)
#: Highest degree a correction file may name ((D + 1)^3 terms: 2197 at 12).
MAX_BERNSTEIN_DEGREE = 12
#: Margin added on every side of the data's bounding box, as a fraction of its span per axis.
BOX_MARGIN = 0.05


def data_box(xyz, margin: float = BOX_MARGIN) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper corners (m) of the bounding box of ``xyz`` widened by ``margin`` of its
    span per axis (an axis without spread gets +-1 mm)."""
    xyz = np.asarray(xyz, dtype=np.float64)
    lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    pad = np.where(hi > lo, float(margin) * (hi - lo), 1e-3)
    return lo - pad, hi + pad


def bernstein_basis(u, degree: int) -> np.ndarray:
    """Tensor-product Bernstein basis of ``u`` (N, 3) in the unit cube: (N, (degree + 1)^3),
    the x index slowest."""
    u = np.asarray(u, dtype=np.float64)
    D = int(degree)
    i = np.arange(D + 1)
    c = np.array([comb(D, k) for k in i], dtype=np.float64)
    b = c * u[:, :, None] ** i * (1.0 - u[:, :, None]) ** (D - i)  # (N, 3, D+1)
    return np.einsum("ni,nj,nk->nijk", b[:, 0], b[:, 1], b[:, 2]).reshape(len(u), -1)


@dataclass(frozen=True)
class BernsteinCorrection:
    """Fitted tensor-product Bernstein correction.

    Attributes
    ----------
    lower, upper : ndarray, shape (3,)
        Corners of the box (m); positions outside it are refused.
    pos_degree : int
    pos_coef : ndarray, shape ((pos_degree + 1)^3, 3)
        Coefficients of the position offsets (m).
    rot_degree : int or None
    rot_coef : ndarray or None
        Coefficients of the rotation-vector offsets (rad).
    selection : dict
        Cross-validation scores per tried degree.
    """

    lower: np.ndarray
    upper: np.ndarray
    pos_degree: int
    pos_coef: np.ndarray
    rot_degree: int | None = None
    rot_coef: np.ndarray | None = None
    selection: dict = field(default_factory=dict)

    def _u(self, xyz):
        xyz = np.asarray(xyz, dtype=np.float64)
        tol = 1e-9 * (self.upper - self.lower)
        outside = np.any((xyz < self.lower - tol) | (xyz > self.upper + tol), axis=1)
        if outside.any():
            i = int(np.flatnonzero(outside)[0])
            box = ", ".join(f"{1e3 * a:.1f}..{1e3 * b:.1f}" for a, b in
                            zip(self.lower, self.upper))
            raise InputError(f"expected positions inside the bernstein correction's box "
                             f"(x, y, z in mm: {box}), got {int(outside.sum())} outside, the "
                             f"first at row {i}: "
                             f"({', '.join(f'{1e3 * v:.1f}' for v in xyz[i])}) mm; the "
                             f"correction is not extrapolated: refit it on data that covers "
                             f"these positions")
        return np.clip((xyz - self.lower) / (self.upper - self.lower), 0.0, 1.0)

    def predict(self, xyz, R=None):
        """Corrected positions (N, 3) and rotations (``None`` if ``R`` is None); InputError for
        positions outside the box."""
        return predict_offsets(self._u(xyz), xyz, R, bernstein_basis, self.pos_degree,
                               self.pos_coef, self.rot_degree, self.rot_coef)

    def to_params(self) -> dict:
        return {"lower": self.lower, "upper": self.upper, "pos_degree": self.pos_degree,
                "pos_coef": self.pos_coef, "rot_degree": self.rot_degree,
                "rot_coef": self.rot_coef, "selection": self.selection}

    @classmethod
    def from_params(cls, p: dict) -> BernsteinCorrection:
        rc = p.get("rot_coef")
        return cls(lower=np.asarray(p["lower"], float), upper=np.asarray(p["upper"], float),
                   pos_degree=int(p["pos_degree"]),
                   pos_coef=np.asarray(p["pos_coef"], float).reshape(-1, 3),
                   rot_degree=None if p.get("rot_degree") is None else int(p["rot_degree"]),
                   rot_coef=None if rc is None else np.asarray(rc, float).reshape(-1, 3),
                   selection=dict(p.get("selection") or {}))


def _degree(value, name):
    if value is None:
        return None
    d = int(value)
    if not 0 <= d <= MAX_BERNSTEIN_DEGREE or d != value:
        raise InputError(f"expected {name} an integer 0..{MAX_BERNSTEIN_DEGREE}, got {value!r}")
    return d


def fit_bernstein(measured_xyz, reference_xyz, measured_R=None, reference_R=None, *,
                  degree: int | None = None, rot_degree: int | None = None,
                  degrees=BERNSTEIN_DEGREES, box=None, margin: float = BOX_MARGIN, k: int = 5,
                  seed: int = 0) -> BernsteinCorrection:
    """Fit a tensor-product Bernstein correction to pose pairs (see the module docstring).

    Parameters
    ----------
    measured_xyz, reference_xyz : ndarray, shape (N, 3)
        Measured and reference positions (m).
    measured_R, reference_R : ndarray, shape (N, 3, 3), optional
        Rotations; if given, the orientation is corrected as well.
    degree, rot_degree : int, optional
        Degrees per axis; ``None`` selects each by k-fold cross-validation over ``degrees``.
    box : (lower, upper), optional
        The box (m); default :func:`data_box` of the measured positions with ``margin``.
    k, seed : int
        Folds and seed of the selection.

    Returns
    -------
    BernsteinCorrection
    """
    m = np.asarray(measured_xyz, dtype=np.float64)
    d = np.asarray(reference_xyz, dtype=np.float64)
    degree = _degree(degree, "degree")
    rot_degree = _degree(rot_degree, "rot_degree")
    lower, upper = data_box(m, margin) if box is None else (np.asarray(box[0], float),
                                                            np.asarray(box[1], float))
    if not np.all(upper > lower):
        raise InputError(f"expected a box with lower < upper, got {lower} and {upper}")
    probe = BernsteinCorrection(lower, upper, 0, np.zeros((1, 3)))
    u = probe._u(m)
    splits = (location_kfold(m, k, seed=seed) if (degree is None or rot_degree is None)
              else None)
    if splits is not None:
        # a degree is tried only where every training part has MIN_PAIRS_FACTOR pairs per term
        n_train = min(len(tr) for tr, _ in splits)
        degrees = [D for D in degrees if MIN_PAIRS_FACTOR * (D + 1) ** 3 <= n_train] \
            or [min(degrees)]

    selection = {}
    degree, pos_coef, rot_degree, rot_coef = fit_offset_terms(
        u, d - m, measured_R, reference_R, degree, rot_degree, degrees, splits, selection,
        bernstein_basis, "a bernstein correction of degree")
    return BernsteinCorrection(lower=lower, upper=upper, pos_degree=int(degree),
                               pos_coef=pos_coef,
                               rot_degree=None if rot_degree is None else int(rot_degree),
                               rot_coef=rot_coef, selection=selection)
