"""Kindratenko polynomial correction of position and orientation (Kindratenko 1999).

Position: ``x~ = x + sum_j c_xj x^p y^q z^s`` over all exponent triples with
``p + q + s <= r`` (likewise y, z), fitted by linear least squares to the offsets
``reference - measured`` of the calibration pairs. Orientation: the rotation offset
``rho = log(R_ref R_meas^T)`` (a rotation vector in the source frame) is fitted by the same
kind of polynomial of the measured position and applied as ``exp([rho(x)]x) R_meas``.
Positions are centred and scaled into about [-1, 1]^3 before building the monomials.

The orders of the position and the orientation polynomials are chosen separately by k-fold
cross-validation over 1..5 unless given.

Identifiability: calibration data are often taken on a grid (ILEMT's md pattern has 3 levels
per axis). On c levels, ``x^c`` is indistinguishable from lower powers at the data, so a fit
with such terms is free to oscillate between the levels; random k-fold cross-validation
cannot see this because every held-out point is on a level too. :func:`axis_levels` detects
axes sampled at a few well-populated levels, and powers >= c along such an axis are left out
of the monomials (``max_power``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._errors import InputError
from ._crossval import (
    apply_rotation_offsets,
    location_kfold,
    normalizer,
    pair_errors,
    rotation_offsets,
)

__all__ = [
    "POLY_ORDERS",
    "PolynomialCorrection",
    "axis_levels",
    "fit_polynomial",
    "monomial_exponents",
    "monomials",
]

#: Orders tried by the cross-validated selection (Kindratenko 1999 uses up to 5).
POLY_ORDERS = (1, 2, 3, 4, 5)


def monomial_exponents(order: int, max_power=None) -> np.ndarray:
    """Exponent triples (p, q, s) with ``p + q + s <= order``, by total degree; (n_terms, 3).

    ``n_terms = C(order + 3, 3)``: 4, 10, 20, 35, 56 for orders 1-5. ``max_power`` (3 ints or
    None per axis) drops terms whose power along an axis exceeds the limit.
    """
    order = int(order)
    if order < 0:
        raise InputError(f"expected a polynomial order >= 0, got {order}")
    out = [(p, q, deg - p - q) for deg in range(order + 1)
           for p in range(deg, -1, -1) for q in range(deg - p, -1, -1)]
    e = np.array(out, dtype=np.int64).reshape(-1, 3)
    if max_power is not None:
        lim = np.array([order if m is None else int(m) for m in max_power])
        e = e[np.all(e <= lim, axis=1)]
    return e


def monomials(u, order: int, max_power=None) -> np.ndarray:
    """Monomials of scaled positions ``u`` (N, 3) up to ``order``: shape (N, n_terms)."""
    u = np.asarray(u, dtype=np.float64)
    e = monomial_exponents(order, max_power)
    return np.prod(u[:, None, :] ** e[None, :, :], axis=-1)


def axis_levels(u, *, gap: float = 0.1, min_fraction: float = 0.05, max_levels: int = 6):
    """Number of sampled levels per axis, or None where the sampling is continuous.

    Along each axis the sorted coordinates are split at gaps wider than ``gap`` times the
    range. If every cluster holding at least ``min_fraction`` of the points is narrower than
    that, the axis is sampled at levels: their count (clusters with at least
    ``min_fraction`` of the points; isolated key points do not count) is returned if it is at
    most ``max_levels``. Returns a tuple of 3 ``int | None``.
    """
    u = np.asarray(u, dtype=np.float64)
    n = len(u)
    out = []
    for a in range(u.shape[1]):
        v = np.sort(u[:, a])
        if n == 0:
            out.append(None)
            continue
        span = v[-1] - v[0]
        if span <= 0:
            out.append(1)
            continue
        parts = np.split(v, np.flatnonzero(np.diff(v) > gap * span) + 1)
        big = [c for c in parts if len(c) >= min_fraction * n]
        if not big or any(c[-1] - c[0] > gap * span for c in big) or len(big) > max_levels:
            out.append(None)
        else:
            out.append(len(big))
    return tuple(out)


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
    max_power : tuple of 3 (int or None), or None
        Highest power allowed along each axis (from :func:`axis_levels`), None: no limit.
    selection : dict
        Cross-validation scores per tried order (``position`` in m, ``orientation`` in rad).
    """

    center: np.ndarray
    scale: float
    pos_order: int
    pos_coef: np.ndarray
    rot_order: int | None = None
    rot_coef: np.ndarray | None = None
    max_power: tuple | None = None
    selection: dict = field(default_factory=dict)

    def _u(self, xyz):
        return (np.asarray(xyz, dtype=np.float64) - self.center) / self.scale

    def predict(self, xyz, R=None):
        """Corrected positions (N, 3) and rotations (N, 3, 3) (``None`` if ``R`` is None)."""
        u = self._u(xyz)
        out_xyz = xyz + monomials(u, self.pos_order, self.max_power) @ self.pos_coef
        if R is None or self.rot_coef is None:
            return out_xyz, R
        rho = monomials(u, self.rot_order, self.max_power) @ self.rot_coef
        return out_xyz, apply_rotation_offsets(rho, R)

    def to_params(self) -> dict:
        return {"center": self.center, "scale": self.scale, "pos_order": self.pos_order,
                "pos_coef": self.pos_coef, "rot_order": self.rot_order,
                "rot_coef": self.rot_coef, "max_power": None if self.max_power is None else list(self.max_power),
                "selection": self.selection}

    @classmethod
    def from_params(cls, p: dict) -> PolynomialCorrection:
        rc = p.get("rot_coef")
        return cls(center=np.asarray(p["center"], float), scale=float(p["scale"]),
                   pos_order=int(p["pos_order"]),
                   pos_coef=np.asarray(p["pos_coef"], float).reshape(-1, 3),
                   rot_order=None if p.get("rot_order") is None else int(p["rot_order"]),
                   rot_coef=None if rc is None else np.asarray(rc, float).reshape(-1, 3),
                   max_power=None if p.get("max_power") is None
                   else tuple(None if m is None else int(m) for m in p["max_power"]),
                   selection=dict(p.get("selection") or {}))


