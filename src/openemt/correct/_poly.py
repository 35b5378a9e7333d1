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
    pw = np.ones((3, len(u), int(order) + 1))  # powers per axis, by repeated products
    for k in range(1, int(order) + 1):
        pw[:, :, k] = pw[:, :, k - 1] * u.T
    return pw[0][:, e[:, 0]] * pw[1][:, e[:, 1]] * pw[2][:, e[:, 2]]


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
        """Corrected positions (N, 3) and rotations (N, 3, 3) (``None`` if ``R`` is None),
        evaluated in blocks of :data:`BLOCK_ROWS` rows."""
        return predict_offsets(self._u(xyz), xyz, R,
                               lambda uu, r: monomials(uu, r, self.max_power),
                               self.pos_order, self.pos_coef, self.rot_order, self.rot_coef)

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


#: Rows of one block of the design matrix: fits and predictions hold at most this many rows of
#: terms in memory (a 1e6-pair fit of order 5 holds 16384 x 62 numbers, not 1e6 x 56 x 3).
BLOCK_ROWS = 16384


def _block_gram(u, Y, rows, order, basis):
    """Normal equations of the least-squares fit of ``Y[rows]`` on ``basis(u[rows], order)``:
    ``(A^T A, A^T Y, column sums of Y^2)``, accumulated over blocks of :data:`BLOCK_ROWS`
    rows, so memory does not grow with the rows and parts of the data combine by addition."""
    p = basis(u[:1], order).shape[1]
    G, B, yy = np.zeros((p, p)), np.zeros((p, Y.shape[1])), np.zeros(Y.shape[1])
    for s in range(0, len(rows), BLOCK_ROWS):
        idx = rows[s:s + BLOCK_ROWS]
        A, y = basis(u[idx], order), Y[idx]
        G += A.T @ A
        B += A.T @ y
        yy += np.einsum("ij,ij->j", y, y)
    return G, B, yy


def _combine(parts):
    """The normal equations of the rows of several parts."""
    return tuple(sum(x) for x in zip(*parts))


def _solve(gram, cols) -> np.ndarray:
    """Least-squares coefficients (p, len(cols)) from the normal equations (minimum norm where
    the terms are not independent at the data)."""
    G, B, _ = gram
    return np.linalg.lstsq(G, B[:, cols], rcond=None)[0]


def _ssr(gram, coef, cols) -> float:
    """Residual sum of squares of the columns ``cols`` fitted by ``coef``, over the rows of
    ``gram``."""
    G, B, yy = gram
    return float(max(np.sum(yy[cols]) - 2 * np.sum(coef * B[:, cols])
                     + np.sum(coef * (G @ coef)), 0.0))


class _OffsetFits:
    """Least-squares fits of position offsets and rotation offsets (columns 0-2 and 3-5 of
    ``Y``) on the terms ``basis(u, order)``, per order, from the normal equations of every test
    part of ``splits`` (a fold's training equations are the sum of the other parts'): one pass
    over the rows per order, memory independent of the number of rows."""

    def __init__(self, u, Y, splits, basis, nested: int | None = None):
        self.u, self.Y, self.splits, self.basis = u, Y, splits, basis
        self._cache = {}
        #: with nested terms (those of a lower order are the first columns of a higher one's,
        #: as the monomials by total degree), one pass at this order serves every lower order
        self.nested = nested

    def factors(self, order):
        if self.nested is not None and order <= self.nested:
            parts, full = self._factors(self.nested)
            p = self.n_terms(order)

            def cut(g):
                return g[0][:p, :p], g[1][:p], g[2]
            return [cut(g) for g in parts], cut(full)
        return self._factors(order)

    def _factors(self, order):
        if order not in self._cache:
            rows = [test for _, test in self.splits] if self.splits else [
                np.arange(len(self.u))]
            parts = [_block_gram(self.u, self.Y, r, order, self.basis) for r in rows]
            self._cache[order] = (parts, parts[0] if len(parts) == 1 else _combine(parts))
        return self._cache[order]

    def n_terms(self, order) -> int:
        return self.basis(self.u[:1], order).shape[1]

    def coef(self, order, cols):
        return _solve(self.factors(order)[1], cols)

    def fold_coefs(self, order, cols):
        parts, _ = self.factors(order)
        return [_solve(_combine([parts[j] for j in range(len(parts)) if j != i]), cols)
                for i in range(len(parts))]


def _select_order(fits, orders, cols, rot_rms=None) -> tuple[int, dict]:
    """Order with the lowest held-out RMS (lowest on ties) of the position offsets (``cols``
    0-2: RMS of the offset error's norm, from the factors) or of the rotations
    (``rot_rms(order, fold_coefs, coef_all)`` -> (held-out, in-sample) RMS angle)."""
    scores = {}
    n = len(fits.u)
    splits = fits.splits
    for r in orders:
        p = fits.n_terms(r)
        if p > min(len(tr) for tr, _ in splits):
            continue
        coefs = fits.fold_coefs(r, cols)
        coef_all = fits.coef(r, cols)
        if rot_rms is None:
            parts, R_all = fits.factors(r)
            held = np.sqrt(sum(_ssr(P, c, cols) for P, c in zip(parts, coefs)) / n)
            ins = np.sqrt(_ssr(R_all, coef_all, cols) / n)
        else:
            held, ins = rot_rms(r, coefs, coef_all)
        scores[int(r)] = {"held_out_rms": float(held), "in_sample_rms": float(ins),
                          "n_terms": int(p)}
    if not scores:
        raise InputError(f"expected enough pairs for a polynomial of order {min(orders)}, "
                         f"got {n}")
    best = min(scores, key=lambda r: scores[r]["held_out_rms"])
    return best, scores


