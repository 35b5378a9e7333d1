"""Calibration of a planar field generator from grid data (Anser-style board, Jaeger et al. 2017).

A single-coil (5-DOF) sensor is placed at known points of a grid over the board with a known
axis; each source coil's coupling into it is measured. The model is the finite-coil model of
the board (:func:`openemt.field.anser_field_generator` by default): coil ``i``, shifted by an
offset ``delta_i`` and scaled by a gain ``g_i``, couples into a sensor at ``p`` with axis ``u``
as::

    C_i = gain * g_i * B_i(p - delta_i) . u

where ``B_i`` is the nominal coil's field for unit gain (``coil_fields``, dipole-model units)
averaged over the sensor's length (2-point Gauss rule along ``u``; 0 = point sensor). The gain
``g_i`` includes the sensor's gain. Per coil 4 parameters are fitted by Gauss-Newton with step halving;
the field is evaluated by the finite-coil code, its gradient by central differences.

Grid CSV: a header with columns ``x, y, z`` (sensor position, m), ``ux, uy, uz`` (sensor
axis) and one column per source coil (any names, in coil order).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._errors import InputError
from ..field import ILEMT_GAIN, anser_field_generator, coil_fields

__all__ = [
    "GridData",
    "PlanarCalibration",
    "calibrate_planar",
    "planar_coupling",
    "read_grid_csv",
    "write_grid_csv",
]

_POS = ("x", "y", "z", "ux", "uy", "uz")


@dataclass(frozen=True, eq=False)
class GridData:
    """Grid measurements of a planar field generator.

    Attributes
    ----------
    points : ndarray, shape (N, 3)
        Sensor positions (m) in the board frame.
    axes : ndarray, shape (N, 3)
        Unit sensor-coil axes.
    couplings : ndarray, shape (N, n_coils)
        Coupling of each source coil into the sensor.
    coil_names : tuple of str
    """

    points: np.ndarray
    axes: np.ndarray
    couplings: np.ndarray
    coil_names: tuple = ()

    def __post_init__(self):
        p = np.asarray(self.points, dtype=np.float64)
        u = np.asarray(self.axes, dtype=np.float64)
        C = np.asarray(self.couplings, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3:
            raise InputError(f"expected `points` of shape (N, 3), got {p.shape}")
        if u.shape != p.shape:
            raise InputError(f"expected `axes` of shape {p.shape}, got {u.shape}")
        if C.ndim != 2 or C.shape[0] != p.shape[0]:
            raise InputError(f"expected `couplings` of shape ({p.shape[0]}, n_coils), "
                             f"got {C.shape}")
        if not (np.all(np.isfinite(p)) and np.all(np.isfinite(u)) and np.all(np.isfinite(C))):
            raise InputError("expected finite grid data, got NaN or inf")
        n = np.linalg.norm(u, axis=1, keepdims=True)
        if np.any(n == 0):
            raise InputError("expected non-zero sensor axes, got a zero row")
        object.__setattr__(self, "points", p)
        object.__setattr__(self, "axes", u / n)
        object.__setattr__(self, "couplings", C)
        names = tuple(self.coil_names) or tuple(f"coil{i + 1}" for i in range(C.shape[1]))
        object.__setattr__(self, "coil_names", names)


def read_grid_csv(path) -> GridData:
    """Read grid data: columns ``x, y, z, ux, uy, uz`` and one column per source coil."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"expected a grid CSV file, got missing file {str(path)!r}")
    with open(path, newline="", encoding="utf-8") as fh:
        rows = [r for r in csv.reader(fh) if r and not r[0].lstrip().startswith("#")]
    if not rows:
        raise InputError(f"{path.name}: expected a header line, got an empty file")
    header = [h.strip() for h in rows[0]]
    missing = [c for c in _POS if c not in header]
    if missing:
        raise InputError(f"{path.name}: expected columns {list(_POS)}, missing {missing}")
    coils = [h for h in header if h not in _POS]
    if not coils:
        raise InputError(f"{path.name}: expected one column per source coil, got none")
    try:
        data = np.array([[float(v) for v in r] for r in rows[1:]], dtype=np.float64)
    except ValueError as exc:
        raise InputError(f"{path.name}: expected numbers, got {exc}") from None
    if data.ndim != 2 or data.shape[1] != len(header):
        raise InputError(f"{path.name}: expected {len(header)} values per row")
    col = {h: i for i, h in enumerate(header)}
    return GridData(points=data[:, [col["x"], col["y"], col["z"]]],
                    axes=data[:, [col["ux"], col["uy"], col["uz"]]],
                    couplings=data[:, [col[c] for c in coils]], coil_names=tuple(coils))


