"""The region a correction was fitted on, and what happens outside it.

A correction is a function of the measured position fitted on pose pairs inside a box: the
bounding box of the training positions (``FitBox``). Every method's orientation offset is a
function of the position only, so the region has no orientation part: a pose of any
orientation inside the box is inside the region.

Outside the box a fitted model extrapolates (a polynomial grows with the power of the
distance, a projective map can pass through infinity), so :func:`correct_poses` corrects only
the poses inside the box (or within an explicit margin around it) and passes the others
through uncorrected, with a status per row (:data:`STATUS`). A corrected pose that comes out
non-finite or moved by more than :func:`max_shift` is not written as corrected either.

:func:`check_over_box` refuses a model that is non-finite or degenerate anywhere in its box
(a projective denominator that vanishes in the box, a scale that overflows, coefficients that
move positions by more than the box), when a correction file is read.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._errors import InputError

__all__ = ["MAX_SHIFT_FLOOR_M", "STATUS", "FitBox", "check_over_box", "max_shift",
           "row_status"]

#: Per-row status codes of an applied correction (``extra/correction_status`` in a pose
#: dataset, the ``correction`` column of a pose CSV).
STATUS = {0: "corrected", 1: "extrapolated", 2: "outside_box", 3: "nonfinite_input",
          4: "rejected", 5: "unchecked"}
CORRECTED, EXTRAPOLATED, OUTSIDE, NONFINITE, REJECTED, UNCHECKED = range(6)

#: Least bound on the shift of a position by a correction (m); the bound is the diagonal of
#: the fitted box, at least this (:func:`max_shift`).
MAX_SHIFT_FLOOR_M = 0.05

#: Points per axis of the lattice on which a model is evaluated over its box when it is read.
_LATTICE = 5
#: Rows corrected at a time (bounds the memory of every method's evaluation).
CHUNK_ROWS = 4096


@dataclass(frozen=True)
class FitBox:
    """The axis-aligned bounding box (m) of the measured positions a correction was fitted on.

    ``source`` says where it comes from: ``"fit"`` (stored by the fit) or ``"params"``
    (rebuilt from the parameters of a version-1 file whose parameters determine it).
    """

    lower: np.ndarray
    upper: np.ndarray
    source: str = "fit"

    @classmethod
    def of(cls, xyz) -> FitBox:
        xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        return cls(xyz.min(axis=0), xyz.max(axis=0))

    @property
    def diagonal(self) -> float:
        return float(np.linalg.norm(self.upper - self.lower))

    def distance(self, xyz) -> np.ndarray:
        """Distance (m) of each position (N, 3) outside the box along the worst axis (0 inside;
        inf for a non-finite position); a tolerance of 1e-9 of the span counts as inside."""
        xyz = np.asarray(xyz, dtype=np.float64)
        tol = 1e-9 * np.maximum(self.upper - self.lower, 1e-3)
        with np.errstate(invalid="ignore"):
            d = np.maximum(self.lower - tol - xyz, xyz - self.upper - tol)
            d = np.max(np.maximum(d, 0.0), axis=-1)
        return np.where(np.isfinite(d), d, np.inf)

    def corners(self) -> np.ndarray:
        return np.array([[(self.lower, self.upper)[b][a] for a, b in enumerate(bits)]
                         for bits in np.ndindex(2, 2, 2)])

    def lattice(self, n: int = _LATTICE) -> np.ndarray:
        axes = [np.linspace(lo, hi, n) for lo, hi in zip(self.lower, self.upper)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)

    def to_dict(self) -> dict:
        return {"lower_m": self.lower.tolist(), "upper_m": self.upper.tolist(),
                "orientation": "any (every offset is a function of the position only)"}

    def describe_mm(self) -> str:
        return ", ".join(f"{1e3 * a:.1f}..{1e3 * b:.1f}" for a, b in zip(self.lower, self.upper))


def read_box(d, where: str) -> FitBox:
    """The ``box`` object of a correction file (version 2)."""
    if not isinstance(d, dict):
        raise InputError(f"{where}expected `box` as an object with lower_m and upper_m, got "
                         f"{type(d).__name__}")
    out = []
    for key in ("lower_m", "upper_m"):
        try:
            a = np.asarray(d.get(key), dtype=np.float64)
        except (TypeError, ValueError):
            a = np.full(0, np.nan)
        if a.shape != (3,) or not np.all(np.isfinite(a)):
            raise InputError(f"{where}expected `box.{key}` as 3 finite numbers (m), got "
                             f"{d.get(key)!r}"[:300])
        out.append(a)
    if not np.all(out[0] <= out[1]):
        raise InputError(f"{where}expected `box.lower_m` <= `box.upper_m` on every axis, got "
                         f"{out[0].tolist()} and {out[1].tolist()}")
    return FitBox(out[0], out[1])


def max_shift(box: FitBox | None) -> float:
    """Largest shift (m) of a position that counts as a correction: the diagonal of the fitted
    box, at least :data:`MAX_SHIFT_FLOOR_M`. A model that moves a position further is not
    correcting a tracker's error but doing something else (or is broken)."""
    return max(box.diagonal if box is not None else 0.0, MAX_SHIFT_FLOOR_M)


def _evaluate(model, xyz, R=None):
    with np.errstate(all="ignore"):
        return model.predict(xyz, R)


