"""Pivot calibration (tool-tip offset) and spin calibration (tool axis) from tracked poses.

Pivot: the tool is pivoted with its tip held in a divot, so for every pose ``(R_i, p_i)`` (tool
in tracker) the tip ``t`` (tool frame) lands on the fixed pivot point ``q`` (tracker frame):
``R_i t + p_i = q``. Methods:

* ``"algebraic"``: linear least squares of ``[R_i, -I] [t; q] = -p_i`` over all poses
  (the standard algebraic two-step-free solution; e.g. Yaniv 2015);
* ``"sphere"``: a sphere fitted to the positions ``p_i`` (centre ``q``), then
  ``t = mean R_i^T (q - p_i)``; uses the orientations only for the tip direction;
* ``"ransac"``: the algebraic solution on random minimal sets of 3 poses, least median of
  squares (or a given threshold), refitted on the inliers (:mod:`openemt.navigate._robust`).

Per pose the residual is ``R_i t + p_i - q`` (the 3-D miss of the tip). Standard errors of
``t`` and ``q`` are the linearised covariance of the algebraic model at the solution,
``s^2 (J^T J)^-1`` with ``s^2 = RSS / (3 n - 6)``, whichever method found the solution.

Spin: the tool turns about its own axis (a needle spun in a guide), so a unit axis ``a`` (tool
frame) maps to one tracker direction ``b``: ``R_i a = b``. ``a`` maximises ``|mean(R_i) a|``
(top right-singular vector); the points of the axis stay fixed, so a point ``c`` of it (tool
frame, taken perpendicular to ``a``: the axis point nearest the tool origin) satisfies
``R_i c + p_i = d``, solved like the pivot with ``c`` restricted to the plane normal to ``a``.

Refusals (``InputError`` naming cause and remedy), only where no answer can come from the
poses, checked before any fit: too few poses; pivot rotations that do not turn about two axes
(:func:`openemt.geometry.require_rotation_diversity`; rotations about one axis leave the tip's
component along it undetermined); a spin of less than ``MIN_SPIN_DEG``. A residual RMS above
the expected level (``max_rms_mm``, and ``max_rms_deg`` of the spin axis) is flagged: the
result's ``warnings`` name the figure and the limit.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .._errors import InputError
from .._result import Result
from ..geometry import check_poses, require_rotation_diversity, rotation_diversity
from ._robust import linear_covariance, ransac

__all__ = ["MAX_PIVOT_RMS_MM", "MAX_SPIN_RMS_DEG", "MIN_POSES", "MIN_SPIN_DEG",
           "PIVOT_METHODS", "TOOL_FORMAT", "PivotResult", "SpinResult", "pivot_calibration",
           "read_tip_transform", "spin_calibration"]

PIVOT_METHODS = ("algebraic", "sphere", "ransac")
#: Fewest usable poses of a pivot or spin calibration.
MIN_POSES = 10
#: Default level of the pivot residual RMS (3-D, mm) above which the result is flagged: a tip
#: that slipped in the divot or a bent tool gives more; EM styluses pivot to about 0.2-1 mm.
MAX_PIVOT_RMS_MM = 2.0
#: Default level of the spin residual RMS (deg) above which the result is flagged: the axis wobbled (the tool did not turn about
#: one axis) when the directions ``R_i a`` scatter more.
MAX_SPIN_RMS_DEG = 2.0
#: Fewest degrees (RMS about the mean orientation) a spin calibration must turn the tool.
MIN_SPIN_DEG = 10.0


def _valid(poses, what: str):
    P = check_poses(poses, "poses")
    if P.ndim != 3:
        raise InputError(f"expected poses of shape (N, 4, 4) for {what}, got {P.shape}")
    ok = np.all(np.isfinite(P), axis=(1, 2))
    if ok.sum() < MIN_POSES:
        raise InputError(f"expected at least {MIN_POSES} poses with finite values for {what}, "
                         f"got {int(ok.sum())} (of {len(P)}): record more poses")
    return P, ok


def _design(R):
    """Rows ``[R_i, -I]`` of the pivot equations, (3n, 6)."""
    n = len(R)
    A = np.empty((n, 3, 6))
    A[:, :, :3] = R
    A[:, :, 3:] = -np.eye(3)
    return A.reshape(3 * n, 6)


def _solve_algebraic(R, p):
    A = _design(R)
    x, *_, rank, _ = np.linalg.lstsq(A, -p.reshape(-1), rcond=None)
    return (x[:3], x[3:]) if rank == 6 else None


def _solve_sphere(R, p):
    A = np.hstack([2 * p, np.ones((len(p), 1))])
    x, *_, rank, _ = np.linalg.lstsq(A, np.sum(p ** 2, axis=1), rcond=None)
    if rank < 4:
        return None
    q = x[:3]
    t = np.mean(np.einsum("nji,nj->ni", R, q - p), axis=0)
    return t, q


def _residuals(R, p, t, q):
    return np.einsum("nij,j->ni", R, t) + p - q


@dataclass(frozen=True, eq=False)
class PivotResult(Result):
    """Result of :func:`pivot_calibration` (SI units; ``to_dict()`` gives mm).

    Attributes
    ----------
    method : str
    tip : ndarray, shape (3,)
        Tool-tip offset in the tool frame (m).
    pivot : ndarray, shape (3,)
        Pivot point in the tracker frame (m).
    tip_se, pivot_se : ndarray, shape (3,)
        Standard errors (m).
    residuals : ndarray, shape (N, 3)
        Per input pose ``R_i t + p_i - q`` (m); NaN for non-finite poses.
    inlier : ndarray of bool, shape (N,)
        Poses the solution was fitted to.
    rms, rms_component, max : float
        RMS of the inliers' 3-D residual distances, of their components, and the largest (m).
    rotation_spread_deg : tuple of 2 float
        RMS rotation of the inliers about the dominant and a second axis (deg).
    warnings : tuple of str
        Residuals above the expected level, with their figures.
    """

    method: str
    tip: np.ndarray
    pivot: np.ndarray
    tip_se: np.ndarray
    pivot_se: np.ndarray
    residuals: np.ndarray
    inlier: np.ndarray
    rms: float
    rms_component: float
    max: float
    rotation_spread_deg: tuple
    warnings: tuple = ()
    _not_in_dict: ClassVar[tuple] = ("residuals", "inlier")

    @property
    def n(self) -> int:
        return int(np.all(np.isfinite(self.residuals), axis=1).sum())

    @property
    def n_inliers(self) -> int:
        return int(self.inlier.sum())

    @property
    def tip_transform(self) -> np.ndarray:
        """4x4 transform from the tip frame to the tool frame (translation ``tip``, no
        rotation): ``pose @ tip_transform`` is the pose of the tip."""
        T = np.eye(4)
        T[:3, 3] = self.tip
        return T

    def _items(self) -> dict:
        finite = np.all(np.isfinite(self.residuals), axis=1)
        return {"method": self.method, "n": self.n, "n_inliers": self.n_inliers,
                "n_nonfinite": int((~finite).sum()),
                "tip_mm": 1e3 * self.tip, "tip_se_mm": 1e3 * self.tip_se,
                "pivot_mm": 1e3 * self.pivot, "pivot_se_mm": 1e3 * self.pivot_se,
                "tip_length_mm": 1e3 * float(np.linalg.norm(self.tip)),
                "rms_mm": 1e3 * self.rms, "rms_component_mm": 1e3 * self.rms_component,
                "max_mm": 1e3 * self.max, "rotation_spread_deg": list(self.rotation_spread_deg),
                "outlier_rows": np.flatnonzero(finite & ~self.inlier).tolist(),
                "warnings": list(self.warnings)}

    def per_pose(self) -> dict:
        """Per-pose residual vectors and distances (mm) and the inlier flags, JSON-ready."""
        r = 1e3 * self.residuals
        return {"residual_mm": [None if not np.all(np.isfinite(v)) else v.tolist() for v in r],
                "distance_mm": [None if not np.isfinite(d) else float(d)
                                for d in np.linalg.norm(r, axis=1)],
                "inlier": self.inlier.tolist()}


def _check_rms(rms_value, limit, unit, what, remedy) -> tuple:
    """A warning (one-tuple) when ``rms_value`` is above ``limit``, else ()."""
    if limit is None or rms_value <= limit:
        return ()
    return (f"{what} residual RMS {rms_value:.3g} {unit} is above the expected {limit:g} "
            f"{unit}: {remedy}",)


def pivot_calibration(poses, method: str = "algebraic", *, max_rms_mm=MAX_PIVOT_RMS_MM,
                      threshold_mm=None, iterations: int = 300, seed: int = 0) -> PivotResult:
    """Tool-tip offset and pivot point from poses recorded while pivoting the tool.

    Parameters
    ----------
    poses : array_like, shape (N, 4, 4)
        Tool poses in the tracker frame (m); non-finite poses are left out.
    method : {"algebraic", "sphere", "ransac"}
        See the module docstring.
    max_rms_mm : float or None
        Flag (``warnings``) a solution whose residual RMS (3-D, inliers) exceeds this (mm);
        None: no flag.
    threshold_mm : float, optional
        ``ransac``: inlier distance (mm); default: from the noise scale (least median of
        squares, chi-square(3) at p = 1e-3).
    iterations, seed : int
        ``ransac``: minimal sets drawn, and the seed of the draw.

    Returns
    -------
    PivotResult

    Examples
    --------
    >>> import numpy as np
    >>> from scipy.spatial.transform import Rotation
    >>> R = Rotation.from_rotvec(np.random.default_rng(0).normal(0, 0.4, (30, 3))).as_matrix()
    >>> tip, pivot = np.array([0.0, 0.0, 0.15]), np.array([0.1, 0.0, 0.2])
    >>> P = np.tile(np.eye(4), (30, 1, 1))
    >>> P[:, :3, :3] = R
    >>> P[:, :3, 3] = pivot - R @ tip
    >>> res = pivot_calibration(P)
    >>> (np.round(res.to_dict()["tip_mm"], 6) + 0.0).tolist(), res.n_inliers
    ([0.0, 0.0, 150.0], 30)
    """
    if method not in PIVOT_METHODS:
        raise InputError(f"expected method in {PIVOT_METHODS}, got {method!r}")
    P, ok = _valid(poses, "pivot calibration")
    require_rotation_diversity(P[ok], "the tool tip of a pivot calibration")
    R, p = P[ok, :3, :3], P[ok, :3, 3]
    n = len(R)
    if method == "algebraic":
        sol = _solve_algebraic(R, p)
        inl = np.ones(n, bool)
    elif method == "sphere":
        sol = _solve_sphere(R, p)
        inl = np.ones(n, bool)
    else:
        def fit(rows):
            return _solve_algebraic(R[rows], p[rows]) if len(rows) >= 3 else None

        def dist(model):
            return np.linalg.norm(_residuals(R, p, *model), axis=1)

        def per_axis(model, rows):
            r = _residuals(R[rows], p[rows], *model).reshape(-1)
            return float(np.sqrt(r @ r / max(r.size - 6, 1)))

        thr = None if threshold_mm is None else 1e-3 * float(threshold_mm)
        sol, inl, _ = ransac(n, 3, fit, dist, threshold=thr, iterations=iterations, seed=seed,
                             per_axis=per_axis)
        if sol is not None and inl.sum() < MIN_POSES:
            raise InputError(f"expected at least {MIN_POSES} inlier poses, got {int(inl.sum())} "
                             f"of {n}: the tip slipped too often; record again")
        if sol is not None:
            require_rotation_diversity(R[inl], "the tool tip of a pivot calibration (inliers)")
    if sol is None:
        raise InputError("expected poses that determine the tip and the pivot, got a degenerate "
                         "set: pivot the tool about two axes")
    t, q = sol
    r_in = _residuals(R[inl], p[inl], t, q)
    cov, _ = linear_covariance(_design(R[inl]), r_in.reshape(-1), 6)
    se = np.sqrt(np.diag(cov))
    dist_in = np.linalg.norm(r_in, axis=1)
    rms = float(np.sqrt(np.mean(dist_in ** 2)))
    warn = _check_rms(1e3 * rms, max_rms_mm, "mm", "pivot",
                      "the tip slipped in the divot, the tool bends or the tracker is distorted "
                      "here; check the result, re-record or use the ransac method")
    residuals = np.full((len(P), 3), np.nan)
    residuals[ok] = _residuals(R, p, t, q)
    inlier = np.zeros(len(P), bool)
    inlier[np.flatnonzero(ok)[inl]] = True
    d = rotation_diversity(R[inl])
    return PivotResult(method=method, tip=t, pivot=q, tip_se=se[:3], pivot_se=se[3:],
                       residuals=residuals, inlier=inlier, rms=rms,
                       rms_component=rms / np.sqrt(3), max=float(dist_in.max()),
                       rotation_spread_deg=(d.primary_deg, d.second_deg), warnings=warn)


# ---------------------------------------------------------------------------------------------
# spin calibration


def _perp_basis(a):
    """Two unit vectors completing ``a`` to an orthonormal basis, (3, 2)."""
    U = np.linalg.svd(np.eye(3) - np.outer(a, a))[0]
    return U[:, :2]


def _spin_axis(R):
    M = R.mean(axis=0)
    U, s, Vt = np.linalg.svd(M)
    a = Vt[0]
    b = M @ a
    nb = np.linalg.norm(b)
    if nb < 1e-9:
        return None
    return a, b / nb


def _spin_angles(R, a, b):
    c = np.clip(np.einsum("nij,j->ni", R, a) @ b, -1.0, 1.0)
    return np.arccos(c)


@dataclass(frozen=True, eq=False)
class SpinResult(Result):
    """Result of :func:`spin_calibration` (SI units; ``to_dict()`` gives mm and deg).

    Attributes
    ----------
    method : str
    axis : ndarray, shape (3,)
        Unit tool axis in the tool frame.
    axis_tracker : ndarray, shape (3,)
        The same axis in the tracker frame (the spin axis).
    axis_se_deg : float
        Standard error of the axis direction (RMS over its two perpendicular components, deg).
    point, point_tracker : ndarray, shape (3,)
        The axis point nearest the tool origin, in the tool frame, and where it stays in the
        tracker frame (m).
    point_se : ndarray, shape (3,)
        Standard errors of ``point`` (m).
    angle_residuals : ndarray, shape (N,)
        Angle between ``R_i axis`` and ``axis_tracker`` per pose (rad); NaN for non-finite poses.
    point_residuals : ndarray, shape (N, 3)
        ``R_i point + p_i - point_tracker`` per pose (m).
    inlier : ndarray of bool, shape (N,)
    rms_deg, rms : float
        RMS angle residual (deg) and RMS point-residual distance (m) of the inliers.
    spin_deg : float
        RMS rotation about the mean orientation (deg): how far the tool was turned.
    warnings : tuple of str
        Residuals above the expected level, with their figures.
    """

    method: str
    axis: np.ndarray
    axis_tracker: np.ndarray
    axis_se_deg: float
    point: np.ndarray
    point_tracker: np.ndarray
    point_se: np.ndarray
    angle_residuals: np.ndarray
    point_residuals: np.ndarray
    inlier: np.ndarray
    rms_deg: float
    rms: float
    spin_deg: float
    warnings: tuple = ()
    _not_in_dict: ClassVar[tuple] = ("angle_residuals", "point_residuals", "inlier")

    @property
    def n(self) -> int:
        return int(np.isfinite(self.angle_residuals).sum())

    @property
    def n_inliers(self) -> int:
        return int(self.inlier.sum())

    def _items(self) -> dict:
        finite = np.isfinite(self.angle_residuals)
        return {"method": self.method, "n": self.n, "n_inliers": self.n_inliers,
                "n_nonfinite": int((~finite).sum()),
                "axis": self.axis, "axis_tracker": self.axis_tracker,
                "axis_se_deg": self.axis_se_deg, "point_mm": 1e3 * self.point,
                "point_se_mm": 1e3 * self.point_se,
                "point_tracker_mm": 1e3 * self.point_tracker, "rms_deg": self.rms_deg,
                "rms_mm": 1e3 * self.rms, "rms_component_mm": 1e3 * self.rms / np.sqrt(3),
                "spin_deg": self.spin_deg,
                "outlier_rows": np.flatnonzero(finite & ~self.inlier).tolist(),
                "warnings": list(self.warnings)}

    def per_pose(self) -> dict:
        """Per-pose angle (deg) and point residuals (mm) and the inlier flags, JSON-ready."""
        a = np.rad2deg(self.angle_residuals)
        r = 1e3 * self.point_residuals
        return {"angle_deg": [None if not np.isfinite(v) else float(v) for v in a],
                "point_residual_mm": [None if not np.all(np.isfinite(v)) else v.tolist()
                                      for v in r],
                "inlier": self.inlier.tolist()}


def spin_calibration(poses, method: str = "algebraic", *, tip=None,
                     max_rms_deg=MAX_SPIN_RMS_DEG, max_rms_mm=None, threshold_deg=None,
                     iterations: int = 300, seed: int = 0) -> SpinResult:
    """The tool's axis from poses recorded while turning the tool about it.

    Parameters
    ----------
    poses : array_like, shape (N, 4, 4)
        Tool poses in the tracker frame (m).
    method : {"algebraic", "ransac"}
        ``ransac`` screens poses by their angle residual (minimal sets of 3 poses).
    tip : array_like, shape (3,), optional
        Tool-tip offset (m, e.g. from :func:`pivot_calibration`): the axis is signed to point
        from the tool origin towards it. Default: its largest component is positive.
    max_rms_deg, max_rms_mm : float or None
        Flag (``warnings``) a solution whose RMS angle residual (deg) or point residual (mm)
        exceeds these.
    threshold_deg : float, optional
        ``ransac`` inlier angle (deg); default from the noise scale.

    Returns
    -------
    SpinResult
    """
    if method not in ("algebraic", "ransac"):
        raise InputError(f"expected method in ('algebraic', 'ransac'), got {method!r}")
    P, ok = _valid(poses, "spin calibration")
    R, p = P[ok, :3, :3], P[ok, :3, 3]
    n = len(R)
    d = rotation_diversity(R)
    if d.primary_deg < MIN_SPIN_DEG:
        raise InputError(f"expected the tool turned about its axis by at least {MIN_SPIN_DEG:g} "
                         f"deg RMS for a spin calibration, got {d.primary_deg:.2f} deg: turn the "
                         f"tool further about its axis")
    inl = np.ones(n, bool)
    if method == "ransac":
        def fit(rows):
            return _spin_axis(R[rows]) if len(rows) >= 3 else None

        def dist(model):
            return _spin_angles(R, *model)

        def per_axis(model, rows):
            a = dist(model)[rows]
            return float(np.sqrt(np.sum(a ** 2) / max(2 * len(rows) - 4, 1)))

        thr = None if threshold_deg is None else np.deg2rad(float(threshold_deg))
        sol, inl, _ = ransac(n, 3, fit, dist, threshold=thr, iterations=iterations, seed=seed,
                             per_axis=per_axis, dof=2)
        if sol is None or inl.sum() < MIN_POSES:
            raise InputError(f"expected at least {MIN_POSES} inlier poses, got "
                             f"{int(inl.sum())} of {n}: record again")
    sol = _spin_axis(R[inl])
    if sol is None:
        raise InputError("expected poses turned about one tool axis, got rotations whose mean "
                         "vanishes: turn the tool less than half a revolution each way")
    a, b = sol
    if tip is not None:
        sign = np.sign(np.dot(a, np.asarray(tip, float))) or 1.0
    else:
        sign = np.sign(a[np.argmax(np.abs(a))]) or 1.0
    a, b = sign * a, sign * b
    Ri, pi = R[inl], p[inl]
    ang = _spin_angles(Ri, a, b)
    rms_deg = float(np.rad2deg(np.sqrt(np.mean(ang ** 2))))
    warn = _check_rms(rms_deg, max_rms_deg, "deg", "spin-axis",
                      "the tool wobbled instead of turning about one axis; hold it in a guide, "
                      "re-record or use the ransac method")
    # axis direction covariance: residuals B_b^T R_i a, unknowns (2 of a, 2 of b)
    Ba, Bb = _perp_basis(a), _perp_basis(b)
    J = np.concatenate([np.einsum("ji,njk,kl->nil", Bb, Ri, Ba),
                        np.broadcast_to(-np.eye(2), (len(Ri), 2, 2))], axis=2).reshape(-1, 4)
    r = np.einsum("ji,nj->ni", Bb, np.einsum("nij,j->ni", Ri, a)).reshape(-1)
    cov, _ = linear_covariance(J, r, 4)
    axis_se = float(np.rad2deg(np.sqrt(cov[0, 0] + cov[1, 1])))
    # axis point: c = Ba y (perpendicular to a), R_i c + p_i = e
    A = np.concatenate([np.einsum("nij,jk->nik", Ri, Ba),
                        np.broadcast_to(-np.eye(3), (len(Ri), 3, 3))], axis=2).reshape(-1, 5)
    x = np.linalg.lstsq(A, -pi.reshape(-1), rcond=None)[0]
    c, e = Ba @ x[:2], x[2:]
    rp = _residuals(Ri, pi, c, e)
    covp, _ = linear_covariance(A, rp.reshape(-1), 5)
    point_se = np.sqrt(np.maximum(np.diag(Ba @ covp[:2, :2] @ Ba.T), 0.0))
    rms = float(np.sqrt(np.mean(np.sum(rp ** 2, axis=1))))
    warn += _check_rms(1e3 * rms, max_rms_mm, "mm", "spin-axis point",
                       "the tool's axis moved while it turned; hold it in a guide and re-record")
    angles = np.full(len(P), np.nan)
    angles[ok] = _spin_angles(R, a, b)
    pres = np.full((len(P), 3), np.nan)
    pres[ok] = _residuals(R, p, c, e)
    inlier = np.zeros(len(P), bool)
    inlier[np.flatnonzero(ok)[inl]] = True
    return SpinResult(method=method, axis=a, axis_tracker=b, axis_se_deg=axis_se, point=c,
                      point_tracker=e, point_se=point_se, angle_residuals=angles,
                      point_residuals=pres, inlier=inlier, rms_deg=rms_deg, rms=rms,
                      spin_deg=float(rotation_diversity(Ri).primary_deg), warnings=warn)


#: ``format`` of the tool-calibration files ``openemt pivot`` and ``openemt spin`` write.
TOOL_FORMAT = "openemt.tool-calibration"


def read_tip_transform(path) -> np.ndarray:
    """The tip transform (4x4, m) of a pivot calibration written by ``openemt pivot``:
    ``pose @ T`` is the pose of the tool tip (translation ``tip``, no rotation)."""
    from ._inputs import read_transform_file

    T, d = read_transform_file(path, "a pivot calibration from 'openemt pivot'", TOOL_FORMAT,
                               "tip_transform", kind="pivot")
    if T.shape != (4, 4) or not np.all(np.isfinite(T)) or not np.allclose(
            T[3], [0, 0, 0, 1]) or not np.allclose(T[:3, :3], np.eye(3)):
        raise InputError(f"expected `tip_transform` a finite 4x4 translation in {path}, got "
                         f"{d.get('tip_transform')!r}")
    return T