def _quat(rho) -> np.ndarray:
    """Unit quaternions (w, x, y, z) of rotation vectors (N, 3)."""
    theta = np.linalg.norm(rho, axis=1)
    return np.hstack([np.cos(theta / 2)[:, None],
                      (0.5 * np.sinc(theta / (2 * np.pi)))[:, None] * rho])


def _angle_between(qa, qb) -> np.ndarray:
    """Rotation angle (rad) of conj(qa) qb per row: the angle between two rotations."""
    w = np.sum(qa * qb, axis=1)
    v = (qa[:, :1] * qb[:, 1:] - qb[:, :1] * qa[:, 1:]
         - np.cross(qa[:, 1:], qb[:, 1:]))
    return 2 * np.arctan2(np.linalg.norm(v, axis=1), np.abs(w))


def predict_offsets(u, xyz, R, basis, order, coef, rot_order, rot_coef):
    """``xyz`` plus the offsets ``basis(u, order) @ coef`` and (with ``R`` and ``rot_coef``)
    ``R`` turned by the rotation offsets, in blocks of :data:`BLOCK_ROWS` rows."""
    xyz = np.asarray(xyz, dtype=np.float64)
    out = np.empty_like(xyz)
    rot = R is not None and rot_coef is not None
    out_R = np.empty_like(R) if rot else R
    for s in range(0, len(xyz), BLOCK_ROWS):
        sl = slice(s, s + BLOCK_ROWS)
        out[sl] = xyz[sl] + basis(u[sl], order) @ coef
        if rot:
            out_R[sl] = apply_rotation_offsets(basis(u[sl], rot_order) @ rot_coef, R[sl])
    return out, out_R


def fit_offset_terms(u, off, measured_R, reference_R, order, rot_order, orders, splits,
                     selection: dict, basis, what: str, nested: bool = False):
    """Position offsets ``off`` and (with both rotation arrays) rotation offsets fitted as linear
    combinations of the terms ``basis(u, order)``, each order chosen by held-out error when
    None (recorded in ``selection``); shared by the total-degree polynomial and the
    tensor-product Bernstein corrections. Fitted by normal equations accumulated in blocks
    (:class:`_OffsetFits`): time linear and memory constant in the number of pairs.

    Returns ``(order, pos_coef, rot_order, rot_coef)`` (the rotation pair None without
    rotations). ``nested``: the terms of an order are the first terms of every higher order.
    """
    n = len(u)
    has_rot = measured_R is not None and reference_R is not None
    if has_rot:
        Rm = np.asarray(measured_R, dtype=np.float64)
        Rd = np.asarray(reference_R, dtype=np.float64)
        Y = np.hstack([off, rotation_offsets(Rm, Rd)])
    else:
        Y = np.asarray(off, dtype=np.float64)
    top = max([*orders, order or 0, rot_order or 0]) if nested else None
    fits = _OffsetFits(u, Y, splits, basis, top)
    pos, rot = [0, 1, 2], [3, 4, 5]
    if order is None:
        order, selection["position"] = _select_order(fits, orders, pos)
    final = _OffsetFits(u, Y, None, basis, top) if splits is None else fits
    p = final.n_terms(order)
    if p > n:
        raise InputError(f"expected at least {p} pairs for {what} {order}, got {n}")
    pos_coef = final.coef(order, pos)
    if not has_rot:
        return order, pos_coef, None, None

    # rotation error of a predicted offset rho: the angle of (exp(rho) Rm)^T Rd (the rotation
    # part of the pose error inv(Pm) Pref), equal to the angle of exp(-rho) exp(rho_true)
    q_true = _quat(Y[:, 3:])

    def rot_rms(r, coefs, coef_all):
        fold = np.empty(n, dtype=np.int64)
        for i, (_, test) in enumerate(splits):
            fold[test] = i
        held = ins = 0.0
        for s in range(0, n, BLOCK_ROWS):
            sl = slice(s, s + BLOCK_ROWS)
            A = basis(u[sl], r)
            every = (A @ np.hstack([*coefs, coef_all])).reshape(len(A), -1, 3)
            pred = every[np.arange(len(A)), fold[sl]]  # each row by its fold's model
            for rho, which in ((pred, 0), (every[:, -1], 1)):
                e2 = float(np.sum(_angle_between(_quat(rho), q_true[sl]) ** 2))
                if which == 0:
                    held += e2
                else:
                    ins += e2
        return np.sqrt(held / n), np.sqrt(ins / n)

    if rot_order is None:
        rot_order, selection["orientation"] = _select_order(fits, orders, rot, rot_rms)
    p = final.n_terms(rot_order)
    if p > n:
        raise InputError(f"expected at least {p} pairs for {what} {rot_order} of the "
                         f"rotations, got {n}")
    return order, pos_coef, rot_order, final.coef(rot_order, rot)


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
        lambda uu, r: monomials(uu, r, max_power), "a polynomial correction of order",
        nested=True)
    return PolynomialCorrection(center=center, scale=scale, pos_order=int(order),
                                pos_coef=pos_coef,
                                rot_order=None if rot_order is None else int(rot_order),
                                rot_coef=rot_coef, max_power=max_power,
                                selection=selection)
