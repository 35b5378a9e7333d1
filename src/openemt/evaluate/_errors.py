"""Pose errors and their summary statistics (MacLachlan et al. 2025, §VIII; docs/paper-procedure.md#test-error)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._result import DictResult
from ..geometry import (
    check_poses,
    error_magnitudes,
    invert,
    pose_error,
    pose_from_vector,
    vector_from_pose,
)

__all__ = [
    "ACCURACY_KEYS",
    "STAGE_UNCERTAINTY_DEG",
    "STAGE_UNCERTAINTY_M",
    "STAGE_UNCERTAINTY_MM",
    "STAGE_UNCERTAINTY_RAD",
    "ErrorSummary",
    "combined_uncertainty",
    "error_summary",
    "pose_error_magnitudes",
    "pose_error_vectors",
    "pose_errors",
]

#: Stage standard uncertainty after compensation (MacLachlan et al. 2025, supplement): 107 um and 0.17 deg.
STAGE_UNCERTAINTY_M = 0.107e-3
STAGE_UNCERTAINTY_RAD = np.deg2rad(0.17)
#: The same in the units of reports (mm, deg).
STAGE_UNCERTAINTY_MM = STAGE_UNCERTAINTY_M * 1e3
STAGE_UNCERTAINTY_DEG = float(np.rad2deg(STAGE_UNCERTAINTY_RAD))

#: The statistics of an accuracy row: RMS and max error magnitudes, translation in mm and
#: rotation in degrees (MacLachlan et al. 2025, Tables II and III).
ACCURACY_KEYS = ("trans_rms_mm", "trans_max_mm", "rot_rms_deg", "rot_max_deg")


def pose_errors(P_measured, P_reference, sensor_fixture=None) -> np.ndarray:
    """Error poses, shape (N, 4, 4); rows with a failed (non-finite) pose stay NaN.

    Without ``sensor_fixture`` the error is ``E = inv(P_measured) @ P_reference``. With the sensor
    fixture F_se (pose vector (6,) or pose (4, 4)) it is ILEMT's "stage coordinates" error
    ``E = F_se . inv(P_reference) . P_measured . inv(F_se)`` (docs/paper-procedure.md#test-error).

    Examples
    --------
    >>> import numpy as np
    >>> from openemt.evaluate import pose_error_magnitudes, pose_errors
    >>> from openemt.geometry import pose_from_vector
    >>> reference = pose_from_vector(np.array([[0.2, 0.0, 0.0, 0.0, 0.0, 0.0]]))
    >>> measured = pose_from_vector(np.array([[0.2, 0.001, 0.0, 0.0, 0.0, 0.01]]))
    >>> pose_errors(measured, reference).shape
    (1, 4, 4)
    >>> trans, rot = pose_error_magnitudes(measured, reference)  # m, rad
    >>> float(trans[0]), float(rot[0])
    (0.001, 0.01)
    """
    M = check_poses(P_measured, "P_measured")
    D = check_poses(P_reference, "P_reference")
    if sensor_fixture is None:
        return pose_error(M, D)
    F = np.asarray(sensor_fixture, dtype=np.float64)
    F = pose_from_vector(F) if F.shape == (6,) else check_poses(F, "sensor_fixture")
    return F @ invert(D) @ M @ invert(F)


def pose_error_magnitudes(P_measured, P_reference, sensor_fixture=None
                          ) -> tuple[np.ndarray, np.ndarray]:
    """Translation (m) and rotation (rad) magnitudes of :func:`pose_errors`, each shape (N,)."""
    return error_magnitudes(pose_errors(P_measured, P_reference, sensor_fixture))


def pose_error_vectors(P_measured, P_reference, sensor_fixture=None) -> np.ndarray:
    """:func:`pose_errors` as vectors ``[tx, ty, tz, rx, ry, rz]`` (m, rad), shape (N, 6), for
    error-vector plots and sweep analysis; their two halves' norms are the magnitudes."""
    return vector_from_pose(pose_errors(P_measured, P_reference, sensor_fixture))


def combined_uncertainty(rms, stage_uncertainty):
    """Combined standard uncertainty ``sqrt(rms^2 + u_stage^2)`` (MacLachlan et al. 2025, eq. 10)."""
    return np.sqrt(np.asarray(rms, dtype=np.float64) ** 2 + stage_uncertainty ** 2)


@dataclass(frozen=True, eq=False)
class ErrorSummary(DictResult):
    """Statistics of translation (mm) and rotation (deg) error magnitudes.

    Also a read-only dict of ``to_dict()`` (``summary["trans_rms_mm"]``), as it was a plain
    dict before.

    Attributes
    ----------
    trans_rms_mm, trans_max_mm, trans_p50_mm, trans_p95_mm : float
        RMS, max, median and 95th percentile of the finite translation errors (NaN if none).
    rot_rms_deg, rot_max_deg, rot_p50_deg, rot_p95_deg : float
        The same of the rotation errors.
    n : int
        Rows, including non-finite ones.
    n_nonfinite : int
        Rows with a non-finite error (failed solutions), left out of the statistics.
    """

    trans_rms_mm: float
    trans_max_mm: float
    trans_p50_mm: float
    trans_p95_mm: float
    rot_rms_deg: float
    rot_max_deg: float
    rot_p50_deg: float
    rot_p95_deg: float
    n: int
    n_nonfinite: int


def error_summary(trans_err, rot_err) -> ErrorSummary:
    """RMS, max and percentiles of translation (reported in mm) and rotation (deg) errors.

    Non-finite errors (failed solves) are excluded from the statistics and counted in
    ``n_nonfinite``; ``n`` counts every row.

    Parameters
    ----------
    trans_err, rot_err : array_like, shape (N,)
        Translation (m) and rotation (rad) error magnitudes, e.g. from
        :func:`pose_error_magnitudes`.

    Returns
    -------
    ErrorSummary

    Examples
    --------
    >>> import numpy as np
    >>> from openemt.evaluate import error_summary
    >>> s = error_summary(np.array([3e-4, 4e-4, np.nan]), np.deg2rad([0.1, 0.2, 0.3]))
    >>> round(s.trans_rms_mm, 4), round(s.rot_max_deg, 3), s.n, s.n_nonfinite
    (0.3536, 0.2, 3, 1)
    """
    t = np.asarray(trans_err, dtype=np.float64)
    r = np.asarray(rot_err, dtype=np.float64)
    ok = np.isfinite(t) & np.isfinite(r)
    t_mm = t[ok] * 1e3
    r_deg = np.rad2deg(r[ok])

    def stats(x, unit):
        if x.size == 0:
            return {f"rms_{unit}": float("nan"), f"max_{unit}": float("nan"),
                    f"p50_{unit}": float("nan"), f"p95_{unit}": float("nan")}
        return {f"rms_{unit}": float(np.sqrt(np.mean(x ** 2))), f"max_{unit}": float(x.max()),
                f"p50_{unit}": float(np.percentile(x, 50)),
                f"p95_{unit}": float(np.percentile(x, 95))}

    ts, rs = stats(t_mm, "mm"), stats(r_deg, "deg")
    return ErrorSummary(**{f"trans_{k}": v for k, v in ts.items()},
                        **{f"rot_{k}": v for k, v in rs.items()},
                        n=int(t.size), n_nonfinite=int((~ok).sum()))


def axis_errors(axes_measured, axes_reference) -> np.ndarray:
    """Angles (rad) between measured and reference unit axes ``(N, 3)``: the orientation error
    of a 5-DOF sensor, whose roll about its axis is not measured (NaN where either is NaN)."""
    a = np.asarray(axes_measured, dtype=np.float64)
    b = np.asarray(axes_reference, dtype=np.float64)
    c = np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0)
    return np.arccos(c)


