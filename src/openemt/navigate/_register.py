"""Paired-point registration: the rigid (or similarity) transform that maps one point set onto
another, its fiducial registration error and the predicted target registration error.

The fit is the closed-form least-squares solution by SVD (Arun et al. 1987; Horn 1987; with
the reflection guard and the scale of Umeyama 1991), weighted per point, batched over frames
(:func:`register_points_batch`: N frames of K markers, e.g. the marker cloud of a tool in every
frame of an optical or EM tracker).

Error prediction (Fitzpatrick, West & Maurer 1998, IEEE TMI 17(5):694-702; the distribution in
Fitzpatrick & West 2001, IEEE TMI 20(9):917-927): with an isotropic fiducial localisation error
of RMS ``FLE``, ``<FRE^2> = (1 - 2/K) FLE^2`` and at a target ``r``

    ``<TRE^2(r)> = FLE^2 / K * (1 + 1/3 * sum_k d_k^2 / f_k^2)``

where ``d_k`` is the distance of ``r`` from the k-th principal axis of the fiducial
configuration and ``f_k`` the RMS distance of the fiducials from that axis. ``FLE`` is given by
the user or estimated from the FRE. The formula assumes equal weights.

Standard errors of the rotation (rotation vector, tracker/fixed frame) and translation come from
the linearised weighted least-squares covariance at the solution, with the noise scale from the
residuals (``3 K - 6`` degrees of freedom; 7 parameters with scale).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .._errors import InputError
from .._result import Result
from ..geometry import check_points, pose_from_rt, skew
from ._robust import linear_covariance

__all__ = ["BatchRegistration", "Registration", "predicted_tre", "register_points",
           "register_points_batch", "rigid_fit"]

#: Fewest paired points of a registration.
MIN_POINTS = 3
#: Largest coordinate accepted (m): beyond it the squares of the fit lose all precision.
MAX_COORDINATE = 1e4
#: Default FRE RMS (mm) above which a registration is flagged.
MAX_FRE_MM = 2.0


def rigid_fit(fixed, moving, weights=None, *, scale: bool = False):
    """Batched weighted least-squares fit of ``fixed ~ s R moving + t`` (Umeyama 1991).

    Parameters
    ----------
    fixed, moving : ndarray, shape (N, K, 3)
        Paired points; rows with weight 0 take no part.
    weights : ndarray, shape (N, K), optional
    scale : bool
        Fit the scale ``s`` too (similarity); otherwise ``s = 1``.

    Returns
    -------
    (R (N, 3, 3), t (N, 3), s (N,))
    """
    F = np.asarray(fixed, dtype=np.float64)
    M = np.asarray(moving, dtype=np.float64)
    w = np.ones(F.shape[:2]) if weights is None else np.asarray(weights, dtype=np.float64)
    W = w.sum(axis=1)
    Wd = np.where(W > 0, W, 1.0)
    Fz, Mz = np.where(w[..., None] > 0, F, 0.0), np.where(w[..., None] > 0, M, 0.0)
    cf = np.einsum("nk,nki->ni", w, Fz) / Wd[:, None]
    cm = np.einsum("nk,nki->ni", w, Mz) / Wd[:, None]
    f0 = Fz - cf[:, None]
    m0 = Mz - cm[:, None]
    S = np.einsum("nk,nki,nkj->nij", w, f0, m0) / Wd[:, None, None]
    U, sv, Vt = np.linalg.svd(S)
    d = np.sign(np.linalg.det(U @ Vt))
    d = np.where(d == 0, 1.0, d)
    D = np.ones((len(F), 3))
    D[:, 2] = d
    R = np.einsum("nij,nj,njk->nik", U, D, Vt)
    if scale:
        var_m = np.einsum("nk,nki,nki->n", w, m0, m0) / Wd
        s = np.sum(sv * D, axis=1) / np.where(var_m > 0, var_m, np.nan)
    else:
        s = np.ones(len(F))
    t = cf - s[:, None] * np.einsum("nij,nj->ni", R, cm)
    return R, t, s


def _transform(R, t, s):
    return pose_from_rt(s[..., None, None] * R, t)


def _principal(moving):
    """Centroid, principal axes (columns) and RMS distance of the points from each axis."""
    c = moving.mean(axis=0)
    X = moving - c
    _, sv, Vt = np.linalg.svd(X, full_matrices=False)
    lam = np.zeros(3)
    lam[:len(sv)] = sv ** 2 / len(X)
    # RMS distance from axis k: the spread along the two other axes
    f2 = np.array([lam[1] + lam[2], lam[0] + lam[2], lam[0] + lam[1]])
    return c, Vt.T, f2


def predicted_tre(moving, targets, fle_rms: float) -> np.ndarray:
    """RMS target registration error at ``targets`` (M, 3) for fiducials ``moving`` (K, 3) with
    localisation error ``fle_rms`` (Fitzpatrick, West & Maurer 1998); same units as ``fle_rms``."""
    M = check_points(moving, "moving")
    T = check_points(targets, "targets").reshape(-1, 3)
    c, V, f2 = _principal(M)
    y = (T - c) @ V
    d2 = np.stack([y[:, 1] ** 2 + y[:, 2] ** 2, y[:, 0] ** 2 + y[:, 2] ** 2,
                   y[:, 0] ** 2 + y[:, 1] ** 2], axis=1)
    ratio = np.where(f2 > 0, d2 / np.where(f2 > 0, f2, 1.0), np.inf)
    return float(fle_rms) * np.sqrt((1 + ratio.sum(axis=1) / 3) / len(M))


@dataclass(frozen=True, eq=False)
class Registration(Result):
    """Result of :func:`register_points` (SI units; ``to_dict()`` gives mm and deg).

    Attributes
    ----------
    transform : ndarray, shape (4, 4)
        Maps moving points onto fixed ones: ``fixed ~ transform @ [moving; 1]`` (its 3x3 part
        is ``scale * R``).
    scale : float
        1 for a rigid fit.
    residuals : ndarray, shape (K, 3)
        ``transform(moving) - fixed`` per point (m).
    fre_rms, fre_max : float
        RMS and largest fiducial registration error (m, unweighted).
    rotation_se : ndarray, shape (3,)
        Standard error of the rotation (rotation-vector components in the fixed frame, rad).
    translation_se : ndarray, shape (3,)
        Standard error of the translation (m).
    scale_se : float
        Standard error of the scale (0 for a rigid fit).
    fle_rms : float
        Fiducial localisation error used for the TRE prediction (m): given, or estimated as
        ``FRE_rms * sqrt(K / (K - 2))``.
    targets : ndarray, shape (M, 3)
        Targets in the moving frame (m).
    tre_rms : ndarray, shape (M,)
        Predicted RMS target registration error at each target (m).
    warnings : tuple of str
        An FRE above the expected level, with its figure.
    """

    transform: np.ndarray
    scale: float
    residuals: np.ndarray
    fre_rms: float
    fre_max: float
    rotation_se: np.ndarray
    translation_se: np.ndarray
    scale_se: float
    fle_rms: float
    targets: np.ndarray
    tre_rms: np.ndarray
    warnings: tuple = ()
    _not_in_dict: ClassVar[tuple] = ("residuals",)

    @property
    def n(self) -> int:
        return len(self.residuals)

    def apply(self, points) -> np.ndarray:
        """Map points (…, 3) of the moving frame into the fixed frame."""
        p = check_points(points, "points")
        return p @ self.transform[:3, :3].T + self.transform[:3, 3]

    def _items(self) -> dict:
        from scipy.spatial.transform import Rotation

        R = self.transform[:3, :3] / self.scale
        return {"n": self.n, "scale": self.scale, "scale_se": self.scale_se,
                "fre_rms_mm": 1e3 * self.fre_rms, "fre_max_mm": 1e3 * self.fre_max,
                "residual_mm": 1e3 * self.residuals,
                "residual_distance_mm": 1e3 * np.linalg.norm(self.residuals, axis=1),
                "transform": self.transform,
                "translation_mm": 1e3 * self.transform[:3, 3],
                "rotation_vector_deg": np.rad2deg(Rotation.from_matrix(R).as_rotvec()),
                "rotation_se_deg": np.rad2deg(self.rotation_se),
                "translation_se_mm": 1e3 * self.translation_se,
                "fle_rms_mm": 1e3 * self.fle_rms, "targets_mm": 1e3 * self.targets,
                "predicted_tre_mm": 1e3 * self.tre_rms, "warnings": list(self.warnings)}


def _check_pair(fixed, moving):
    F = check_points(fixed, "fixed")
    M = check_points(moving, "moving")
    if F.ndim != 2 or M.shape != F.shape:
        raise InputError(f"expected `fixed` and `moving` of the same shape (K, 3), got "
                         f"{F.shape} and {M.shape}")
    return F, M


def register_points(fixed, moving, weights=None, *, scale: bool = False, targets=None,
                    fle_rms=None, max_fre_mm=MAX_FRE_MM) -> Registration:
    """Register paired points: the transform mapping ``moving`` onto ``fixed``.

    Parameters
    ----------
    fixed, moving : array_like, shape (K, 3)
        Paired points (m), e.g. fiducials in the image (fixed) and measured by the tracker
        (moving). Rows with a non-finite value are refused.
    weights : array_like, shape (K,), optional
        Non-negative weight per pair (e.g. inverse localisation variance).
    scale : bool
        Similarity transform (a uniform scale is fitted too).
    targets : array_like, shape (M, 3), optional
        Points of the moving frame where the TRE is predicted.
    fle_rms : float, optional
        RMS fiducial localisation error (m); default: estimated from the FRE (needs K > 3).
    max_fre_mm : float or None
        Flag (``warnings``) an FRE RMS above this (mm), and, with ``fle_rms`` given, above
        twice its expectation ``FLE sqrt(1 - 2/K)``.

    Returns
    -------
    Registration

    Examples
    --------
    >>> import numpy as np
    >>> moving = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1]])
    >>> fixed = moving + [0.01, 0.02, 0.03]
    >>> reg = register_points(fixed, moving)
    >>> np.round(reg.to_dict()["translation_mm"], 9).tolist(), round(reg.fre_rms, 12)
    ([10.0, 20.0, 30.0], 0.0)
    """
    F, M = _check_pair(fixed, moving)
    K = len(F)
    if K < MIN_POINTS:
        raise InputError(f"expected at least {MIN_POINTS} point pairs, got {K}")
    if not (np.all(np.isfinite(F)) and np.all(np.isfinite(M))):
        raise InputError("expected finite points, got NaN or infinite coordinates")
    big = max(np.abs(F).max(), np.abs(M).max())
    if big > MAX_COORDINATE:
        raise InputError(f"expected coordinates within {MAX_COORDINATE:g} m, got {big:.3g} m: "
                         f"check the length unit of the points")
    w = np.ones(K) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != (K,) or not np.all(np.isfinite(w)) or np.any(w < 0) or not np.sum(w > 0) >= 3:
        raise InputError(f"expected {K} finite weights >= 0, at least 3 of them > 0, got "
                         f"{np.shape(weights)}")
    sv = np.linalg.svd(M - M.mean(axis=0), compute_uv=False)
    if sv[1] <= 1e-9 * max(sv[0], 1e-300):
        raise InputError("expected moving points that are not all on one line, got collinear "
                         "points: the rotation about that line is undetermined")
    R, t, s = rigid_fit(F[None], M[None], w[None], scale=scale)
    R, t, s = R[0], t[0], float(s[0])
    T = _transform(R, t, np.float64(s))
    res = M @ T[:3, :3].T + T[:3, 3] - F
    # linearised covariance: r_i = s exp([w]) R m_i + t - f_i
    sRm = s * M @ R.T
    J = np.concatenate([-skew(sRm), np.broadcast_to(np.eye(3), (K, 3, 3))], axis=2)
    if scale:
        J = np.concatenate([J, (M @ R.T)[:, :, None]], axis=2)
    sw = np.sqrt(w)[:, None, None]
    n_par = J.shape[2]
    cov, _ = linear_covariance((sw * J).reshape(-1, n_par), (sw[:, :, 0] * res).reshape(-1),
                               n_par)
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    dist = np.linalg.norm(res, axis=1)
    fre = float(np.sqrt(np.mean(dist ** 2)))
    if fle_rms is None:
        fle = fre * np.sqrt(K / (K - 2)) if K > 3 else float("nan")
    else:
        fle = float(fle_rms)
        if not np.isfinite(fle) or fle < 0:
            raise InputError(f"expected a finite fle_rms >= 0, got {fle_rms!r}")
    if not (np.all(np.isfinite(T)) and np.isfinite(fre)):
        raise InputError("expected points that determine a transform, got a degenerate set "
                         "(the fit is not finite)")
    tg = np.zeros((0, 3)) if targets is None else check_points(targets, "targets").reshape(-1, 3)
    tre = predicted_tre(M, tg, fle) if len(tg) else np.zeros(0)
    warn = ()
    limit = None if max_fre_mm is None else float(max_fre_mm)
    if fle_rms is not None and limit is not None:
        limit = min(limit, 2e3 * fle * np.sqrt(max(1 - 2 / K, 0.0))) or limit
    if limit is not None and 1e3 * fre > limit:
        warn = (f"FRE RMS {1e3 * fre:.3g} mm is above the expected {limit:.3g} mm: a fiducial "
                f"was touched off its mark or paired with the wrong one; check the residual "
                f"per point",)
    return Registration(transform=T, scale=s, residuals=res, fre_rms=fre,
                        fre_max=float(dist.max()), rotation_se=se[:3],
                        translation_se=se[3:6], scale_se=float(se[6]) if scale else 0.0,
                        fle_rms=fle, targets=tg, tre_rms=tre, warnings=warn)


@dataclass(frozen=True, eq=False)
class BatchRegistration(Result):
    """Result of :func:`register_points_batch`.

    Attributes
    ----------
    poses : ndarray, shape (N, 4, 4)
        Per frame, the transform mapping the moving points onto the fixed ones (NaN where the
        frame has fewer than 3 usable pairs or collinear ones).
    scale : ndarray, shape (N,)
    fre_rms : ndarray, shape (N,)
        RMS registration error per frame (m; NaN where no pose).
    n_used : ndarray of int, shape (N,)
        Pairs used per frame (finite, weight > 0).
    """

    poses: np.ndarray
    scale: np.ndarray
    fre_rms: np.ndarray
    n_used: np.ndarray
    _not_in_dict: ClassVar[tuple] = ("poses", "scale", "fre_rms", "n_used")

    def _items(self) -> dict:
        ok = np.isfinite(self.fre_rms)
        return {"n_frames": len(self.poses), "n_failed": int((~ok).sum()),
                "fre_rms_mm": (1e3 * float(np.sqrt(np.mean(self.fre_rms[ok] ** 2)))
                               if ok.any() else float("nan"))}


def register_points_batch(fixed, moving, weights=None, *, scale: bool = False
                          ) -> BatchRegistration:
    """:func:`register_points` for N frames at once (no standard errors or TRE).

    ``fixed`` and ``moving`` are (N, K, 3) or (K, 3) (the same points in every frame, e.g. a
    tool's marker geometry). Non-finite pairs (an occluded marker) take no part; frames with
    fewer than 3 usable or collinear pairs get NaN poses (flagged per frame, never guessed).
    """
    F = check_points(fixed, "fixed")
    M = check_points(moving, "moving")
    if F.ndim == 2:
        F = F[None]
    if M.ndim == 2:
        M = M[None]
    if F.ndim != 3 or M.ndim != 3 or F.shape[1] != M.shape[1]:
        raise InputError(f"expected `fixed` and `moving` of shape (N, K, 3) or (K, 3) with "
                         f"equal K, got {np.shape(fixed)} and {np.shape(moving)}")
    n = max(len(F), len(M))
    if len(F) not in (1, n) or len(M) not in (1, n):
        raise InputError(f"expected the same number of frames, got {len(F)} and {len(M)}")
    F = np.broadcast_to(F, (n,) + F.shape[1:])
    M = np.broadcast_to(M, (n,) + M.shape[1:])
    K = F.shape[1]
    w = np.ones((n, K)) if weights is None else np.broadcast_to(
        np.asarray(weights, dtype=np.float64), (n, K))
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise InputError("expected finite weights >= 0, got negative or non-finite ones")
    use = (w > 0) & np.all(np.isfinite(F), axis=2) & np.all(np.isfinite(M), axis=2)
    w = np.where(use, w, 0.0)
    R, t, s = rigid_fit(F, M, w, scale=scale)
    T = _transform(R, t, s)
    Mz = np.where(use[..., None], M, 0.0)
    sv = np.linalg.svd(Mz - (np.einsum("nk,nki->ni", w, Mz) / np.maximum(w.sum(1), 1e-300)[:, None]
                             )[:, None] * use[..., None], compute_uv=False)
    bad = (use.sum(axis=1) < MIN_POINTS) | (sv[:, 1] <= 1e-9 * np.maximum(sv[:, 0], 1e-300)) \
        | ~np.isfinite(s)
    res = np.einsum("nij,nkj->nki", T[:, :3, :3], Mz) + T[:, None, :3, 3] - np.where(
        use[..., None], F, 0.0)
    d2 = np.where(use, np.sum(res ** 2, axis=2), 0.0)
    fre = np.sqrt(d2.sum(axis=1) / np.maximum(use.sum(axis=1), 1))
    T[bad] = np.nan
    fre[bad] = np.nan
    s = np.where(bad, np.nan, s)
    return BatchRegistration(poses=T, scale=s, fre_rms=fre, n_used=use.sum(axis=1))