def _select_order(u, target, orders, splits, score, max_power, basis=None
                  ) -> tuple[int, dict]:
    """Order with the lowest held-out RMS of ``score(prediction, rows)`` (lowest on ties).

    ``basis(u, order)`` gives the design matrix (default: the monomials up to ``order``)."""
    scores = {}
    n = len(u)
    for r in orders:
        A = monomials(u, r, max_power) if basis is None else basis(u, r)
        n_terms = A.shape[1]
        if n_terms > min(len(tr) for tr, _ in splits):
            continue
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
        raise InputError(f"expected enough pairs for a polynomial of order {min(orders)}, "
                         f"got {n}")
    best = min(scores, key=lambda r: scores[r]["held_out_rms"])
    return best, scores


def fit_offset_terms(u, off, measured_R, reference_R, order, rot_order, orders, splits,
                     selection: dict, basis, what: str):
    """Position offsets ``off`` and (with both rotation arrays) rotation offsets fitted as linear
    combinations of the terms ``basis(u, order)``, each order chosen by held-out error when
    None (recorded in ``selection``); shared by the total-degree polynomial and the
    tensor-product Bernstein corrections.

    Returns ``(order, pos_coef, rot_order, rot_coef)`` (the rotation pair None without
    rotations)."""
    n = len(u)
    if order is None:
        order, selection["position"] = _select_order(
            u, off, orders, splits, lambda pred, rows: pair_errors(pred, None, off[rows], None)[0],
            None, basis)
    A = basis(u, order)
    if A.shape[1] > n:
        raise InputError(f"expected at least {A.shape[1]} pairs for {what} {order}, got {n}")
    pos_coef = _lstsq(A, off)
    if measured_R is None or reference_R is None:
        return order, pos_coef, None, None
    Rm = np.asarray(measured_R, dtype=np.float64)
    Rd = np.asarray(reference_R, dtype=np.float64)
    rho = rotation_offsets(Rm, Rd)

    def rot_score(pred, rows):
        zero = np.zeros((len(rows), 3))
        return pair_errors(zero, apply_rotation_offsets(pred, Rm[rows]), zero, Rd[rows])[1]

    if rot_order is None:
        rot_order, selection["orientation"] = _select_order(u, rho, orders, splits, rot_score,
                                                            None, basis)
    A = basis(u, rot_order)
    if A.shape[1] > n:
        raise InputError(f"expected at least {A.shape[1]} pairs for {what} {rot_order} of the "
                         f"rotations, got {n}")
    return order, pos_coef, rot_order, _lstsq(A, rho)


def fit_polynomial(measured_xyz, reference_xyz, measured_R=None, reference_R=None, *,
                   order: int | None = None, rot_order: int | None = None,
                   orders=POLY_ORDERS, max_power="auto", k: int = 5,
                   seed: int = 0) -> PolynomialCorrection:
    """Fit a Kindratenko polynomial correction (Kindratenko 1999) to pose pairs.

    Parameters
    ----------
    measured_xyz, reference_xyz : ndarray, shape (N, 3)
        Measured and reference positions (m). Validated by the caller.
    measured_R, reference_R : ndarray, shape (N, 3, 3), optional
        Measured and reference rotations; if given, the orientation is corrected as well.
    order, rot_order : int, optional
        Polynomial orders; ``None`` selects each by k-fold cross-validation over ``orders``.
    max_power : tuple of 3 (int or None), "auto" or None
        Per-axis power limit; ``"auto"`` (default) uses ``axis_levels(u) - 1`` on axes sampled
        at few levels (see the module docstring); ``None`` disables the limit.
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
    if isinstance(max_power, str):
        if max_power != "auto":
            raise InputError(f"expected max_power 'auto', None or 3 ints, got {max_power!r}")
        levels = axis_levels(u)
        max_power = (None if all(c is None for c in levels)
                     else tuple(None if c is None else c - 1 for c in levels))
    elif max_power is not None:
        max_power = tuple(None if c is None else int(c) for c in max_power)
        if len(max_power) != 3:
            raise InputError(f"expected max_power of 3 entries, got {len(max_power)}")
    splits = (location_kfold(m, k, seed=seed) if (order is None or rot_order is None)
              else None)
    selection = {}

    order, pos_coef, rot_order, rot_coef = fit_offset_terms(
        u, d - m, measured_R, reference_R, order, rot_order, orders, splits, selection,
        lambda uu, r: monomials(uu, r, max_power), "a polynomial correction of order")
    return PolynomialCorrection(center=center, scale=scale, pos_order=int(order),
                                pos_coef=pos_coef,
                                rot_order=None if rot_order is None else int(rot_order),
                                rot_coef=rot_coef, max_power=max_power,
                                selection=selection)