def point_axis_summary(position_error, axis_error, scored) -> dict:
    """``n`` (rows scored), ``n_failed``, ``position_rms_mm``, ``position_max_mm`` and
    ``axis_rms_deg`` of 5-DOF errors: position error magnitudes (m) and axis errors (rad) of
    the rows ``scored`` (a boolean mask; NaN statistics when none is)."""
    ok = np.asarray(scored, dtype=bool)
    dp = np.asarray(position_error, dtype=np.float64)[ok]
    ang = np.rad2deg(np.asarray(axis_error, dtype=np.float64)[ok])
    nan = float("nan")
    return {"n": int(ok.sum()), "n_failed": int((~ok).sum()),
            "position_rms_mm": float(np.sqrt(np.mean(dp ** 2)) * 1e3) if ok.any() else nan,
            "position_max_mm": float(dp.max() * 1e3) if ok.any() else nan,
            "axis_rms_deg": float(np.sqrt(np.mean(ang ** 2))) if ok.any() else nan}


def coil_residual_percent(residual, couplings) -> np.ndarray:
    """RMS residual of each coil (column) in percent of its peak |coupling|."""
    peak = np.abs(couplings).max(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return 100.0 * np.sqrt(np.mean(np.asarray(residual) ** 2, axis=0)) / peak