def check_over_box(method: str, model, box: FitBox, where: str) -> None:
    """InputError when ``model`` is non-finite or degenerate somewhere in ``box``.

    Exact where the form allows it: the denominator of a projective (DLT) map is linear, so
    its sign and smallest magnitude over the box are those of the corners; a polynomial's
    largest term over the box is bounded by its coefficients and the scaled box. Every model
    is also evaluated on a lattice of the box (:data:`_LATTICE` points per axis, corners
    included): finite positions and rotations, shifts at most :func:`max_shift`.
    """
    limit = max_shift(box)
    if method == "dlt":
        L = model.matrix
        w = box.corners() @ L[3, :3] + L[3, 3]
        scale = float(np.max(np.abs(L)))
        if not (np.all(w > 1e-12 * scale) or np.all(w < -1e-12 * scale)):
            raise InputError(
                f"{where}expected a projective correction whose denominator (row 4 of "
                f"`params.matrix`) keeps one sign over the fitted box (x, y, z in mm: "
                f"{box.describe_mm()}), got values from {w.min():.3g} to {w.max():.3g} at its "
                f"corners: it vanishes inside the box")
    if method in ("poly", "rbf"):
        with np.errstate(all="ignore"):
            u = (box.corners() - model.center) / model.scale
        if not np.all(np.isfinite(u)) or np.max(np.abs(u)) > 1e6:
            raise InputError(f"{where}expected `params.center` and `params.scale` that map the "
                             f"fitted box into about [-1, 1]^3, got scaled coordinates up to "
                             f"{np.max(np.abs(u)):.3g} (scale {model.scale:.3g} m)")
    if method == "poly":
        from ._poly import monomial_exponents

        umax = np.max(np.abs((box.corners() - model.center) / model.scale), axis=0)
        for order, coef, what in ((model.pos_order, model.pos_coef, "pos_coef"),
                                  (model.rot_order, model.rot_coef, "rot_coef")):
            if coef is None:
                continue
            e = monomial_exponents(order, model.max_power)
            with np.errstate(all="ignore"):
                bound = np.abs(coef).T @ np.prod(umax ** e, axis=1)
            if not np.all(np.isfinite(bound)):
                raise InputError(f"{where}expected `params.{what}` whose polynomial is finite "
                                 f"over the fitted box, got one that overflows")
    probe = box.lattice()
    R = np.broadcast_to(np.eye(3), (len(probe), 3, 3)).copy()
    try:
        xyz, Rc = _evaluate(model, probe, R)
    except (np.linalg.LinAlgError, ValueError, InputError) as exc:
        raise InputError(f"{where}expected a {method} correction that can be evaluated over "
                         f"its box, got {type(exc).__name__}: {exc}"[:400]) from None
    with np.errstate(all="ignore"):
        shift = np.linalg.norm(xyz - probe, axis=1)
    if not np.all(np.isfinite(shift)) or (Rc is not None and not np.all(np.isfinite(Rc))):
        raise InputError(f"{where}expected a {method} correction that is finite over its box "
                         f"(x, y, z in mm: {box.describe_mm()}), got non-finite corrected "
                         f"poses at points of the box")
    if shift.max() > limit:
        i = int(np.argmax(shift))
        raise InputError(f"{where}expected a {method} correction that moves positions of its "
                         f"box by at most {1e3 * limit:.1f} mm (the box diagonal, at least "
                         f"{1e3 * MAX_SHIFT_FLOOR_M:.0f} mm), got {1e3 * shift[i]:.4g} mm at "
                         f"({', '.join(f'{1e3 * v:.1f}' for v in probe[i])}) mm")


def row_status(box: FitBox | None, xyz, margin: float, domain=None) -> np.ndarray:
    """Status per position before correcting: NONFINITE, CORRECTED (inside the box),
    EXTRAPOLATED (outside, within ``margin`` m), OUTSIDE (beyond), UNCHECKED (no box known).
    ``domain`` (lower, upper) bounds where the model can be evaluated at all (bernstein)."""
    xyz = np.asarray(xyz, dtype=np.float64)
    finite = np.all(np.isfinite(xyz), axis=1)
    st = np.full(len(xyz), UNCHECKED if box is None else CORRECTED, dtype=np.int8)
    if box is not None:
        d = box.distance(xyz)
        st[d > 0] = EXTRAPOLATED
        st[d > margin] = OUTSIDE
    if domain is not None:
        lo, hi = domain
        with np.errstate(invalid="ignore"):
            out = np.any((xyz < lo) | (xyz > hi), axis=1)
        st[out] = OUTSIDE
    st[~finite] = NONFINITE
    return st


def correct_rows(model, box, xyz, R, margin: float, domain=None):
    """Corrected positions (N, 3), rotations (or None) and status per row (int8, STATUS):
    rows not corrected keep their input values."""
    st = row_status(box, xyz, margin, domain)
    if R is not None:
        st[~np.all(np.isfinite(R), axis=(1, 2))] = NONFINITE
    out_xyz = np.array(xyz, dtype=np.float64, copy=True)
    out_R = None if R is None else np.array(R, dtype=np.float64, copy=True)
    todo = np.flatnonzero((st == CORRECTED) | (st == EXTRAPOLATED) | (st == UNCHECKED))
    limit = max_shift(box)
    for start in range(0, len(todo), CHUNK_ROWS):
        rows = todo[start:start + CHUNK_ROWS]
        px, pR = _evaluate(model, out_xyz[rows], None if R is None else out_R[rows])
        ok = np.all(np.isfinite(px), axis=1)
        if pR is not None:
            ok &= np.all(np.isfinite(pR), axis=(1, 2))
        with np.errstate(invalid="ignore"):
            ok &= np.linalg.norm(px - out_xyz[rows], axis=1) <= limit
        st[rows[~ok]] = REJECTED
        good = rows[ok]
        out_xyz[good] = px[ok]
        if pR is not None:
            out_R[good] = pR[ok]
    return out_xyz, out_R, st


def status_counts(st) -> dict:
    """``{name: count}`` of every status code."""
    return {name: int(np.count_nonzero(st == code)) for code, name in STATUS.items()}
