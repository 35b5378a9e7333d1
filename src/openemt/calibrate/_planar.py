"""Calibration of a planar field generator from grid data (Anser-style board, Jaeger et al. 2017).

A single-coil (5-DOF) sensor is placed at known points of a grid over the board with a known
axis; each source coil's coupling into it is measured. The model is the finite-coil model of
the board (the built-in ``anser`` board file by default, docs/planar.md): coil ``i``, shifted by an
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
import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._errors import InputError
from ..field import ILEMT_GAIN, coil_fields

__all__ = [
    "GridData",
    "PlanarCalibration",
    "PlanarErrors",
    "PlanarFit",
    "calibrate_planar",
    "check_grid_units",
    "checkerboard_split",
    "coil_residual_percent",
    "fit_planar",
    "planar_accuracy",
    "planar_coupling",
    "planar_errors",
    "read_grid",
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
    from ..io._safefile import MAX_TEXT_BYTES, read_limited

    path = Path(path)
    data = read_limited(path, "a grid CSV file", MAX_TEXT_BYTES)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(f"{path.name}: expected a grid CSV file (UTF-8 text), got a byte that "
                         f"is not UTF-8 at offset {exc.start}") from None
    rows = [r for r in csv.reader(io.StringIO(text, newline=""))
            if r and not r[0].lstrip().startswith("#")]
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


def read_grid(path) -> GridData:
    """Grid data from a grid CSV (:func:`read_grid_csv`) or from a dataset file with known
    poses (a simulation: the sensor axis is the pose's z axis, couplings signed real)."""
    path = Path(path)
    if path.suffix.lower() == ".csv" or not path.exists():
        return read_grid_csv(path)
    from ..io import read_dataset

    ds = read_dataset(path)
    if ds.poses is None or ds.n_sensor != 1:
        raise InputError(f"{path.name}: expected a grid CSV or a single-coil dataset with known "
                         f"poses, got a dataset with {ds.n_sensor} sensor coils and "
                         f"{'no' if ds.poses is None else ''} poses")
    P = ds.poses
    return GridData(P[:, :3, 3], P[:, :3, 2], ds.signed_real()[:, :, 0],
                    tuple(f"coil{i + 1}" for i in range(ds.n_source)))


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
        Nominal coils (default: the built-in ``anser`` board file, :func:`openemt.board.board_coils`).
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
    check_grid_units(data, sensor_length)
    if coils is None:
        from ..board import board_coils

        coils = board_coils("anser")
    coils = tuple(coils)
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


# --------------------------------------------------------------------------- board fit

#: Largest plausible grid coordinate (m): beyond it the grid is taken for millimetres.
_MAX_GRID_M = 2.0


@dataclass(frozen=True, eq=False)
class PlanarFit:
    """Result of :func:`fit_planar`: the fitted board model and how the fit went.

    Attributes
    ----------
    model : openemt.board.PlanarModel
        Board with fitted per-coil gains, offsets (m) and tilts (rotation vectors, rad).
    gains_se, offsets_se, tilts_se : ndarray
        Standard errors (Gauss-Newton covariance scaled by the residual variance).
    status : str
        ``converged``, ``max_iterations`` or ``singular`` (rank-deficient normal equations).
    iterations : int
    rms_residual : float
        RMS residual in coupling units.
    coil_residual_percent : ndarray, shape (n_coils,)
        RMS residual of each coil in percent of that coil's peak |coupling| on the grid.
    n_points : int
    condition : float
        Condition number of the column-scaled Jacobian.
    """

    model: object
    gains_se: np.ndarray
    offsets_se: np.ndarray
    tilts_se: np.ndarray
    status: str
    iterations: int
    rms_residual: float
    coil_residual_percent: np.ndarray
    n_points: int
    condition: float

    def to_dict(self) -> dict:
        m = self.model
        return {"status": self.status, "iterations": self.iterations,
                "n_points": self.n_points, "rms_residual": self.rms_residual,
                "condition": self.condition,
                "coil_residual_percent": self.coil_residual_percent.tolist(),
                "gains": m.gains.tolist(), "gains_se": self.gains_se.tolist(),
                "offsets_mm": (m.offsets * 1e3).tolist(),
                "offsets_se_mm": (self.offsets_se * 1e3).tolist(),
                "tilts_deg": np.degrees(m.tilts).tolist(),
                "tilts_se_deg": np.degrees(self.tilts_se).tolist()}


def check_grid_units(data: GridData, sensor_length: float | None = None) -> None:
    """Refuse grids and sensor lengths that look like millimetres (one-line InputError)."""
    big = float(np.abs(data.points).max()) if len(data.points) else 0.0
    if big > _MAX_GRID_M:
        raise InputError(f"expected grid positions x, y, z in m (|value| <= {_MAX_GRID_M:g} m), "
                         f"got up to {big:g}: millimetres given where metres are expected?")
    if sensor_length is not None and not 0 <= sensor_length <= 0.1:
        raise InputError(f"expected a sensor length in m between 0 and 0.1, got "
                         f"{sensor_length:g}: millimetres given where metres are expected?")


def coil_residual_percent(residual, couplings) -> np.ndarray:
    """RMS residual of each coil (column) in percent of its peak |coupling|."""
    peak = np.abs(couplings).max(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return 100.0 * np.sqrt(np.mean(np.asarray(residual) ** 2, axis=0)) / peak


def _cross_cols(v):
    """``e_k x v`` for k = 0, 1, 2: (N, 3 [k], 3)."""
    z = np.zeros(len(v))
    return np.stack([np.column_stack([z, -v[:, 2], v[:, 1]]),
                     np.column_stack([v[:, 2], z, -v[:, 0]]),
                     np.column_stack([-v[:, 1], v[:, 0], z])], axis=1)


def _board_jacobian(model, P, U, fit_tilt):
    """Model couplings (N, n) and the Jacobian (N, n, k) by each coil's own parameters:
    gain, offset (3) and, with ``fit_tilt``, the tilt about the coil's local x and y."""
    C, dp, du = model.coupling_points(P, U, gradient=True)
    n = model.n_coils
    k = 6 if fit_tilt else 4
    J = np.zeros((len(P), n, k))
    J[:, :, 0] = C / model.gains
    J[:, :, 1:4] = -dp                               # moving the coil by d = moving p by -d
    if fit_tilt:
        for i, c in enumerate(model.board.coils):
            centre = c.center + model.offsets[i]
            # turning the coil by w about its centre = turning the sensor by -w
            dpw = -np.einsum("nkj,nj->nk", _cross_cols(P - centre), dp[:, i])
            duw = -np.einsum("nkj,nj->nk", _cross_cols(U), du[:, i])
            dw = dpw + duw                                   # (N, 3): by board-frame w
            R = c.rotation
            J[:, i, 4] = dw @ R[:, 0]
            J[:, i, 5] = dw @ R[:, 1]
    return C, J


def fit_planar(data: GridData, model=None, *, fit_tilt=False, max_iter=50, tol=1e-10
               ) -> PlanarFit:
    """Fit per-coil gain, position offset (and with ``fit_tilt`` a small tilt) of a board to
    grid data with the compiled finite-coil model (analytic Jacobian, Levenberg-Marquardt).

    Parameters
    ----------
    data : GridData
        Known sensor positions (m) and axes and the measured couplings (any units: tesla for
        the Anser board; the gains carry the scale).
    model : openemt.board.PlanarModel, Board, str or path, optional
        Starting model (a previous fit, ``--from``) or a board (default: built-in ``anser``);
        a board starts with zero offsets and tilts and per-coil least-squares gains.
    fit_tilt : bool
        Also fit a tilt of each coil about its local x and y axes.
    max_iter, tol
        Iteration limit and relative step size below which the fit has converged.
    """
    from ..board import PlanarModel
    from ..io import load_board

    if not isinstance(data, GridData):
        raise TypeError(f"expected GridData, got {type(data).__name__}")
    if not isinstance(model, PlanarModel):
        model = PlanarModel.from_board(load_board(model))   # a Board, built-in name or file
        f0 = model.coupling_points(data.points, data.axes)
        if data.couplings.shape[1] == model.n_coils:
            g0 = np.sum(f0 * data.couplings, 0) / np.sum(f0 * f0, 0)
            model = model.replace(gains=np.where(g0 != 0, g0, 1.0))
    n = model.n_coils
    if data.couplings.shape[1] != n:
        raise InputError(f"expected {n} coil columns for this board, got "
                         f"{data.couplings.shape[1]}")
    check_grid_units(data, model.sensor_length)
    P, U, Cm = data.points, data.axes, data.couplings
    k = 6 if fit_tilt else 4
    scale = np.sqrt(np.mean(Cm ** 2))

    def unpack(m, x):
        x = x.reshape(n, k)
        tilts = m.tilts.copy()
        if fit_tilt:
            # tilt rotation vectors stay in the coil plane (no turn about the normal); the
            # Jacobian is exact at zero tilt and first-order accurate for small ones
            for i, c in enumerate(m.board.coils):
                tilts[i] = tilts[i] + x[i, 4] * c.rotation[:, 0] + x[i, 5] * c.rotation[:, 1]
        return m.replace(gains=m.gains + x[:, 0], offsets=m.offsets + x[:, 1:4], tilts=tilts)

    def full_jacobian(J):
        A = np.zeros((len(P), n, n, k))
        A[:, np.arange(n), np.arange(n)] = J
        return A.reshape(len(P) * n, n * k) / scale

    C, J = _board_jacobian(model, P, U, fit_tilt)
    r = ((Cm - C) / scale).ravel()
    cost = r @ r
    lam = 1e-6
    status, it = "max_iterations", 0
    A = full_jacobian(J)
    for it in range(1, max_iter + 1):
        col = np.linalg.norm(A, axis=0)
        if np.any(col == 0):
            status = "singular"
            break
        As = A / col
        H = As.T @ As
        g = As.T @ r
        improved = False
        step = np.zeros(n * k)
        while lam < 1e10:
            try:
                step = np.linalg.solve(H + lam * np.diag(np.diag(H)), g) / col
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            trial = unpack(model, step)
            C_t, J_t = _board_jacobian(trial, P, U, fit_tilt)
            r_t = ((Cm - C_t) / scale).ravel()
            cost_t = r_t @ r_t
            if cost_t <= cost:
                improved = True
                model, C, J, r, cost = trial, C_t, J_t, r_t, cost_t
                A = full_jacobian(J)
                lam = max(lam / 10, 1e-12)
                break
            lam *= 10
        xs = np.abs(step.reshape(n, k))
        rel = np.max(xs[:, 0] / np.abs(model.gains))
        small = rel < tol and xs[:, 1:].max() < tol * 1.0
        if not improved or small:
            status = "converged"
            break
    col = np.linalg.norm(A, axis=0)
    sv = np.linalg.svd(A / np.where(col > 0, col, 1), compute_uv=False)
    condition = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")
    if not np.isfinite(condition) or condition > 1e12:
        status = "singular"
    dof = max(A.shape[0] - A.shape[1], 1)
    cov = np.linalg.pinv(A.T @ A) * cost / dof
    se = np.sqrt(np.clip(np.diag(cov), 0, None)).reshape(n, k)
    resid = Cm - C
    tilts_se = np.zeros((n, 3))
    if fit_tilt:
        tilts_se[:, :2] = se[:, 4:6]         # about the coil's local x and y
    return PlanarFit(model=model, gains_se=se[:, 0], offsets_se=se[:, 1:4], tilts_se=tilts_se,
                     status=status, iterations=it,
                     rms_residual=float(np.sqrt(np.mean(resid ** 2))),
                     coil_residual_percent=coil_residual_percent(resid, Cm),
                     n_points=len(P), condition=condition)


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


@dataclass(frozen=True, eq=False)
class PlanarErrors:
    """Per-point errors of a board model on grid data (:func:`planar_errors`).

    Attributes
    ----------
    result : openemt.solve.SolveResult
        The 5-DOF solution of every grid point (cold start from the seed grid).
    converged : ndarray, shape (N,), bool
        Points solved with status ``converged`` (the ones scored).
    error_vectors : ndarray, shape (N, 3)
        Solved minus known position (m); NaN where not converged.
    position_error : ndarray, shape (N,)
        ``|error_vectors|`` (m); NaN where not converged.
    axis_error_deg : ndarray, shape (N,)
        Angle between the solved and the known sensor axis (deg); NaN where not converged.
    coil_residual : ndarray, shape (N, n_coils)
        Measured minus model coupling at the known poses.
    couplings : ndarray, shape (N, n_coils)
        The measured couplings.
    """

    result: object
    converged: np.ndarray
    error_vectors: np.ndarray
    position_error: np.ndarray
    axis_error_deg: np.ndarray
    coil_residual: np.ndarray
    couplings: np.ndarray

    def subset(self, mask) -> PlanarErrors:
        """The errors of the points ``mask`` (boolean or indices)."""
        return PlanarErrors(self.result.select(mask), self.converged[mask],
                            self.error_vectors[mask], self.position_error[mask],
                            self.axis_error_deg[mask], self.coil_residual[mask],
                            self.couplings[mask])

    @staticmethod
    def concatenate(parts) -> PlanarErrors:
        """Join the errors of consecutive blocks of points."""
        from ..solve import SolveResult

        parts = list(parts)
        if not parts:
            raise InputError("expected at least one block of errors to join, got none")
        return PlanarErrors(SolveResult.concatenate([p.result for p in parts]),
                            *(np.concatenate([getattr(p, f) for p in parts])
                              for f in ("converged", "error_vectors", "position_error",
                                        "axis_error_deg", "coil_residual", "couplings")))

    def summary(self) -> dict:
        """``n`` (converged points scored), ``n_failed``, ``position_rms_mm``,
        ``position_max_mm``, ``axis_rms_deg`` and ``coil_residual_percent`` (per coil: RMS of
        measured minus model coupling at the known poses, percent of the coil's peak)."""
        ok = self.converged
        dp, ang = self.position_error[ok], self.axis_error_deg[ok]
        nan = float("nan")
        return {"n": int(ok.sum()), "n_failed": int((~ok).sum()),
                "position_rms_mm": float(np.sqrt(np.mean(dp ** 2)) * 1e3) if ok.any() else nan,
                "position_max_mm": float(dp.max() * 1e3) if ok.any() else nan,
                "axis_rms_deg": float(np.sqrt(np.mean(ang ** 2))) if ok.any() else nan,
                "coil_residual_percent": coil_residual_percent(self.coil_residual,
                                                               self.couplings).tolist()}


def planar_errors(model, data: GridData, *, result=None, **solve_options) -> PlanarErrors:
    """Solve every grid point from its couplings alone (cold start from the seed grid) with the
    5-DOF solver and compare with the known positions and axes, point by point.

    ``result`` (a :class:`~openemt.solve.SolveResult` of the grid's couplings, e.g. a tracked
    solution) is scored instead of solving again.
    """
    from ..solve import Status
    from ..solve._planar import solve_planar

    if data.couplings.shape[1] != model.n_coils:
        raise InputError(f"expected {model.n_coils} coil columns for this board, got "
                         f"{data.couplings.shape[1]}")
    res = (solve_planar(data.couplings, model, initial="grid", **solve_options)
           if result is None else result)
    if len(res) != len(data.points):
        raise InputError(f"expected a solution of {len(data.points)} points, got {len(res)}")
    ok = res.status == Status.CONVERGED
    ev = np.full((len(ok), 3), np.nan)
    ev[ok] = res.poses[ok, :3, 3] - data.points[ok]
    ang = np.full(len(ok), np.nan)
    cosang = np.clip(np.einsum("ij,ij->i", res.poses[ok, :3, 2], data.axes[ok]), -1.0, 1.0)
    ang[ok] = np.degrees(np.arccos(cosang))
    resid = data.couplings - model.coupling_points(data.points, data.axes)
    return PlanarErrors(res, ok, ev, np.linalg.norm(ev, axis=1), ang, resid, data.couplings)


def planar_accuracy(model, data: GridData, **solve_options) -> dict:
    """Solve every grid point from its couplings alone (cold start from the seed grid) with the
    5-DOF solver and compare with the known positions and axes.

    Returns :meth:`PlanarErrors.summary` of :func:`planar_errors`: ``n`` (converged samples
    scored), ``n_failed``, ``position_rms_mm``, ``position_max_mm``, ``axis_rms_deg`` and
    ``coil_residual_percent`` (per coil: RMS of measured minus model coupling at the known
    poses, percent of the coil's peak).
    """
    return planar_errors(model, data, **solve_options).summary()