def write_grid_csv(data: GridData, path) -> None:
    """Write grid data in the format :func:`read_grid_csv` reads (atomically)."""
    from ..io import atomic_path

    with atomic_path(path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(list(_POS) + list(data.coil_names))
        for p, u, c in zip(data.points, data.axes, data.couplings):
            w.writerow([repr(float(v)) for v in (*p, *u, *c)])


def _sensor_rule(length: float):
    if length <= 0:
        return np.array([0.0]), np.array([1.0])
    s = length / (2 * np.sqrt(3.0))
    return np.array([-s, s]), np.array([0.5, 0.5])


def _coil_coupling(coil, points, axes, offset, length, step: float = 0.0):
    """``B(p - offset) . u`` of one coil (unit gain), averaged over the sensor length, (N,).

    With ``step > 0`` also its gradient with respect to ``offset`` by central differences,
    (N, 3); all points go to the field code in one call.
    """
    s, w = _sensor_rule(length)
    shifts = [np.zeros(3)]
    if step > 0:
        shifts += [sg * step * e for e in np.eye(3) for sg in (1.0, -1.0)]
    base = points[None, :, :] + s[:, None, None] * axes[None]              # (k, N, 3)
    pts = np.concatenate([(base - offset - sh).reshape(-1, 3) for sh in shifts])
    B = coil_fields([coil], pts)[0].reshape(len(shifts), len(s), len(points), 3)
    f = np.einsum("k,mkna,na->mn", w, B, axes)                            # (n_shift, N)
    if step <= 0:
        return f[0]
    # shift +h e evaluates the coil displaced to offset + h e
    grad = (f[1::2] - f[2::2]).T / (2 * step)
    return f[0], grad


def planar_coupling(coils, gains, offsets, points, axes, *, gain=ILEMT_GAIN,
                    sensor_length: float = 0.0) -> np.ndarray:
    """Model couplings ``(N, n_coils)`` of shifted, scaled coils into a single-coil sensor."""
    gains = np.asarray(gains, dtype=np.float64)
    offsets = np.asarray(offsets, dtype=np.float64).reshape(len(coils), 3)
    u = np.asarray(axes, dtype=np.float64)
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    return gain * np.column_stack([
        g * _coil_coupling(c, np.asarray(points, dtype=np.float64), u, d, sensor_length)
        for c, g, d in zip(coils, gains, offsets)])


@dataclass(frozen=True, eq=False)
class PlanarCalibration:
    """Fitted per-coil gains and position offsets of a planar field generator.

    Attributes
    ----------
    gains : ndarray, shape (n_coils,)
        Coil gain (times the sensor gain) relative to the nominal coil.
    offsets : ndarray, shape (n_coils, 3)
        Coil position offsets (m) in the board frame.
    gains_se, offsets_se : ndarray
        Standard errors (Gauss-Newton covariance).
    rms_residue : float
        RMS of the residuals relative to the RMS coupling.
    coils : tuple of Coil
        The nominal coils.
    iterations : int
    """

    gains: np.ndarray
    offsets: np.ndarray
    gains_se: np.ndarray
    offsets_se: np.ndarray
    rms_residue: float
    coils: tuple
    iterations: int

    def coupling(self, points, axes, *, gain=ILEMT_GAIN, sensor_length=0.0) -> np.ndarray:
        """Predicted couplings ``(N, n_coils)``."""
        return planar_coupling(self.coils, self.gains, self.offsets, points, axes, gain=gain,
                               sensor_length=sensor_length)

    def to_dict(self) -> dict:
        """JSON-ready summary: gains, offsets (mm) with standard errors, residue, iterations."""
        return {"gains": self.gains.tolist(), "gains_se": self.gains_se.tolist(),
                "offsets_mm": (self.offsets * 1e3).tolist(),
                "offsets_se_mm": (self.offsets_se * 1e3).tolist(),
                "rms_residue": self.rms_residue, "iterations": self.iterations}


def calibrate_planar(data: GridData, coils=None, *, gain=ILEMT_GAIN, sensor_length: float = 0.0,
                     max_iter: int = 10, step: float = 1e-5, tol: float = 1e-6
                     ) -> PlanarCalibration:
    """Fit per-coil gain and position offset of a planar field generator to grid data.

    Parameters
    ----------
    data : GridData
    coils : sequence of Coil, optional
        Nominal coils (default: :func:`openemt.field.anser_field_generator` with unit gains).
    gain : float
        Coupling scale (``1/250`` as the dipole model).
    sensor_length : float
        Sensor coil length (m) for the field average along the axis; 0 for a point sensor.
    max_iter, step, tol
        Gauss-Newton iterations, finite-difference step (m) of the field gradient, and the
        convergence threshold (offset steps below ``1e3 * tol * step``, relative gain steps
        below ``1e2 * tol``).
    """
    if not isinstance(data, GridData):
        raise TypeError(f"expected GridData, got {type(data).__name__}")
    coils = tuple(anser_field_generator(gain=1.0) if coils is None else coils)
    n_c = len(coils)
    if data.couplings.shape[1] != n_c:
        raise InputError(f"expected {n_c} coil columns, got {data.couplings.shape[1]}")
    P, U, C = data.points, data.axes, data.couplings
    n = len(P)
    scale = np.sqrt(np.mean(C ** 2))
    g = np.ones(n_c)
    d = np.zeros((n_c, 3))

    def evaluate(g, d, jac):
        F = np.empty((n, n_c))
        J = np.zeros((n, n_c, n_c, 4)) if jac else None
        for i, c in enumerate(coils):
            if jac:
                f0, grad = _coil_coupling(c, P, U, d[i], sensor_length, step)
                J[:, i, i, 0] = gain * f0
                J[:, i, i, 1:] = gain * g[i] * grad
            else:
                f0 = _coil_coupling(c, P, U, d[i], sensor_length)
            F[:, i] = gain * g[i] * f0
        return F, J

    # Gauss-Newton (the problem is nearly linear: gains enter linearly, offsets are sub-mm);
    # a step that raises the cost is halved, which needs no extra evaluation when it does not
    F, J = evaluate(g, d, True)
    r = (C - F) / scale
    cost = float(np.sum(r ** 2))
    it = 0
    for it in range(1, max_iter + 1):
        A = J.reshape(n * n_c, 4 * n_c) / scale
        H = A.T @ A
        delta = np.linalg.solve(H + 1e-12 * np.diag(np.diag(H)), A.T @ r.ravel()).reshape(n_c, 4)
        t = 1.0
        while True:
            g_new, d_new = g + t * delta[:, 0], d + t * delta[:, 1:]
            F_new, J_new = evaluate(g_new, d_new, True)
            r_new = (C - F_new) / scale
            cost_new = float(np.sum(r_new ** 2))
            if cost_new <= cost * (1 + 1e-12) or t < 1e-3:
                break
            t *= 0.5
        converged = (np.max(np.abs(t * delta[:, 1:])) < tol * 1e3 * step
                     and np.max(np.abs(t * delta[:, 0] / g)) < tol * 1e2)
        g, d, F, J, r, cost = g_new, d_new, F_new, J_new, r_new, cost_new
        if converged:
            break
    A = J.reshape(n * n_c, 4 * n_c) / scale
    dof = max(A.shape[0] - A.shape[1], 1)
    cov = np.linalg.pinv(A.T @ A) * cost / dof
    se = np.sqrt(np.clip(np.diag(cov), 0, None)).reshape(n_c, 4)
    return PlanarCalibration(gains=g, offsets=d, gains_se=se[:, 0], offsets_se=se[:, 1:],
                             rms_residue=float(np.sqrt(cost / r.size)), coils=coils,
                             iterations=it)
