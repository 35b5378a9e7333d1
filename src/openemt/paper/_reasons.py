"""One-line reasons for the failed or surprising rows of the accuracy tables (``openemt demo``,
``openemt report``): each reason is computed from the models and the rows, never written for a
named row.

* :func:`concentric_reason`: a concentric closed form (Kim18) tested on a source whose coils are
  not concentric. The reason is derived from the non-concentric calibration of the same
  tracker: its coils are apart, and on noise-free couplings of that model at the test poses
  the concentric model's Kim18 residue already breaks ILEMT's validity rule. The failure is then
  the approximation's, not the data's.
* :func:`invalid_reason`: any other row with invalid solutions (residue not below the rule).
* :func:`correction_reason`: an output correction that makes the test error larger.
* :func:`start_reason`: a calibration that was not fitted (the perturbed start of a simulated
  fit), with how far it is from the truth.
"""

from __future__ import annotations

import numpy as np

from ..calibrate._check import ILEMT_VALID_RESNORM
from ..geometry import pose_from_vector

__all__ = ["coil_spread", "concentric_misfit", "concentric_reason", "correction_reason",
           "explain_rows", "invalid_reason", "start_reason"]

#: Coil centres closer than this (m) count as concentric.
CONCENTRIC_TOL_M = 1e-6


def coil_spread(L) -> float:
    """Largest distance (m) between two coil centres; ``L`` is (3, n) with the coils as columns."""
    L = np.asarray(L, dtype=np.float64)
    if L.shape[1] < 2:
        return 0.0
    d = L[:, :, None] - L[:, None, :]
    return float(np.sqrt((d ** 2).sum(axis=0)).max())


def _is_concentric(model) -> bool:
    return max(coil_spread(model.L_so), coil_spread(model.L_se)) < CONCENTRIC_TOL_M


def concentric_misfit(model, concentric_model, poses) -> np.ndarray:
    """Residue (ILEMT's resnorm) of the Kim18 solution with ``concentric_model`` on the
    noise-free couplings of ``model`` at ``poses`` (N, 4, 4): what the concentric approximation
    leaves unexplained when the data are exactly ``model``'s."""
    from ..solve import hemisphere_from_positions, solve_kim18

    P = np.asarray(poses, dtype=np.float64)
    C = model.coupling(P)
    res = solve_kim18(C, concentric_model, hemisphere=hemisphere_from_positions(P[:, :3, 3]))
    return np.asarray(res.residual, dtype=np.float64)


def invalid_reason(n_invalid: int, n: int, limit: float = ILEMT_VALID_RESNORM) -> str | None:
    """The reason of a row with invalid solutions that no model difference explains."""
    if n_invalid <= 0:
        return None
    return (f"{n_invalid} of {n} rows have a solution residue >= {limit:g} (the validity rule): "
            "their solutions do not explain the couplings (a local solution from a poor start, "
            "field distortion, a pose outside the calibrated volume or the wrong hemisphere)")


