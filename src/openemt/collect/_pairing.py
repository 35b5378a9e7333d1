"""Do the paired dwells agree? The tracker's motion between dwells against the reference's.

Between dwells i and j, the tracker's relative motion ``A_i^-1 A_j`` and the reference's
``B_i^-1 B_j`` are conjugate (``A_i^-1 A_j = X B_i^-1 B_j X^-1`` whatever X and Y are), so their
screw invariants agree: the rotation angle, and the translation along the rotation axis (the
translation itself for a motion without rotation). The tracker's poses come from its model
before calibration, so they agree within a few degrees and millimetres, not exactly.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import spearmanr

from .._errors import InputError

__all__ = ["MAX_ANGLE_DIFF_DEG", "MIN_RANK_CORRELATION", "SCALE_RANGE", "check_pairing"]

#: The median difference of the rotation angles between dwells may be at most this (deg) ...
MAX_ANGLE_DIFF_DEG = 10.0
#: ... the angles must rank alike (Spearman's correlation over the pairs of dwells, with at
#: least 5 dwells) at least this much ...
MIN_RANK_CORRELATION = 0.5
#: ... and the median of the reference's screw translations over the tracker's must lie in this
#: range (a reference in another length unit is 1000 times off).
SCALE_RANGE = (1 / 3, 3.0)
#: Below this angle (rad) a relative motion counts as a translation.
_SMALL_ANGLE = 0.1
_MAX_PAIRS = 5000


def _invariants(P, i, j):
    rel = np.linalg.solve(P[i], P[j])          # P_i^-1 P_j
    rv = Rotation.from_matrix(rel[:, :3, :3]).as_rotvec()
    ang = np.linalg.norm(rv, axis=1)
    t = rel[:, :3, 3]
    axis = rv / np.where(ang > 0, ang, 1.0)[:, None]
    along = np.abs(np.einsum("ni,ni->n", t, axis))
    return ang, np.where(ang > _SMALL_ANGLE, along, np.linalg.norm(t, axis=1))


def check_pairing(A, B, *, rotations: bool = True, refuse: bool = True) -> dict:
    """Compare the relative motions of the tracker's dwell poses ``A`` (N, 4, 4; solved with
    its model, source frame) and the reference's ``B`` (N, 4, 4) over pairs of dwells.

    Returns the figures (``n_pairs``, ``angle_diff_deg_median``, ``rank_correlation`` of the
    angles, ``scale`` of the screw translations, ``ok``) and, with ``refuse``, raises
    :class:`InputError` when they show that the dwells are not paired with the reference poses
    held there (:data:`MAX_ANGLE_DIFF_DEG`, :data:`MIN_RANK_CORRELATION`,
    :data:`SCALE_RANGE`). ``rotations=False`` (a 5-DOF sensor, whose roll the model does not
    give) compares translations only.
    """
    A, B = np.asarray(A, float), np.asarray(B, float)
    out = {"n_pairs": 0, "angle_diff_deg_median": None, "rank_correlation": None,
           "scale": None, "ok": True}
    ok = np.all(np.isfinite(A), axis=(1, 2)) & np.all(np.isfinite(B), axis=(1, 2))
    A, B = A[ok], B[ok]
    n = len(A)
    if n < 3:
        return out
    i, j = np.triu_indices(n, 1)
    if len(i) > _MAX_PAIRS:
        k = np.random.default_rng(0).choice(len(i), _MAX_PAIRS, replace=False)
        i, j = i[k], j[k]
    angA, dA = _invariants(A, i, j)
    angB, dB = _invariants(B, i, j)
    if not rotations:
        dA = np.linalg.norm(A[i, :3, 3] - A[j, :3, 3], axis=1)
        dB = np.linalg.norm(B[i, :3, 3] - B[j, :3, 3], axis=1)
    out["n_pairs"] = int(len(i))
    why = []
    if np.median(dA) > 0:
        out["scale"] = float(np.median(dB) / np.median(dA))
        if not SCALE_RANGE[0] <= out["scale"] <= SCALE_RANGE[1]:
            why.append(f"the reference's translations between dwells are {out['scale']:.3g} "
                       f"times the tracker's (another length unit?)")
    if rotations:
        d = float(np.degrees(np.median(np.abs(angA - angB))))
        out["angle_diff_deg_median"] = d
        if not d <= MAX_ANGLE_DIFF_DEG:
            why.append(f"the rotations between dwells differ by {d:.1f} deg in the median (at "
                       f"most {MAX_ANGLE_DIFF_DEG:g} expected)")
        if n >= 5 and np.ptp(angA) > 0 and np.ptp(angB) > 0:
            rho = float(spearmanr(angA, angB).statistic)
            out["rank_correlation"] = rho
            if not rho >= MIN_RANK_CORRELATION:
                why.append(f"the rotations between dwells rank alike with a correlation of "
                           f"only {rho:.2f} (at least {MIN_RANK_CORRELATION:g} expected)")
    out["ok"] = not why
    if why and refuse:
        raise InputError(f"expected the dwells to pair with the reference poses held there, "
                         f"got {'; '.join(why)}; nothing written")
    return out
