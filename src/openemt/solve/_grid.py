"""A 5-DOF solution scored against a grid of known sensor positions and axes (a measured or
simulated grid over a planar board): :func:`planar_errors`, point by point, and
:func:`planar_accuracy`, the summary that planar calibration, ``openemt solve`` and the report
give (docs/planar.md#accuracy)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._errors import InputError
from ..evaluate import axis_errors, coil_residual_percent, point_axis_summary

__all__ = ["GridData", "PlanarErrors", "planar_accuracy", "planar_errors"]


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

    def subset(self, rows) -> GridData:
        """The grid points ``rows`` (a boolean mask or indices)."""
        return GridData(self.points[rows], self.axes[rows], self.couplings[rows],
                        self.coil_names)



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
        from ._result import SolveResult

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
        return {**point_axis_summary(self.position_error, np.deg2rad(self.axis_error_deg),
                                     self.converged),
                "coil_residual_percent": coil_residual_percent(self.coil_residual,
                                                               self.couplings).tolist()}


def planar_errors(model, data: GridData, *, result=None, **solve_options) -> PlanarErrors:
    """Solve every grid point from its couplings alone (cold start from the seed grid) with the
    5-DOF solver and compare with the known positions and axes, point by point.

    ``result`` (a :class:`~openemt.solve.SolveResult` of the grid's couplings, e.g. a tracked
    solution) is scored instead of solving again.
    """
    from ._factory import prepare
    from ._result import Status

    if data.couplings.shape[1] != model.n_coils:
        raise InputError(f"expected {model.n_coils} coil columns for this board, got "
                         f"{data.couplings.shape[1]}")
    res = (prepare(model, initial="grid", **solve_options)(data.couplings)
           if result is None else result)
    if len(res) != len(data.points):
        raise InputError(f"expected a solution of {len(data.points)} points, got {len(res)}")
    ok = res.status == Status.CONVERGED
    ev = np.full((len(ok), 3), np.nan)
    ev[ok] = res.poses[ok, :3, 3] - data.points[ok]
    ang = np.full(len(ok), np.nan)
    ang[ok] = np.degrees(axis_errors(res.poses[ok, :3, 2], data.axes[ok]))
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
