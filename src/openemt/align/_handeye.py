"""Hand-eye / robot-world calibration ``A_i X = Y B_i`` (docs/alignment.md#the-model).

``A_i`` is the tracked tool in the measured tracker's frame (EM sensor in the field-generator
frame), ``B_i`` the rigidly attached reference tool in the reference frame (optical marker in
the camera frame, or the flange in the robot base frame). The two unknown constant transforms
are ``X`` (reference tool -> EM sensor) and ``Y`` (reference frame -> field-generator frame),
so ``A_i X`` and ``Y B_i`` are both the reference tool in the field-generator frame, and
``Y B_i X^-1`` is the reference pose of the EM sensor in the field-generator frame.

1. Closed-form start (Shah 2013, eqs. 11-17): ``R_A R_X = R_Y R_B`` gives
   ``(R_B (x) R_A) vec(R_X) = vec(R_Y)`` for every pair; the singular vectors of the summed
   Kronecker products for the largest singular value hold ``vec(R_X)`` and ``vec(R_Y)``
   (scaled to det +1 and projected onto SO(3)). The translations follow from the linear
   least squares ``[R_A, -I] [t_X; t_Y] = R_Y t_B - t_A``.
2. Nonlinear least squares (``scipy.optimize.least_squares``) of the pose residual
   ``A_i`` vs ``Y B_i X^-1``: translation (m) and rotation vector (rad), each divided by its
   own noise level (estimated from the residuals, so the two are weighted by their scatter),
   over left perturbations of X and Y. A robust (soft-L1) pass screens outliers: a pair whose
   whitened translation or rotation residual exceeds the chi-square(3) quantile
   :data:`OUTLIER_P` is left out of the final plain least-squares fit.
3. Standard errors from the Jacobian at the solution: ``cov = s^2 (J^T J)^-1`` with
   ``s^2`` the residual variance per degree of freedom.
4. Held-out check: k-fold over the inlier pairs, each fold fitted without its pairs.

References: M. Shah, "Solving the robot-world/hand-eye calibration problem using the
Kronecker product", J. Mechanisms Robotics 5(3), 2013; F. Park and B. Martin, "Robot sensor
calibration: solving AX = XB on the Euclidean group", IEEE Trans. Robot. Autom. 10(5), 1994.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from .._errors import InputError
from ..evaluate import pose_error_magnitudes
from ..geometry import (
    check_poses,
    invert,
    nearest_rotation,
    pose_from_rt,
    require_rotation_diversity,
)

__all__ = [
    "MIN_PAIRS",
    "OUTLIER_P",
    "HandEyeResult",
    "axyb_closed_form",
    "fit_axyb",
    "reference_in_measured_frame",
]

#: Fewest pairs with which X and Y are determined (two rotations about distinct axes and one
#: more pair for the translations; docs/alignment.md#how-many-pairs).
MIN_PAIRS = 3
#: Tail probability of the chi-square(3) screen of whitened residuals.
OUTLIER_P = 1e-3
#: Folds of the held-out check (fewer when there are fewer pairs).
HELD_OUT_FOLDS = 5


def axyb_closed_form(A, B) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form X, Y of ``A_i X = Y B_i`` (Shah 2013; see the module docstring).

    Parameters
    ----------
    A, B : array_like, shape (N, 4, 4)
        Paired poses, N >= 3.

    Returns
    -------
    (X, Y) : ndarrays, shape (4, 4)
    """
    A = check_poses(A, "A")
    B = check_poses(B, "B")
    n = len(A)
    K = np.zeros((9, 9))
    for i in range(n):
        K += np.kron(B[i, :3, :3], A[i, :3, :3])
    U, _, Vt = np.linalg.svd(K)
    Vx = Vt[0].reshape(3, 3, order="F")
    Vy = U[:, 0].reshape(3, 3, order="F")
    det = np.linalg.det(Vx)
    if abs(det) < 1e-12:
        raise InputError("expected pose pairs whose rotations determine X and Y, got a "
                         "degenerate set (all rotations about one axis or none)")
    alpha = np.sign(det) * abs(det) ** (-1.0 / 3.0)
    Rx, Ry = nearest_rotation(alpha * Vx), nearest_rotation(alpha * Vy)
    C = np.zeros((3 * n, 6))
    d = np.zeros(3 * n)
    for i in range(n):
        C[3 * i:3 * i + 3, :3] = A[i, :3, :3]
        C[3 * i:3 * i + 3, 3:] = -np.eye(3)
        d[3 * i:3 * i + 3] = Ry @ B[i, :3, 3] - A[i, :3, 3]
    t = np.linalg.lstsq(C, d, rcond=None)[0]
    return pose_from_rt(Rx, t[:3]), pose_from_rt(Ry, t[3:])


def reference_in_measured_frame(B, X, Y) -> np.ndarray:
    """Reference poses mapped onto the measured tool: ``Y B_i X^-1``, shape (N, 4, 4)."""
    return check_poses(Y) @ check_poses(B, "B") @ invert(X)


