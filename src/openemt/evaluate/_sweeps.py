"""Axis-sweep linearity: direct and cross error and nonlinearity (MacLachlan et al. 2025, §VIII-I, Table IV).

A sweep moves one stage axis while the others stay at zero (ILEMT ``sweep`` pattern:
0.5 mm / 0.5 deg steps). Along each sweep the pose error vector (translation in mm, rotation
vector in degrees; :func:`pose_error_vectors`) is split by the kind of motion:

* direct error: translation error during a translation sweep, rotation error during a
  rotation sweep; cross error: the other half (rotation error caused by translation and
  vice versa);
* nonlinearity: the magnitude of the derivative of the 3-D error vector with respect to the
  swept coordinate, from a Savitzky-Golay filter (order 2, window 21; docs/paper-procedure.md#test-error).
  Direct nonlinearity is dimensionless (reported in percent of the motion); cross
  nonlinearity is in deg/mm (translation sweeps) or mm/deg (rotation sweeps).

Each curve is summarised by RMS and max; :func:`sweep_table` combines curves by the max over
the driving axes, as Table IV does, with columns named by the kind of motion (``xyz`` or
``rot``) and units in the keys.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._errors import InputError
from .._result import DictResult, Result
from ..geometry import check_poses
from ._errors import pose_error_vectors

__all__ = [
    "SWEEP_AXES",
    "SweepAnalysis",
    "SweepCurve",
    "SweepTable",
    "find_sweeps",
    "sweep_linearity",
    "sweep_table",
]

SWEEP_AXES = ("x", "y", "z", "rx", "ry", "rz")
#: ILEMT: "sweep points are found where all other stage axes are within 0.25 of zero"
#: (stage units mm and degrees).
SWEEP_TOL_M = 0.25e-3
SWEEP_TOL_RAD = np.deg2rad(0.25)


@dataclass(frozen=True, eq=False)
class SweepCurve:
    """One single-axis sweep.

    Attributes
    ----------
    label : str
        Curve group (e.g. the input file) the sweep came from.
    axis : str
        Swept stage axis (``x`` ... ``rz``).
    motion : ndarray, shape (n,)
        Swept coordinate, mm (translation) or degrees (rotation), increasing; rows at the
        same coordinate are averaged.
    trans_err : ndarray, shape (n, 3)
        Translation error vectors, mm.
    rot_err : ndarray, shape (n, 3)
        Rotation error vectors, degrees.
    abs_direct, abs_cross, nonlin_direct, nonlin_cross : ndarray, shape (n,)
        Magnitudes: direct/cross absolute error (mm or deg) and nonlinearity (direct in
        percent; cross in deg/mm or mm/deg).
    """

    label: str
    axis: str
    motion: np.ndarray
    trans_err: np.ndarray
    rot_err: np.ndarray
    abs_direct: np.ndarray
    abs_cross: np.ndarray
    nonlin_direct: np.ndarray
    nonlin_cross: np.ndarray

    @property
    def is_rotation(self) -> bool:
        return self.axis.startswith("r")

    def to_dict(self) -> dict:
        """JSON-ready summary: label, axis, points, range, RMS and max of each magnitude."""

        def rm(x):
            return float(np.sqrt(np.mean(x ** 2))), float(np.max(x))

        out = {"label": self.label, "axis": self.axis, "n": len(self.motion),
               "range": [float(self.motion[0]), float(self.motion[-1])]}
        for name in ("abs_direct", "abs_cross", "nonlin_direct", "nonlin_cross"):
            r, m = rm(getattr(self, name))
            out[f"{name}_rms"], out[f"{name}_max"] = r, m
        return out


@dataclass(frozen=True, eq=False)
class SweepTable(DictResult):
    """Table IV of a set of sweep curves (also a read-only dict of ``to_dict()``).

    Attributes
    ----------
    direct, cross : dict
        Per kind of motion (``xyz_`` translation sweeps, ``rot_`` rotation sweeps), the max over
        curves of each curve's RMS and max absolute error and nonlinearity, units in the keys
        (``xyz_abs_rms_mm``, ``rot_nonlin_max_percent``, ``xyz_nonlin_rms_deg_per_mm`` ...);
        NaN without such a sweep.
    n_curves : dict
        Number of ``xyz`` and ``rot`` curves.
    """

    direct: dict
    cross: dict
    n_curves: dict


@dataclass(frozen=True, eq=False)
class SweepAnalysis(Result):
    """All sweep curves of a test and their Table IV summary.

    Attributes
    ----------
    curves : tuple of SweepCurve
    table : SweepTable

    ``to_dict()`` gives ``table`` and the curves' summaries (``curves``).
    """

    curves: tuple
    table: SweepTable

    def _items(self) -> dict:
        return {"table": self.table, "curves": [c.to_dict() for c in self.curves]}


def find_sweeps(stage, labels=None, *, tol_m: float = SWEEP_TOL_M,
                tol_rad: float = SWEEP_TOL_RAD, min_points: int = 21) -> list:
    """Rows of each single-axis sweep.

    Parameters
    ----------
    stage : array_like, shape (N, 6)
        Stage vectors ``[x, y, z, a, b, c]`` (m, rad), preferably as logged.
    labels : array_like, shape (N,), optional
        Group per row (e.g. file); sweeps are found within each group.
    tol_m, tol_rad : float
        A row belongs to the sweep of axis ``a`` if every other axis is within the tolerance
        of zero (0.25 mm and 0.25 deg by default).
    min_points : int
        Minimum number of distinct swept coordinates for a sweep.

    Returns
    -------
    list of (label, axis name, row indices)
    """
    S = np.asarray(stage, dtype=np.float64)
    if S.ndim != 2 or S.shape[1] != 6:
        raise InputError(f"expected `stage` of shape (N, 6), got {S.shape}")
    lab = np.zeros(len(S), dtype=int).astype(str) if labels is None else \
        np.asarray(labels).astype(str)
    if lab.shape != (len(S),):
        raise InputError(f"expected `labels` of shape ({len(S)},), got {lab.shape}")
    tol = np.array([tol_m] * 3 + [tol_rad] * 3)
    near0 = np.abs(S) <= tol
    out = []
    _, first = np.unique(lab, return_index=True)
    for g in lab[np.sort(first)]:
        in_g = lab == g
        for a in range(6):
            others = np.delete(near0, a, axis=1).all(axis=1)
            rows = np.flatnonzero(in_g & others)
            if len(rows) and len(np.unique(np.round(S[rows, a], 9))) >= min_points:
                out.append((str(g), SWEEP_AXES[a], rows))
    return out


def _derivative(y: np.ndarray, s: np.ndarray, window: int, polyorder: int) -> np.ndarray:
    """d y / d s along axis 0 by Savitzky-Golay, chain rule over the sample index.

    For uniformly spaced ``s`` this equals ``savgol_filter(y, deriv=1, delta=ds)``; the chain
    rule also handles the odd step (e.g. ILEMT's Z sweep clipped at -46.2 mm).
    """
    from scipy.signal import savgol_filter  # here: scipy.signal costs every command's import

    w = min(window, len(s) if len(s) % 2 else len(s) - 1)
    dy = savgol_filter(y, w, polyorder, deriv=1, axis=0, mode="interp")
    ds = savgol_filter(s, w, polyorder, deriv=1, axis=0, mode="interp")
    return dy / ds[:, None]


def sweep_linearity(P_measured, P_reference, stage, *, labels=None, sensor_fixture=None,
                    window: int = 21, polyorder: int = 2, tol_m: float = SWEEP_TOL_M,
                    tol_rad: float = SWEEP_TOL_RAD) -> SweepAnalysis:
    """Direct and cross absolute error and nonlinearity of axis sweeps (Table IV, Fig. 10).

    Parameters
    ----------
    P_measured, P_reference : array_like, shape (N, 4, 4)
        Measured (solved, optionally corrected) and reference poses of the sweep rows.
    stage : array_like, shape (N, 6)
        Stage vectors (m, rad) used to find the sweeps and as the swept coordinate (logged
        values recommended).
    labels : array_like, shape (N,), optional
        Curve group per row (e.g. file name; one sweep file per sensor fixture).
    sensor_fixture : array_like, optional
        F_se for ILEMT's stage-coordinates error (docs/paper-procedure.md#test-error).
    window, polyorder : int
        Savitzky-Golay window and order (21 and 2 as in the reference procedure).

    Returns
    -------
    SweepAnalysis
        Rows with a non-finite measured pose are dropped from their sweep.
    """
    M = check_poses(P_measured, "P_measured")
    D = check_poses(P_reference, "P_reference")
    if M.ndim != 3 or D.shape != M.shape:
        raise InputError(f"expected P_measured and P_reference of one shape (N, 4, 4), got "
                         f"{M.shape} and {D.shape}")
    S = np.asarray(stage, dtype=np.float64)
    if S.shape != (len(M), 6):
        raise InputError(f"expected `stage` of shape ({len(M)}, 6), got {S.shape}")
    if window % 2 == 0 or window <= polyorder:
        raise InputError(f"expected an odd window > polyorder, got window={window}")
    ok = np.all(np.isfinite(M), axis=(1, 2))
    err = np.full((len(M), 6), np.nan)
    if ok.any():
        err[ok] = pose_error_vectors(M[ok], D[ok], sensor_fixture)
    curves = []
    for lab, axis, rows in find_sweeps(S, labels, tol_m=tol_m, tol_rad=tol_rad,
                                       min_points=window):
        rows = rows[ok[rows]]
        a = SWEEP_AXES.index(axis)
        rot_axis = a >= 3
        s = np.rad2deg(S[rows, a]) if rot_axis else S[rows, a] * 1e3
        et = err[rows, :3] * 1e3
        er = np.rad2deg(err[rows, 3:])
        # average rows at the same coordinate (null rows, clipped ends), then sort
        key = np.round(s, 6)
        u, inv = np.unique(key, return_inverse=True)
        if len(u) < window:
            continue
        cnt = np.bincount(inv).astype(float)[:, None]
        s_u = np.bincount(inv, weights=s) / cnt[:, 0]
        et_u = np.stack([np.bincount(inv, weights=et[:, j]) for j in range(3)], 1) / cnt
        er_u = np.stack([np.bincount(inv, weights=er[:, j]) for j in range(3)], 1) / cnt
        dt = np.linalg.norm(_derivative(et_u, s_u, window, polyorder), axis=1)
        dr = np.linalg.norm(_derivative(er_u, s_u, window, polyorder), axis=1)
        nt, nr = np.linalg.norm(et_u, axis=1), np.linalg.norm(er_u, axis=1)
        if rot_axis:
            direct, cross, nl_d, nl_c = nr, nt, 100.0 * dr, dt
        else:
            direct, cross, nl_d, nl_c = nt, nr, 100.0 * dt, dr
        curves.append(SweepCurve(label=lab, axis=axis, motion=s_u, trans_err=et_u,
                                 rot_err=er_u, abs_direct=direct, abs_cross=cross,
                                 nonlin_direct=nl_d, nonlin_cross=nl_c))
    return SweepAnalysis(curves=tuple(curves), table=sweep_table(curves))


def sweep_table(curves) -> SweepTable:
    """Table IV: per kind of motion, the max over curves of each curve's RMS and max.

    ``xyz_*`` keys come from translation sweeps and ``rot_*`` keys from rotation sweeps; values
    are NaN if there is no such sweep.
    """
    units = {  # (row, motion) -> (abs unit, nonlinearity unit)
        ("direct", "xyz"): ("mm", "percent"), ("direct", "rot"): ("deg", "percent"),
        ("cross", "xyz"): ("deg", "deg_per_mm"), ("cross", "rot"): ("mm", "mm_per_deg")}
    table = {"direct": {}, "cross": {}}
    n = {"xyz": 0, "rot": 0}
    for (row, kind), (ua, un) in units.items():
        sel = [c for c in curves if c.is_rotation == (kind == "rot")]
        n[kind] = len(sel)

        def comb(field_name, stat, sel=sel, row=row):
            vals = []
            for c in sel:
                x = getattr(c, f"{field_name}_{row}")
                vals.append(np.sqrt(np.mean(x ** 2)) if stat == "rms" else np.max(x))
            return float(max(vals)) if vals else float("nan")

        t = table[row]
        t[f"{kind}_abs_rms_{ua}"] = comb("abs", "rms")
        t[f"{kind}_abs_max_{ua}"] = comb("abs", "max")
        t[f"{kind}_nonlin_rms_{un}"] = comb("nonlin", "rms")
        t[f"{kind}_nonlin_max_{un}"] = comb("nonlin", "max")
    return SweepTable(direct=table["direct"], cross=table["cross"], n_curves=n)
