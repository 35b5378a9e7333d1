"""Characterization of tracker error (MacLachlan et al. 2025, §VIII): error vectors, u(cal), combined u(P).

The error of a measured pose against the reference is ``E = inv(P_measured) @ P_reference``
(MacLachlan et al. 2025, eqs. 8 and 9), or ILEMT's "stage coordinates" error
``E = F_se . inv(P_reference) . P_measured . inv(F_se)`` when the sensor fixture is given
(docs/paper-procedure.md#test-error); see :func:`openemt.evaluate.pose_error_magnitudes`. u(cal) is the RMS
of the error magnitudes and the combined standard uncertainty of a measurement is
``u(P) = sqrt(u(P_stage)^2 + u(cal)^2)`` (eq. 10).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._errors import InputError
from .._result import Result
from ..geometry import check_poses
from ._errors import (
    STAGE_UNCERTAINTY_M,
    STAGE_UNCERTAINTY_RAD,
    ErrorSummary,
    combined_uncertainty,
    error_summary,
    pose_error_magnitudes,
    pose_error_vectors,
)

__all__ = [
    "Characterization",
    "UncertaintySummary",
    "characterize",
    "fixture_labels",
    "uncertainty_summary",
]


@dataclass(frozen=True, eq=False)
class UncertaintySummary(ErrorSummary):
    """:class:`~openemt.evaluate.ErrorSummary` plus u(cal) and the combined u(P) of
    MacLachlan et al. 2025, eq. 10 (also a read-only dict of ``to_dict()``).

    Attributes
    ----------
    u_cal_trans_mm, u_cal_rot_deg : float
        u(cal): the RMS errors.
    u_P_trans_mm, u_P_rot_deg : float
        ``sqrt(u(cal)^2 + u(stage)^2)``.
    u_stage_trans_mm, u_stage_rot_deg : float
        The reference's standard uncertainty.

    and the fields of :class:`~openemt.evaluate.ErrorSummary`.
    """

    u_cal_trans_mm: float
    u_P_trans_mm: float
    u_cal_rot_deg: float
    u_P_rot_deg: float
    u_stage_trans_mm: float
    u_stage_rot_deg: float


def uncertainty_summary(trans_err, rot_err, *, stage_uncertainty_m: float = STAGE_UNCERTAINTY_M,
                        stage_uncertainty_rad: float = STAGE_UNCERTAINTY_RAD
                        ) -> UncertaintySummary:
    """``error_summary`` plus u(cal) and the combined u(P) of eq. 10, in mm and degrees."""
    s = error_summary(trans_err, rot_err)
    us_mm = stage_uncertainty_m * 1e3
    us_deg = float(np.rad2deg(stage_uncertainty_rad))
    return UncertaintySummary(
        **s.to_dict(), u_cal_trans_mm=s.trans_rms_mm,
        u_P_trans_mm=float(combined_uncertainty(s.trans_rms_mm, us_mm)),
        u_cal_rot_deg=s.rot_rms_deg,
        u_P_rot_deg=float(combined_uncertainty(s.rot_rms_deg, us_deg)),
        u_stage_trans_mm=us_mm, u_stage_rot_deg=us_deg)


@dataclass(frozen=True, eq=False)
class Characterization(Result):
    """Error statistics of a test set, overall and per group (e.g. fixture combination).

    Attributes
    ----------
    overall : dict
        :func:`uncertainty_summary` of all rows (mm, deg).
    by_group : dict
        The same per group label (only if groups were given).
    positions : ndarray, shape (N, 3)
        Reference positions (m), for error-vector workspace plots (MacLachlan et al. 2025, Fig. 8).
    error_vectors : ndarray, shape (N, 6)
        Error vectors (m, rad) as :func:`pose_error_vectors`.
    groups : ndarray of str, shape (N,) or None

    ``to_dict()`` gives the statistics (``overall``, ``by_group``), not the per-row arrays.
    """

    _not_in_dict = ("positions", "error_vectors", "groups")

    overall: UncertaintySummary
    by_group: dict = field(default_factory=dict)
    positions: np.ndarray | None = None
    error_vectors: np.ndarray | None = None
    groups: np.ndarray | None = None


def characterize(P_measured, P_reference, *, groups=None, sensor_fixture=None,
                 stage_uncertainty_m: float = STAGE_UNCERTAINTY_M,
                 stage_uncertainty_rad: float = STAGE_UNCERTAINTY_RAD) -> Characterization:
    """Characterize tracker error against reference poses (MacLachlan et al. 2025, §VIII).

    Parameters
    ----------
    P_measured, P_reference : array_like, shape (N, 4, 4)
        Tracker output and reference (stage / ground truth) poses. Non-finite measured poses
        (failed solves) are counted in ``n_nonfinite`` and left out of the statistics.
    groups : array_like, shape (N,), optional
        Label per row (e.g. ``fixture_labels(dataset)``) for the per-group breakdown.
    sensor_fixture : array_like, shape (6,) or (4, 4), optional
        F_se for ILEMT's stage-coordinates error (docs/paper-procedure.md#test-error).
    stage_uncertainty_m, stage_uncertainty_rad : float
        Standard uncertainty of the reference (default 0.107 mm and 0.17 deg, MacLachlan et al. 2025).

    Returns
    -------
    Characterization

    Examples
    --------
    >>> import numpy as np
    >>> from openemt.evaluate import characterize
    >>> from openemt.geometry import pose_from_vector
    >>> reference = pose_from_vector(np.array([[0.2, 0.0, 0.0, 0.0, 0.0, 0.0],
    ...                                        [0.2, 0.05, 0.0, 0.0, 0.0, 0.0]]))
    >>> measured = pose_from_vector(np.array([[0.2, 0.0003, 0.0, 0.0, 0.0, 0.0],
    ...                                       [0.2, 0.0504, 0.0, 0.0, 0.0, 0.0]]))
    >>> c = characterize(measured, reference, groups=["a", "b"])
    >>> round(c.overall.trans_rms_mm, 4), round(c.overall.u_P_trans_mm, 4), list(c.by_group)
    (0.3536, 0.3694, ['a', 'b'])
    """
    M = check_poses(P_measured, "P_measured")
    D = check_poses(P_reference, "P_reference")
    if M.ndim != 3 or D.shape != M.shape:
        raise InputError(f"expected P_measured and P_reference of one shape (N, 4, 4), got "
                         f"{M.shape} and {D.shape}")
    trans, rot = pose_error_magnitudes(M, D, sensor_fixture)  # NaN for failed rows
    kw = {"stage_uncertainty_m": stage_uncertainty_m,
          "stage_uncertainty_rad": stage_uncertainty_rad}
    overall = uncertainty_summary(trans, rot, **kw)
    by_group = {}
    g = None
    if groups is not None:
        g = np.asarray(groups).astype(str)
        if g.shape != (len(M),):
            raise InputError(f"expected `groups` of shape ({len(M)},), got {g.shape}")
        _, first = np.unique(g, return_index=True)
        for lab in g[np.sort(first)]:
            sel = g == lab
            by_group[str(lab)] = uncertainty_summary(trans[sel], rot[sel], **kw)
    vec = pose_error_vectors(M, D, sensor_fixture)
    return Characterization(overall=overall, by_group=by_group, positions=D[:, :3, 3].copy(),
                            error_vectors=vec, groups=g)


def fixture_labels(dataset) -> np.ndarray:
    """Per-row labels ``so<source code>_se<sensor code>`` of a Dataset, shape (N,)."""
    so = np.asarray(dataset.source_fixture).astype(str)
    se = np.asarray(dataset.sensor_fixture).astype(str)
    return np.char.add(np.char.add(np.char.add("so", so), "_se"), se)