def _perturb(P0: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Pose with translation ``t0 + d[:3]`` and rotation ``exp([d[3:]]x) R0`` (left)."""
    R = Rotation.from_rotvec(d[3:]).as_matrix() @ P0[:3, :3]
    return pose_from_rt(R, P0[:3, 3] + d[:3])


def _raw_residuals(A, B, X, Y) -> tuple[np.ndarray, np.ndarray]:
    """Translation (m) and rotation-vector (rad) residuals of ``A_i`` vs ``Y B_i X^-1``."""
    Ah = reference_in_measured_frame(B, X, Y)
    rt = A[:, :3, 3] - Ah[:, :3, 3]
    rr = Rotation.from_matrix(A[:, :3, :3] @ np.swapaxes(Ah[:, :3, :3], -1, -2)).as_rotvec()
    return rt, rr


def _whitened(A, B, X0, Y0, sig_t, sig_r):
    """Whitened residuals as a function of left perturbations ``p`` (12,) of ``(X0, Y0)``."""
    def fun(p):
        rt, rr = _raw_residuals(A, B, _perturb(X0, p[:6]), _perturb(Y0, p[6:]))
        return np.concatenate([(rt / sig_t).ravel(), (rr / sig_r).ravel()])

    return fun


def _refine(A, B, X0, Y0, sig_t, sig_r, loss="linear"):
    res = least_squares(_whitened(A, B, X0, Y0, sig_t, sig_r), np.zeros(12), loss=loss,
                        f_scale=3.0, x_scale="jac", method="trf")
    return _perturb(X0, res.x[:6]), _perturb(Y0, res.x[6:])


def _jacobian(fun) -> np.ndarray:
    """Jacobian of the :func:`_whitened` residuals ``fun`` at 0 (central differences, step
    1e-6)."""
    return np.stack([(fun(e) - fun(-e)) / 2e-6 for e in 1e-6 * np.eye(12)], axis=1)


def _sigmas(rt, rr, dof_fraction=1.0) -> tuple[float, float]:
    st = float(np.sqrt(np.sum(rt ** 2) / max(rt.size * dof_fraction, 1)))
    sr = float(np.sqrt(np.sum(rr ** 2) / max(rr.size * dof_fraction, 1)))
    return max(st, 1e-9), max(sr, 1e-9)


def _robust_sigmas(rt, rr) -> tuple[float, float]:
    """Noise per component from the median absolute deviation (robust to outliers)."""
    st = 1.4826 * float(np.median(np.abs(rt)))
    sr = 1.4826 * float(np.median(np.abs(rr)))
    return max(st, 1e-9), max(sr, 1e-9)


def _fit(A, B, robust: bool):
    X, Y = axyb_closed_form(A, B)
    rt, rr = _raw_residuals(A, B, X, Y)
    st, sr = _robust_sigmas(rt, rr) if robust else _sigmas(rt, rr)
    for _ in range(2):  # re-weight: the noise levels come from the fit's own residuals
        X, Y = _refine(A, B, X, Y, st, sr, loss="soft_l1" if robust else "linear")
        rt, rr = _raw_residuals(A, B, X, Y)
        st, sr = _robust_sigmas(rt, rr) if robust else _sigmas(rt, rr)
    return X, Y, st, sr


@dataclass(frozen=True, eq=False)
class HandEyeResult:
    """Result of :func:`fit_axyb`.

    Attributes
    ----------
    X, Y : ndarray, shape (4, 4)
        Reference tool -> measured tool, and reference frame -> measured tracker frame (m).
    X_se, Y_se : ndarray, shape (6,)
        Standard errors ``[x, y, z, rx, ry, rz]``: translation (m) and a small rotation
        about the axes of the parent frame (rad), i.e. of the left perturbation
        ``exp([w]x) R``.
    covariance : ndarray, shape (12, 12)
        Covariance of ``[X perturbation, Y perturbation]``.
    residual_trans, residual_rot : ndarray, shape (N,)
        Per-pair residual magnitudes (m, rad) of ``A_i`` vs ``Y B_i X^-1``, all pairs.
    inlier : ndarray of bool, shape (N,)
        Pairs used in the final fit (False: flagged as outliers).
    sigma_trans, sigma_rot : float
        Noise per component estimated from the inlier residuals (m, rad).
    held_out : dict
        ``trans_rms_mm``, ``rot_rms_deg`` of inlier pairs predicted by fits without them,
        ``n_folds``; empty when there are too few pairs.
    condition : float
        Condition number of the whitened Jacobian (large: X or Y poorly determined).
    """

    X: np.ndarray
    Y: np.ndarray
    X_se: np.ndarray
    Y_se: np.ndarray
    covariance: np.ndarray
    residual_trans: np.ndarray
    residual_rot: np.ndarray
    inlier: np.ndarray
    sigma_trans: float
    sigma_rot: float
    held_out: dict = field(default_factory=dict)
    condition: float = float("nan")

    @property
    def outliers(self) -> np.ndarray:
        return np.flatnonzero(~self.inlier)

    def summary(self) -> dict:
        """JSON-able summary (mm/deg in the names; X, Y and the standard errors in m/rad)."""
        ok = self.inlier
        return {
            "n": int(ok.size), "n_inliers": int(ok.sum()), "n_outliers": int((~ok).sum()),
            "outliers": self.outliers.tolist(),
            "residual_trans_rms_mm": float(1e3 * np.sqrt(np.mean(self.residual_trans[ok] ** 2))),
            "residual_rot_rms_deg": float(np.rad2deg(np.sqrt(np.mean(self.residual_rot[ok] ** 2)))),
            "sigma_trans_mm": 1e3 * self.sigma_trans,
            "sigma_rot_deg": float(np.rad2deg(self.sigma_rot)),
            "X": self.X, "Y": self.Y, "X_se": self.X_se, "Y_se": self.Y_se,
            "se_units": "m, m, m, rad, rad, rad (left perturbation)",
            "held_out": dict(self.held_out), "condition": self.condition,
        }


def fit_axyb(A, B, *, robust: bool = True, folds: int = HELD_OUT_FOLDS,
             seed: int = 0) -> HandEyeResult:
    """Solve ``A_i X = Y B_i`` with standard errors, outlier screening and a held-out check.

    Parameters
    ----------
    A : array_like, shape (N, 4, 4)
        Measured tool poses (EM sensor in the field-generator frame), m.
    B : array_like, shape (N, 4, 4)
        Reference tool poses (marker in the camera frame, flange in the robot base), m.
    robust : bool
        Screen outliers with a soft-L1 pass and the chi-square test (default).
    folds : int
        Folds of the held-out check (0: none).
    seed : int
        Seed of the fold assignment.

    Returns
    -------
    HandEyeResult
    """
    from ..correct import MAX_FOLDS, kfold_splits

    A = check_poses(A, "A")
    B = check_poses(B, "B")
    if A.ndim != 3 or A.shape != B.shape:
        raise InputError(f"expected A and B of the same shape (N, 4, 4), got {A.shape} and "
                         f"{B.shape}")
    n = len(A)
    if n < MIN_PAIRS:
        raise InputError(f"expected at least {MIN_PAIRS} pose pairs for X and Y, got {n}")
    if not (np.all(np.isfinite(A)) and np.all(np.isfinite(B))):
        raise InputError("expected finite pose pairs, got non-finite values")
    folds = int(folds)
    if folds and not 2 <= folds <= MAX_FOLDS:
        raise InputError(f"expected 2 <= folds <= {MAX_FOLDS} (or 0), got {folds}")
    # a property of the motion, tested before any fit (scale-free; openemt.geometry._motion)
    require_rotation_diversity(A, "X and Y of A X = Y B")
    inlier = np.ones(n, dtype=bool)
    X, Y, st, sr = _fit(A, B, robust=robust)
    if robust:
        rt, rr = _raw_residuals(A, B, X, Y)
        lim = chi2.ppf(1.0 - OUTLIER_P, 3)
        inlier = (np.sum((rt / st) ** 2, 1) <= lim) & (np.sum((rr / sr) ** 2, 1) <= lim)
        if inlier.sum() < MIN_PAIRS:
            raise InputError(f"expected at least {MIN_PAIRS} consistent pose pairs, got "
                             f"{int(inlier.sum())} of {n} after outlier screening")
        X, Y, st, sr = _fit(A[inlier], B[inlier], robust=False)
    Ai, Bi = A[inlier], B[inlier]
    m = int(inlier.sum())
    rt, rr = _raw_residuals(Ai, Bi, X, Y)
    dof = max(6 * m - 12, 1)
    # noise levels with the fitted parameters' share removed, then the residual variance s^2
    st, sr = _sigmas(rt, rr, dof_fraction=dof / (6 * m))
    fun = _whitened(Ai, Bi, X, Y, st, sr)
    J = _jacobian(fun)
    r = fun(np.zeros(12))
    s2 = float(r @ r) / dof
    JtJ = J.T @ J
    cov = s2 * np.linalg.pinv(JtJ)
    sv = np.linalg.svd(J, compute_uv=False)
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")
    se = np.sqrt(np.clip(np.diag(cov), 0, None))

    held = {}
    if folds and m >= 2 * MIN_PAIRS:
        k = min(folds, m // MIN_PAIRS)
        idx = np.flatnonzero(inlier)
        et, er = np.empty(m), np.empty(m)
        for train, test in kfold_splits(m, k, seed=seed):
            Xf, Yf, _, _ = _fit(A[idx[train]], B[idx[train]], robust=False)
            Ah = reference_in_measured_frame(B[idx[test]], Xf, Yf)
            et[test], er[test] = pose_error_magnitudes(A[idx[test]], Ah)
        held = {"n_folds": int(k), "trans_rms_mm": float(1e3 * np.sqrt(np.mean(et ** 2))),
                "rot_rms_deg": float(np.rad2deg(np.sqrt(np.mean(er ** 2))))}
    tm, rm = pose_error_magnitudes(A, reference_in_measured_frame(B, X, Y))
    return HandEyeResult(X=X, Y=Y, X_se=se[:6], Y_se=se[6:], covariance=cov,
                         residual_trans=tm, residual_rot=rm, inlier=inlier, sigma_trans=st,
                         sigma_rot=sr, held_out=held, condition=cond)
