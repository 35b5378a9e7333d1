"""Calibration of a planar field generator from grid data (Anser-style board, Jaeger et al. 2017).

A single-coil (5-DOF) sensor is placed at known points of a grid over the board with a known
axis; each source coil's coupling into it is measured. The model is the finite-coil model of
the board (the built-in ``anser`` board file by default, docs/planar.md),
:class:`openemt.board.BoardModel`: coil ``i``, shifted by an offset ``delta_i`` (and, on
request, tilted out of its plane) and scaled by a gain ``g_i``, couples into a sensor at ``p``
with axis ``u`` as ``C_i = g_i B_i(p - delta_i) . u``, the Biot-Savart field of its traces
averaged over the sensor's length. The gain ``g_i`` includes the sensor's gain. The fit is the
one calibration engine with the grid's known sensor poses as kinematics (:func:`fit_planar`).

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
from ..evaluate import coil_residual_percent
from ..solve import GridData, PlanarErrors, planar_accuracy, planar_errors
from ._engine import fit_problem, fit_provenance
from ._layout import ParameterLayout
from ._objective import CalibrationProblem
from ._split import checkerboard_split

__all__ = [
    "GridData",
    "PlanarErrors",
    "PlanarFit",
    "check_grid_units",
    "checkerboard_split",
    "coil_residual_percent",
    "fit_planar",
    "planar_accuracy",
    "planar_errors",
    "read_grid",
    "read_grid_csv",
    "write_grid_csv",
]

_POS = ("x", "y", "z", "ux", "uy", "uz")


def read_grid_csv(path) -> GridData:
    """Read grid data: columns ``x, y, z, ux, uy, uz`` and one column per source coil."""
    from ..io._safefile import read_text

    path = Path(path)
    text = read_text(path, "a grid CSV file")
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


#: Largest plausible grid coordinate (m): larger values are millimetres given as metres.
_MAX_GRID_M = 2.0


@dataclass(frozen=True, eq=False)
class PlanarFit:
    """Result of :func:`fit_planar`: the fitted board model and how the fit went.

    Attributes
    ----------
    model : openemt.board.BoardModel
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
    free: tuple = ("gains", "offsets")

    def to_calibration(self, *, insample=None, holdout=None, provenance=None):
        """The calibration file's content: the board model with this fit's standard errors,
        statistics (with the ``insample`` / ``holdout`` accuracy blocks given) and provenance
        (:func:`~openemt.calibrate._engine.fit_provenance` plus the dict ``provenance``)."""
        from ..io import Calibration

        stats = {k: v for k, v in self.to_dict().items()
                 if k in ("status", "iterations", "n_points", "rms_residual", "condition",
                          "coil_residual_percent")}
        for key, block in (("insample", insample), ("holdout", holdout)):
            if block is not None:
                stats[key] = block
        return Calibration(self.model, mode="planar", free=tuple(self.free),
                           standard_errors={"gains": self.gains_se,
                                            "offsets": self.offsets_se,
                                            "tilts": self.tilts_se},
                           stats=stats, provenance=fit_provenance("planar",
                                                                  **(provenance or {})))

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


def fit_planar(data: GridData, model=None, *, fit_tilt=False, max_iter=50, tol=1e-10,
               uncertainty: bool = True) -> PlanarFit:
    """Fit per-coil gain, position offset (and with ``fit_tilt`` a small tilt) of a board to
    grid data: the one calibration engine (:class:`~openemt.calibrate.CalibrationProblem`,
    scipy's Levenberg-Marquardt with the model interface's analytic Jacobian) with the grid's
    known sensor poses as its kinematics; standard errors and the condition number from
    :func:`~openemt.calibrate.analyse_identifiability`.

    Parameters
    ----------
    data : GridData
        Known sensor positions (m) and axes and the measured couplings (any units: tesla for
        the Anser board; the gains carry the scale).
    model : openemt.board.BoardModel, Board, str or path, optional
        Starting model (a previous fit, ``--from``) or a board (default: built-in ``anser``);
        a board starts with zero offsets and tilts and per-coil least-squares gains.
    fit_tilt : bool
        Also fit a tilt of each coil about its local x and y axes.
    max_iter, tol
        Iteration limit (function evaluations of the Levenberg-Marquardt fit) and its relative
        tolerance.
    uncertainty : bool
        Compute the standard errors and the condition number (NaN without: the
        cross-validation's fits, which need the fitted model only).
    """
    from ..board import BoardModel
    from ..io import load_board

    if not isinstance(data, GridData):
        raise TypeError(f"expected GridData, got {type(data).__name__}")
    if not isinstance(model, BoardModel):
        model = BoardModel.from_board(load_board(model))   # a Board, built-in name or file
        f0 = model.coupling_points(data.points, data.axes)
        if data.couplings.shape[1] == model.n_coils:
            g0 = np.sum(f0 * data.couplings, 0) / np.sum(f0 * f0, 0)
            model = model.replace(gains=np.where(g0 != 0, g0, 1.0))
    n = model.n_coils
    if data.couplings.shape[1] != n:
        raise InputError(f"expected {n} coil columns for this board, got "
                         f"{data.couplings.shape[1]}")
    if model.n_sensor != 1:
        raise InputError(f"expected a board with a single-coil sensor for a grid of points and "
                         f"axes, got {model.n_sensor} sensor coils (calibrate a 6-DOF sensor "
                         f"against reference poses: --mode reference)")
    check_grid_units(data, model.sensor_length)
    Cm = data.couplings
    # the one calibration engine with known poses as its kinematics: the sensor pose of row i
    # is st_J_i (its z axis the grid axis), every fixture identity and held
    from ..solve._planar import pose_from_axis

    known, _ = pose_from_axis(data.points, data.axes)
    N = len(known)
    scale = np.sqrt(np.mean(Cm ** 2))
    layout = ParameterLayout.for_model(model)
    prob = CalibrationProblem(layout=layout, C_meas=Cm[:, :, None],
                              weight=np.full(N, 1.0 / scale),
                              so_J=np.broadcast_to(np.eye(4), (N, 4, 4)).copy(), st_J=known,
                              gain=None)
    groups = ("gains", "offsets") + (("tilts_in_plane",) if fit_tilt else ())
    free = layout.free_indices(groups)
    x0 = layout.pack(model, np.zeros(6), np.zeros(6), np.zeros(6))
    f = fit_problem(prob, x0, free, groups, tol=tol, max_nfev=max_iter, warn=False,
                    uncertainty=uncertainty)
    model = layout.model(f.x)
    se = f.standard_errors[layout.slices["model"]] if uncertainty else \
        np.full(np.size(model.params), np.nan)
    parts = model.split_params(se)
    condition = float(f.identifiability.condition) if uncertainty else float("nan")
    status = ("singular" if uncertainty and not condition <= 1e12 else
              "converged" if f.converged else "max_iterations")
    resid = Cm - model.coupling_points(data.points, data.axes)
    return PlanarFit(model=model, gains_se=parts["gains"], offsets_se=parts["offsets"],
                     tilts_se=parts["tilts"], status=status, iterations=int(f.result.nfev),
                     rms_residual=float(np.sqrt(np.mean(resid ** 2))),
                     coil_residual_percent=coil_residual_percent(resid, Cm),
                     n_points=N, condition=condition,
                     free=groups)
