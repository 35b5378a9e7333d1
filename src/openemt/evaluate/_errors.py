"""Pose errors and their summary statistics (MacLachlan et al. 2025, §VIII; docs/paper-procedure.md#test-error)."""

from __future__ import annotations

import numpy as np

from ..geometry import (
    check_poses,
    error_magnitudes,
    invert,
    pose_error,
    pose_from_vector,
    vector_from_pose,
)

__all__ = [
    "STAGE_UNCERTAINTY_M",
    "STAGE_UNCERTAINTY_RAD",
    "combined_uncertainty",
    "error_summary",
    "pose_error_magnitudes",
    "pose_error_vectors",
    "pose_errors",
]

#: Stage standard uncertainty after compensation (MacLachlan et al. 2025, supplement): 107 um and 0.17 deg.
STAGE_UNCERTAINTY_M = 0.107e-3
STAGE_UNCERTAINTY_RAD = np.deg2rad(0.17)


def pose_errors(P_measured, P_reference, sensor_fixture=None) -> np.ndarray:
    """Error poses, shape (N, 4, 4); rows with a failed (non-finite) pose stay NaN.

    Without ``sensor_fixture`` the error is ``E = inv(P_measured) @ P_reference``. With the sensor
    fixture F_se (pose vector (6,) or pose (4, 4)) it is ILEMT's "stage coordinates" error
    ``E = F_se . inv(P_reference) . P_measured . inv(F_se)`` (docs/paper-procedure.md#test-error).
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


def error_summary(trans_err, rot_err) -> dict:
    """RMS, max and percentiles of translation (reported in mm) and rotation (deg) errors.

    Non-finite errors (failed solves) are excluded from the statistics and counted in
    ``n_nonfinite``; ``n`` counts every row.
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
    out = {f"trans_{k}": v for k, v in ts.items()}
    out.update({f"rot_{k}": v for k, v in rs.items()})
    out["n"] = int(t.size)
    out["n_nonfinite"] = int((~ok).sum())
    return out