def concentric_reason(model, concentric_model, poses, n_invalid: int,
                      limit: float = ILEMT_VALID_RESNORM) -> str | None:
    """Why a concentric model's Kim18 rows are invalid, as far as the concentric approximation
    of the non-concentric ``model`` explains it; else None.

    Parameters
    ----------
    model : DipoleModel
        The non-concentric (dipole) calibration of the same tracker.
    concentric_model : DipoleModel
        The concentric model the rows were solved with.
    poses : ndarray, shape (N, 4, 4)
        The test rows' reference poses in ``model``'s frame.
    n_invalid : int
        Invalid rows of the concentric test.

    Returns
    -------
    str or None
        The expected failure when noise-free couplings of ``model`` at ``poses`` leave at least
        half as many invalid rows as failed; the :func:`invalid_reason` with the share the
        approximation accounts for when they leave fewer; None when nothing failed, when
        ``concentric_model`` is not concentric or ``model`` is, or when noise-free couplings
        leave no invalid row (the approximation is not the cause).
    """
    if n_invalid <= 0 or not _is_concentric(concentric_model) or _is_concentric(model):
        return None
    misfit = concentric_misfit(model, concentric_model, poses)
    k, n = int((~(misfit < limit)).sum()), len(misfit)
    so, se = coil_spread(model.L_so) * 1e3, coil_spread(model.L_se) * 1e3
    if k >= max(1, n_invalid // 2):
        return (f"expected: Kim18 assumes concentric coils, but the dipole calibration places "
                f"the source coils up to {so:.1f} mm apart (sensor coils {se:.1f} mm); on "
                f"noise-free couplings of that model at the test poses the concentric model "
                f"already leaves a residue >= {limit:g} (the validity rule) in {k} of {n} rows")
    if k > 0:
        return (f"{invalid_reason(n_invalid, n, limit)}; the concentric approximation of source "
                f"coils {so:.1f} mm apart (sensor coils {se:.1f} mm) alone leaves {k} such rows "
                "on noise-free couplings")
    return None


def correction_reason(uncorrected: dict, corrected: dict) -> str | None:
    """Why an output-correction row is worse than the row without it, if it is."""
    a, b = uncorrected["trans_rms_mm"], corrected["trans_rms_mm"]
    if not (np.isfinite(a) and np.isfinite(b)) or b <= a:
        return None
    return (f"the output correction, fitted on the calibration rows, raises the translation "
            f"RMS of these test rows from {a:.3f} to {b:.3f} mm: it does not carry over to "
            "them")


def explain_rows(rows: dict, *, model, poses, concentric=None, concentric_key=None,
                 corrections=()) -> dict:
    """Give every accuracy row (name -> :func:`~openemt.paper.accuracy_row`) a ``reason``: a
    line for a failed or surprising row, None for the others (in place; returns ``rows``).

    Parameters
    ----------
    rows : dict of str -> dict
        Accuracy rows with ``trans_rms_mm``, ``n`` and ``n_invalid``.
    model : DipoleModel
        The main (non-concentric) calibration's model.
    poses : ndarray, shape (N, 4, 4)
        The test rows' reference poses in ``model``'s frame.
    concentric : DipoleModel, optional
        The concentric model of the row ``concentric_key`` (solved with Kim18 alone).
    corrections : iterable of (str, str)
        ``(uncorrected row, corrected row)`` pairs.
    """
    pairs = {b: a for a, b in corrections}
    for key, row in rows.items():
        n_inv, n = int(row.get("n_invalid") or 0), int(row.get("n") or len(poses))
        reason = None
        if key == concentric_key and concentric is not None:
            reason = concentric_reason(model, concentric, poses, n_inv)
        reason = reason or invalid_reason(n_inv, n)
        if reason is None and key in pairs and pairs[key] in rows:
            reason = correction_reason(rows[pairs[key]], row)
        row["reason"] = reason
    return rows


def start_reason(start, truth) -> str:
    """Why an unfitted start calibration is far off: how far its parameters are from the
    truth (coil positions and fixture translations in mm, moments in percent, fixture rotations
    in degrees)."""
    ms, mt = start.model, truth.model
    pos = max(np.abs(np.asarray(ms.L_so) - mt.L_so).max(),
              np.abs(np.asarray(ms.L_se) - mt.L_se).max()) * 1e3
    rel = []
    for a, b in ((ms.M_so, mt.M_so), (ms.M_se, mt.M_se)):
        a, b = np.asarray(a), np.asarray(b)
        rel.append((np.linalg.norm(a - b, axis=0) / np.linalg.norm(b, axis=0)).max())
    names = ("source_fixture", "stage_fixture", "sensor_fixture")
    A = pose_from_vector(np.array([getattr(start, f) for f in names], dtype=np.float64))
    B = pose_from_vector(np.array([getattr(truth, f) for f in names], dtype=np.float64))
    ft = np.linalg.norm(A[:, :3, 3] - B[:, :3, 3], axis=1).max() * 1e3
    cos = (np.einsum("nij,nij->n", A[:, :3, :3], B[:, :3, :3]) - 1.0) / 2.0
    fr = np.rad2deg(np.arccos(np.clip(cos, -1.0, 1.0)).max())
    return (f"not fitted: the start of the calibration, its coil positions up to {pos:.2f} mm, "
            f"moments up to {100 * max(rel):.2f} % and fixtures up to {ft:.2f} mm / "
            f"{fr:.2f} deg from the truth")
