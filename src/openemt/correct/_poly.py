"""Kindratenko polynomial correction of position and orientation (seed 002).

Position: ``x~ = x + sum_j c_xj x^p y^q z^s`` over all exponent triples with
``p + q + s <= r`` (likewise y, z), fitted by linear least squares to the offsets
``reference - measured`` of the calibration pairs. Orientation: the rotation offset
``rho = log(R_ref R_meas^T)`` (a rotation vector in the source frame) is fitted by the same
kind of polynomial of the measured position and applied as ``exp([rho(x)]x) R_meas``.
Positions are centred and scaled into about [-1, 1]^3 before building the monomials.

The orders of the position and the orientation polynomials are chosen separately by k-fold
cross-validation over 1..5 unless given.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from math import comb

import numpy as np

from ._crossval import (
    apply_rotation_offsets,
    kfold_splits,
    normalizer,
    position_errors,
    rotation_errors,
    rotation_offsets,
)

__all__ = [
    "POLY_ORDERS",
    "PolynomialCorrection",
    "fit_polynomial",
    "monomial_exponents",
    "monomials",
]

#: Orders tried by the cross-validated selection (seed 002 uses up to 5).
POLY_ORDERS = (1, 2, 3, 4, 5)


def monomial_exponents(order: int) -> np.ndarray:
    """Exponent triples (p, q, s) with ``p + q + s <= order``, by total degree; (n_terms, 3).

    ``n_terms = C(order + 3, 3)``: 4, 10, 20, 35, 56 for orders 1-5.
    """
    order = int(order)
    if order < 0:
        raise ValueError(f"expected a polynomial order >= 0, got {order}")
    out = [(p, q, deg - p - q) for deg in range(order + 1)
           for p in range(deg, -1, -1) for q in range(deg - p, -1, -1)]
    return np.array(out, dtype=np.int64).reshape(-1, 3)


def monomials(u, order: int) -> np.ndarray:
    """Monomials of scaled positions ``u`` (N, 3) up to ``order``: shape (N, n_terms)."""
    u = np.asarray(u, dtype=np.float64)
    e = monomial_exponents(order)
    return np.prod(u[:, None, :] ** e[None, :, :], axis=-1)


def _lstsq(A, y):
    return np.linalg.lstsq(A, y, rcond=None)[0]


@dataclass(frozen=True)
class PolynomialCorrection:
    """Fitted polynomial correction (position, and orientation if fitted).

    Attributes
    ----------
    center : ndarray, shape (3,)
        Centre (m) subtracted from measured positions before scaling.
    scale : float
        Scale (m) dividing the centred positions.
    pos_order : int
    pos_coef : ndarray, shape (n_terms, 3)
        Coefficients of the position offsets (m) per monomial of :func:`monomial_exponents`.
    rot_order : int or None
    rot_coef : ndarray, shape (n_terms, 3) or None
        Coefficients of the rotation-vector offset (rad).
    selection : dict
        Cross-validation scores per tried order (``position`` in m, ``orientation`` in rad).
    """

    center: np.ndarray
    scale: float
    pos_order: int
    pos_coef: np.ndarray
    rot_order: int | None = None
    rot_coef: np.ndarray | None = None
    selection: dict = field(default_factory=dict)

    def _u(self, xyz):
        return (np.asarray(xyz, dtype=np.float64) - self.center) / self.scale

    def predict(self, xyz, R=None):
        """Corrected positions (N, 3) and rotations (N, 3, 3) (``None`` if ``R`` is None)."""
        u = self._u(xyz)
        out_xyz = xyz + monomials(u, self.pos_order) @ self.pos_coef
        if R is None or self.rot_coef is None:
            return out_xyz, R
        rho = monomials(u, self.rot_order) @ self.rot_coef
        return out_xyz, apply_rotation_offsets(rho, R)

    def to_params(self) -> dict:
        return {"center": self.center, "scale": self.scale, "pos_order": self.pos_order,
                "pos_coef": self.pos_coef, "rot_order": self.rot_order,
                "rot_coef": self.rot_coef, "selection": self.selection}

    @classmethod
    def from_params(cls, p: dict) -> PolynomialCorrection:
        rc = p.get("rot_coef")
        return cls(center=np.asarray(p["center"], float), scale=float(p["scale"]),
                   pos_order=int(p["pos_order"]),
                   pos_coef=np.asarray(p["pos_coef"], float).reshape(-1, 3),
                   rot_order=None if p.get("rot_order") is None else int(p["rot_order"]),
                   rot_coef=None if rc is None else np.asarray(rc, float).reshape(-1, 3),
                   selection=dict(p.get("selection") or {}))


def _select_order(u, target, orders, splits, score) -> tuple[int, dict]:
    """Order with the lowest held-out RMS of ``score(prediction, rows)``."""
    scores = {}
    n = len(u)
    for r in orders:
        n_terms = comb(r + 3, 3)
        if n_terms > min(len(tr) for tr, _ in splits):
            continue
        A = monomials(u, r)
        held = np.empty(n)
        for train, test in splits:
            coef = _lstsq(A[train], target[train])
            held[test] = score(A[test] @ coef, test)
        coef_all = _lstsq(A, target)
        ins = score(A @ coef_all, np.arange(n))
        scores[int(r)] = {"held_out_rms": float(np.sqrt(np.mean(held ** 2))),
                          "in_sample_rms": float(np.sqrt(np.mean(ins ** 2))),
                          "n_terms": int(n_terms)}
    if not scores:
        raise ValueError(f"expected enough pairs for a polynomial of order {min(orders)}, "
                         f"got {n}")
    best = min(scores, key=lambda r: scores[r]["held_out_rms"])
    return best, scores


def fit_polynomial(measured_xyz, reference_xyz, measured_R=None, reference_R=None, *,
                   order: int | None = None, rot_order: int | None = None,
                   orders=POLY_ORDERS, k: int = 5, seed: int = 0) -> PolynomialCorrection:
    """Fit a Kindratenko polynomial correction (seed 002) to pose pairs.

    Parameters
    ----------
    measured_xyz, reference_xyz : ndarray, shape (N, 3)
        Measured and reference positions (m). Validated by the caller.
    measured_R, reference_R : ndarray, shape (N, 3, 3), optional
        Measured and reference rotations; if given, the orientation is corrected as well.
    order, rot_order : int, optional
        Polynomial orders; ``None`` selects each by k-fold cross-validation over ``orders``.
    orders : sequence of int
        Candidate orders (default 1-5).
    k, seed : int
        Folds and seed of the selection.

    Returns
    -------
    PolynomialCorrection

    References
    ----------
    V. Kindratenko, "Calibration of electromagnetic tracking devices", Virtual Reality 4 (2000).
    """
    m = np.asarray(measured_xyz, dtype=np.float64)
    d = np.asarray(reference_xyz, dtype=np.float64)
    center, scale = normalizer(m)
    u = (m - center) / scale
    n = len(m)
    splits = kfold_splits(n, min(k, n), seed=seed) if (order is None or rot_order is None) \
        else None
    selection = {}

    off = d - m
    if order is None:
        order, selection["position"] = _select_order(
            u, off, orders, splits, lambda pred, rows: position_errors(pred, off[rows]))
    if comb(int(order) + 3, 3) > n:
        raise ValueError(f"expected at least {comb(int(order) + 3, 3)} pairs for order {order}, "
                         f"got {n}")
    pos_coef = _lstsq(monomials(u, order), off)

    rot_coef = None
    if measured_R is not None and reference_R is not None:
        Rm = np.asarray(measured_R, dtype=np.float64)
        Rd = np.asarray(reference_R, dtype=np.float64)
        rho = rotation_offsets(Rm, Rd)

        def rot_score(pred, rows):
            return rotation_errors(apply_rotation_offsets(pred, Rm[rows]), Rd[rows])

        if rot_order is None:
            rot_order, selection["orientation"] = _select_order(u, rho, orders, splits,
                                                                rot_score)
        rot_coef = _lstsq(monomials(u, rot_order), rho)
    else:
        rot_order = None
    return PolynomialCorrection(center=center, scale=scale, pos_order=int(order),
                                pos_coef=pos_coef,
                                rot_order=None if rot_order is None else int(rot_order),
                                rot_coef=rot_coef, selection=selection)
