"""Reference-pose calibration: the coil model, X and Y fitted to couplings at robot or optical
tracker poses (docs/reference-calibration.md).

The sensor is fixed to a robot flange or an optical marker (unknown X), the reference's base
stands near the field generator (unknown Y), and the reference reports poses ``B_i``. With the
hand-eye convention of :func:`openemt.align.fit_axyb` (``A_i X = Y B_i``), the sensor pose in
the source frame is ``P_i = Y B_i X^-1`` and the model is ``C_i = f(model, Y B_i X^-1)``.

This is the paper's kinematic chain ``P = F_so so_J F_st st_J F_se`` (MacLachlan et al. 2025,
eq. 6) with ``so_J = I``, ``F_so = I`` (held), ``F_st = Y`` and ``st_J = B_i``,
``F_se = X^-1``, so the normalised residual, its analytic Jacobian
(:class:`~openemt.calibrate.CalibrationProblem`) and the gauge of the coil parameters
(docs/paper-procedure.md#gauge) are the calibration module's own. The free parameters are those
of the paper's XYZ mode (coil positions and moments, sensor gain, ``F_st`` = Y, ``F_se`` = X^-1).

Start: the couplings are solved with the start model (Kim18 + LM) to get ``A_i``; X and Y
follow from the hand-eye solution (Shah 2013 closed form, refined) unless the start calibration
carries them. When the reference states its noise, each row's residual is then whitened by the
covariance that noise gives it and the fit repeated (errors in variables,
:func:`errors_in_variables_whitening`). Standard errors come from the Jacobian at the solution
and the residual variance; X and Y standard errors are given for left perturbations (translation, then a small rotation
about the parent frame's axes), like :class:`openemt.align.HandEyeResult`.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from .._errors import InputError
from ..io import Calibration, Dataset
from ..solve import spectral_norms
from ._engine import fit_problem, fit_provenance, residue_block
from ._fit import check_inputs
from ._identifiability import IdentifiabilityWarning
from ._layout import ParameterLayout
from ._objective import CalibrationProblem
from ._split import holdout_split

__all__ = [
    "EIV_NOISE_FLOOR",
    "MIN_REFERENCE_POSES",
    "REFERENCE_RESIDUAL_FACTOR",
    "WEIGHTINGS",
    "XY_CONDITION_LIMIT",
    "ReferenceFit",
    "errors_in_variables_whitening",
    "fit_reference",
    "reference_block",
    "reference_errors",
    "reference_noise_covariance",
    "reference_poses",
    "reference_residuals",
    "score_reference",
    "stage_reference",
]

#: Fewest training poses of a reference calibration.
MIN_REFERENCE_POSES = 12
#: The fit is refused (``accept_residual=False``) when the fitted reference residual (3-D RMS
#: translation or RMS angle of the reference poses' misfit) exceeds the stated reference noise
#: by more than this factor: a good fit comes out near 1 (0.8-1.2 on simulated robot and optical
#: data); a reference that does not belong to the couplings (another motion, mispaired dwells,
#: another unit) comes out thousands of times over.
REFERENCE_RESIDUAL_FACTOR = 10.0
#: Condition number of the X/Y block of the column-scaled Jacobian, with the coil parameters
#: projected out, above which X and Y count as ill-determined (docs/reference-calibration.md#identifiability).
XY_CONDITION_LIMIT = 1e3
_XY_NAMES = ("Y translation", "Y rotation", "X translation", "X rotation")


def reference_block(X, Y, *, kind: str = "", noise_trans=None, noise_rot=None,
                    X_se=None, Y_se=None) -> dict:
    """The JSON block that carries X and Y in a calibration's ``extra['reference']``
    (docs/reference-calibration.md#calibration-file)."""
    out = {
        "convention": "A_i X = Y B_i; sensor pose in the source frame P_i = Y B_i X^-1",
        "kind": kind,
        "X": np.asarray(X, dtype=np.float64).tolist(),
        "Y": np.asarray(Y, dtype=np.float64).tolist(),
        "noise_trans_m": None if noise_trans is None else float(noise_trans),
        "noise_rot_rad": None if noise_rot is None else float(noise_rot),
    }
    if X_se is not None:
        out["X_se"] = np.asarray(X_se, dtype=np.float64).tolist()
        out["Y_se"] = np.asarray(Y_se, dtype=np.float64).tolist()
        out["se_units"] = "m, m, m, rad, rad, rad (translation; left rotation about parent axes)"
    return out


def reference_poses(dataset) -> tuple[np.ndarray, dict]:
    """The reference poses ``B_i`` (N, 4, 4) of a dataset and the reference description.

    They are stored like the pose datasets' references (docs/data-format.md#reference-poses):
    ``extra['reference_poses']``, with ``meta['reference']`` = ``kind``, ``noise_trans_m``
    (3-D RMS), ``noise_rot_rad`` (RMS angle) and optionally ``hemisphere``.
    """
    if not isinstance(dataset, Dataset):
        raise TypeError(f"expected an openemt.io.Dataset, got {type(dataset).__name__}")
    B = dataset.extra.get("reference_poses")
    if B is None:
        raise InputError("expected a dataset with reference poses (extra/reference_poses, "
                         "from 'openemt collect', 'openemt simulate --reference' or "
                         "openemt.calibrate.stage_reference for rig data), got none")
    B = np.asarray(B, dtype=np.float64)
    if B.shape != (dataset.n_samples, 4, 4):
        raise InputError(f"expected reference poses of shape ({dataset.n_samples}, 4, 4), got "
                         f"{B.shape}")
    Bf = np.where(np.isfinite(B), B, np.eye(4))  # non-finite rows are refused by the fit
    R = Bf[:, :3, :3]
    off = np.abs(np.swapaxes(R, 1, 2) @ R - np.eye(3)).max(axis=(1, 2), initial=0.0)
    bottom = np.abs(Bf[:, 3] - [0.0, 0.0, 0.0, 1.0]).max(axis=1, initial=0.0)
    bad = np.flatnonzero(np.all(np.isfinite(B), axis=(1, 2)) & ((off > 1e-6) | (bottom > 0)))
    if bad.size:
        raise InputError(f"expected reference poses with orthonormal rotations and a last row "
                         f"[0, 0, 0, 1], got {len(bad)} rows that are not (first: row "
                         f"{int(bad[0])})")
    info = dict(dataset.meta.get("reference") or {})
    return B, info


def stage_reference(dataset, *, source_fixture="YoutZup", sensor_fixture="YoutZup",
                    pattern="md", noise_trans=None, noise_rot=None) -> Dataset:
    """Rows of one fixture combination of a rig dataset, with the stage motion as reference.

    ``B_i = stage_transform(stage_i) S(sensor code)`` (the stage joint ``st_J``,
    docs/ilemt-data.md#ground-truth), so ``Y = F_so so_J F_st`` and ``X^-1 = F_se``. The
    reference noise defaults to the stage uncertainty (MacLachlan et al. 2025, eq. 10).
    ``pattern`` may be one pattern, several or ``None`` (every row of the combination).
    """
    from ..evaluate import STAGE_UNCERTAINTY_M, STAGE_UNCERTAINTY_RAD
    from ..geometry import stage_joint

    rows = dataset.mask(pattern=pattern, source_fixture=source_fixture,
                        sensor_fixture=sensor_fixture)
    if not rows.any():
        raise InputError(f"expected rows of source fixture {source_fixture!r}, sensor fixture "
                         f"{sensor_fixture!r}, pattern {pattern!r}, got none")
    sub = dataset.select(rows)
    B = stage_joint(sub.stage, sub.sensor_fixture)
    ref = {"kind": "stage",
           "noise_trans_m": STAGE_UNCERTAINTY_M if noise_trans is None else float(noise_trans),
           "noise_rot_rad": STAGE_UNCERTAINTY_RAD if noise_rot is None else float(noise_rot),
           "noise_definition": "stage standard uncertainty after compensation",
           "source_fixture": source_fixture, "sensor_fixture": sensor_fixture}
    return Dataset(couplings=sub.couplings, stage=sub.stage, source_fixture=sub.source_fixture,
                   sensor_fixture=sub.sensor_fixture, pattern=sub.pattern,
                   file_index=sub.file_index, files=sub.files, stage_logged=sub.stage_logged,
                   poses=sub.poses, source_signs=sub.source_signs,
                   sensor_signs=sub.sensor_signs,
                   extra={**sub.extra, "reference_poses": B},
                   meta={**sub.meta, "reference": ref})


@dataclass(frozen=True, eq=False)
class ReferenceFit:
    """Result of :func:`fit_reference`.

    Attributes
    ----------
    calibration : Calibration
        Mode ``reference``; fixtures ``source`` = 0, ``stage`` = Y, ``sensor`` = X^-1 and the
        block ``extra['reference']`` with X, Y and their standard errors.
    X, Y : ndarray, shape (4, 4)
        Reference tool -> sensor, reference frame -> source frame (m).
    X_se, Y_se : ndarray, shape (6,)
        Standard errors (m, m, m, rad, rad, rad) of left perturbations; inf if undetermined.
    covariance_xy : ndarray, shape (12, 12)
        Covariance of ``[X perturbation, Y perturbation]``.
    rms_residue : float
        ``sqrt(SSR / N)`` of the normalised coupling residuals over the training rows.
    n_train : int
    identifiability : dict
        ``rank``, ``n_free``, ``condition``, ``xy_condition``, ``undetermined`` (names from
        ``X translation``, ``X rotation``, ``Y translation``, ``Y rotation`` and coil groups),
        ``ill_conditioned`` (bool).
    warnings : list of str
    start : dict
        How X and Y were started (``hand-eye`` with its residuals, or ``calibration``).
    holdout : dict
        Held-out error (see :func:`score_reference`); empty without held-out poses.
    train, test : ndarray of int
        Row indices used for the fit and held out.
    weighting : dict
        ``method`` (``ordinary`` or ``errors-in-variables``), for the latter
        ``coupling_noise`` (the estimated noise of a normalised residual), and for both
        ``reference_residual_trans_m`` / ``reference_residual_rot_rad``: the 3-D RMS and RMS
        angle of the reference pose corrections that explain the training rows
        (:func:`reference_residuals`), to compare with the stated noise.
    seconds : float
    """

    calibration: Calibration
    X: np.ndarray
    Y: np.ndarray
    X_se: np.ndarray
    Y_se: np.ndarray
    covariance_xy: np.ndarray
    rms_residue: float
    n_train: int
    identifiability: dict
    warnings: list
    start: dict
    holdout: dict = field(default_factory=dict)
    train: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    test: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    x: np.ndarray = field(default_factory=lambda: np.zeros(0))
    free: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    layout: ParameterLayout | None = None
    weighting: dict = field(default_factory=lambda: {"method": "ordinary"})
    seconds: float = 0.0

    def summary(self) -> dict:
        """JSON-able summary (X, Y in m as 4x4; standard errors in m and rad)."""
        return {
            "X": self.X, "Y": self.Y, "X_se": self.X_se, "Y_se": self.Y_se,
            "se_units": "m, m, m, rad, rad, rad (translation; left rotation about parent axes)",
            "rms_residue": self.rms_residue, "num_points": self.n_train,
            "identifiability": dict(self.identifiability), "warnings": list(self.warnings),
            "start": dict(self.start), "holdout": dict(self.holdout),
            "weighting": dict(self.weighting), "seconds": self.seconds,
        }


def _perturbation(P, P0) -> np.ndarray:
    """Left perturbation ``[t - t0, rotvec(R R0^T)]`` that takes ``P0`` to ``P``."""
    d = np.empty(6)
    d[:3] = P[:3, 3] - P0[:3, 3]
    d[3:] = Rotation.from_matrix(P[:3, :3] @ P0[:3, :3].T).as_rotvec()
    return d


def _xy_of(v_st, v_se):
    from ..geometry import invert, pose_from_vector

    return invert(pose_from_vector(v_se)), pose_from_vector(v_st)


def _xy_covariance(v_st, v_se, cov_vec, bad) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Covariance of the X and Y perturbations from that of the fixture vectors ``[F_st, F_se]``
    (12 x 12, central differences of the map); components touched by an undetermined input
    (``bad``, (12,)) get an infinite standard error."""
    X0, Y0 = _xy_of(v_st, v_se)
    v0 = np.concatenate([v_st, v_se])
    G = np.empty((12, 12))
    h = 1e-7
    for j in range(12):
        out = []
        for s in (h, -h):
            v = v0.copy()
            v[j] += s
            X, Y = _xy_of(v[:6], v[6:])
            out.append(np.concatenate([_perturbation(X, X0), _perturbation(Y, Y0)]))
        G[:, j] = (out[0] - out[1]) / (2 * h)
    cov = G @ cov_vec @ G.T
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    touched = np.abs(G[:, bad]).sum(axis=1) > 1e-9 if np.any(bad) else np.zeros(12, bool)
    se = np.where(touched, np.inf, se)
    return cov, se[:6], se[6:]


def _hemisphere(info, hemisphere):
    if hemisphere is not None:
        return hemisphere
    h = info.get("hemisphere")
    return "+x" if h is None else (h if isinstance(h, str) else np.asarray(h, dtype=float))


def _hand_eye_start(C, B, model, hemisphere) -> tuple[np.ndarray, np.ndarray, dict]:
    from ..align import fit_axyb, reference_in_measured_frame
    from ..evaluate import pose_error_magnitudes
    from ..geometry import rotation_diversity

    res = solve_cold(model, C, hemisphere)
    ok = np.all(np.isfinite(res.pose_vectors), axis=1)
    if ok.sum() < MIN_REFERENCE_POSES:
        raise InputError(f"expected at least {MIN_REFERENCE_POSES} poses solvable with the "
                         f"start model for the hand-eye start, got {int(ok.sum())}")
    A, Bk = res.poses[ok], B[ok]
    if not rotation_diversity(Bk).ok:
        # rotations about one axis only (a stage with one rotary axis, a turntable): the
        # rotation-only closed form is degenerate; take R_Y from the translations instead
        X, Y = _translation_start(A, Bk)
        t, r = pose_error_magnitudes(A, reference_in_measured_frame(Bk, X, Y))
        return X, Y, {"method": "translations", "n_pairs": int(ok.sum()), "n_outliers": 0,
                      "residual_trans_rms_mm": float(1e3 * np.sqrt(np.mean(t ** 2))),
                      "residual_rot_rms_deg": float(np.rad2deg(np.sqrt(np.mean(r ** 2))))}
    s = fit_axyb(A, Bk, folds=0).summary()
    return s["X"], s["Y"], {"method": "hand-eye", "n_pairs": int(ok.sum()),
                        "n_outliers": s["n_outliers"],
                        "residual_trans_rms_mm": s["residual_trans_rms_mm"],
                        "residual_rot_rms_deg": s["residual_rot_rms_deg"]}


def _nearest_rotation(M) -> np.ndarray:
    U, _, Vt = np.linalg.svd(M)
    return U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt


def _translation_start(A, B, tol=0.0175) -> tuple[np.ndarray, np.ndarray]:
    """X and Y of ``A_i X = Y B_i`` when the reference rotations share one axis.

    Rows whose reference rotations agree within ``tol`` (rad) also share the measured rotation, so
    their translation differences obey ``dt_A = R_Y dt_B``: ``R_Y`` by orthogonal Procrustes
    (Kabsch), ``R_X`` as the nearest rotation to the mean of ``R_A^T R_Y R_B``, then the
    translations by minimum-norm linear least squares (the part along the common axis is not
    determined by the poses; the coupling fit needs it held, e.g. ``z_se_fix``).
    """
    from ..geometry import pose_from_rt

    n = len(A)
    group = np.full(n, -1)
    for i in range(n):
        if group[i] >= 0:
            continue
        rel = Rotation.from_matrix(np.swapaxes(B[:, :3, :3], 1, 2) @ B[i, :3, :3])
        group[(rel.magnitude() < tol) & (group < 0)] = i
    dA, dB = [], []
    for g in np.unique(group):
        rows = group == g
        if rows.sum() >= 2:
            dA.append(A[rows, :3, 3] - A[rows, :3, 3].mean(axis=0))
            dB.append(B[rows, :3, 3] - B[rows, :3, 3].mean(axis=0))
    if not dA:
        raise InputError("expected reference poses with rotations about several axes, or "
                         "several translations at one rotation, got neither")
    dA, dB = np.vstack(dA), np.vstack(dB)
    Ry = _nearest_rotation(dA.T @ dB)
    Rx = _nearest_rotation(np.einsum("kba,bc,kcd->ad", A[:, :3, :3], Ry, B[:, :3, :3]))
    M = np.zeros((3 * n, 6))
    M[:, :3] = A[:, :3, :3].reshape(3 * n, 3)
    M[:, 3:] = -np.tile(np.eye(3), (n, 1))
    d = (np.einsum("ab,kb->ka", Ry, B[:, :3, 3]) - A[:, :3, 3]).ravel()
    t = np.linalg.lstsq(M, d, rcond=None)[0]
    return pose_from_rt(Rx, t[:3]), pose_from_rt(Ry, t[3:])


def _start_xy(start, C, B, hemisphere):
    block = (start.extra or {}).get("reference") or {}
    if "X" in block and "Y" in block:
        X = np.asarray(block["X"], dtype=np.float64)
        Y = np.asarray(block["Y"], dtype=np.float64)
        if X.shape == (4, 4) and Y.shape == (4, 4):
            return X, Y, {"method": "calibration"}
    return _hand_eye_start(C, B, start.model, hemisphere)


def solve_cold(model, couplings, hemisphere):
    """Poses of ``couplings`` from no prior pose with the solver of
    :func:`openemt.solve.prepare` for ``model``, from the model's own cold start (Kim18 for a
    dipole model, coil by coil for a board's multi-coil sensor)."""
    from ..solve import prepare

    return prepare(model, initial=model.cold_start, hemisphere=hemisphere)(couplings)


def _xy_identifiability(J, free, layout, ident, groups, null_tol=1e-4) -> dict:
    """Rank and conditioning of the X/Y block: the column-scaled Jacobian of the fixture
    columns with the coil columns projected out (Schur complement)."""
    fix = np.concatenate([layout.groups["st_fix"], layout.groups["se_fix"]])
    is_fix = np.isin(free, fix)
    Js = J / np.where(np.linalg.norm(J, axis=0) > 0, np.linalg.norm(J, axis=0), 1.0)
    A, F = Js[:, ~is_fix], Js[:, is_fix]
    if A.shape[1]:
        Q, _ = np.linalg.qr(A)
        F = F - Q @ (Q.T @ F)
    s = np.linalg.svd(F, compute_uv=False) if F.shape[1] else np.zeros(0)
    cond = float(s[0] / s[-1]) if s.size and s[-1] > 1e-12 * s[0] else float("inf")
    pos = {int(k): i for i, k in enumerate(free)}
    undetermined = []
    blocks = (("Y translation", layout.groups["st_fix_trans"]),
              ("Y rotation", layout.groups["st_fix_rot"]),
              ("X translation", layout.groups["se_fix_trans"]),
              ("X rotation", layout.groups["se_fix_rot"]))
    for name, idx in blocks:
        cols = [pos[int(k)] for k in idx if int(k) in pos]
        if cols and np.any(ident.null_weight[cols] > null_tol):
            undetermined.append(name)
    for g in groups:
        if g.endswith("_fix"):
            continue
        cols = [pos[int(k)] for k in layout.groups[g] if int(k) in pos]
        if cols and np.any(ident.null_weight[cols] > null_tol):
            undetermined.append(g)
    return {"rank": ident.rank, "n_free": ident.n_free,
            "condition": float(ident.condition) if np.isfinite(ident.condition) else None,
            "xy_condition": cond if np.isfinite(cond) else None,
            "undetermined": undetermined,
            "ill_conditioned": bool(undetermined) or not cond < XY_CONDITION_LIMIT}


#: Weightings of the reference fit's rows (docs/reference-calibration.md#errors-in-variables).
WEIGHTINGS = ("auto", "errors-in-variables", "ordinary")
#: Whitened fits after the ordinary one.
EIV_PASSES = 2


def reference_noise_covariance(info) -> np.ndarray | None:
    """Covariance ``(6, 6)`` of a reference pose's noise ``(dt, dphi)`` in the tool frame, from
    the stated 3-D RMS translation ``noise_trans_m`` and RMS angle ``noise_rot_rad`` of
    ``meta['reference']`` (each axis gets sigma^2 / 3); None when no noise is stated."""
    st, sr = info.get("noise_trans_m"), info.get("noise_rot_rad")
    if st is None or sr is None:
        return None
    st, sr = float(st), float(sr)
    if not (np.isfinite(st) and np.isfinite(sr) and st >= 0 and sr >= 0 and st + sr > 0):
        return None
    return np.diag([st ** 2 / 3] * 3 + [sr ** 2 / 3] * 3)


def _weighting(weighting, info) -> tuple[str, np.ndarray | None]:
    if weighting not in WEIGHTINGS:
        raise InputError(f"expected weighting in {', '.join(WEIGHTINGS)}, got {weighting!r}")
    S = reference_noise_covariance(info)
    if weighting == "ordinary" or (weighting == "auto" and S is None):
        return "ordinary", None
    if S is None:
        raise InputError("expected a dataset that states its reference noise "
                         "(meta['reference'] noise_trans_m and noise_rot_rad, e.g. collect's "
                         "--reference-noise-mm/--reference-noise-deg) for the "
                         "errors-in-variables weighting, got none")
    return "errors-in-variables", S


def reference_residuals(prob, x) -> np.ndarray:
    """Per-row reference pose corrections ``(N, 6)``, ``(dt, dphi)`` in the tool frame: the
    least-squares change of each ``B_i`` that explains row i's residual at ``x`` to first
    order (``G_i^+ r_i``, :meth:`CalibrationProblem.pose_gradient`). Their RMS is what the
    fit says the reference's noise is, to compare with the stated noise."""
    r, G = prob.pose_gradient(x)
    return -np.einsum("kab,kb->ka", np.linalg.pinv(G), r)


#: Smallest coupling noise (standard deviation of a normalised residual) of the
#: errors-in-variables weighting: keeps the row covariance invertible when the couplings are
#: exact (a simulation without coupling noise).
EIV_NOISE_FLOOR = 1e-8


def errors_in_variables_whitening(prob, x, S, *, n_free: int = 0):
    """Per-row whitening of the normalised residuals for reference poses with noise.

    A reference pose error ``d`` (covariance ``S``) moves row i's residual by ``G_i d``, so the
    residual's covariance is ``Sigma_i = G_i S G_i^T + s^2 I`` with ``s^2`` the coupling noise
    (the first-order marginal of the errors-in-variables likelihood; Deming 1943, Williamson
    1968). ``s^2`` is estimated from the residual left after projecting out each row's pose
    directions (``m - 6`` per row), floored at :data:`EIV_NOISE_FLOOR`. Returns the whitening
    ``L_i^-1`` (``Sigma_i = L_i L_i^T``, shape (N, m, m)) and ``{"coupling_noise": s}``.
    """
    r, G = prob.pose_gradient(x)
    n, m = r.shape
    k = min(6, m)
    Q = np.linalg.qr(G)[0][:, :, :k]
    perp = r - np.einsum("kab,kb->ka", Q, np.einsum("kab,ka->kb", Q, r))
    dof = n * (m - k) - n_free
    s2 = float(np.sum(perp ** 2) / dof) if dof > 0 else 0.0
    s2 = max(s2, EIV_NOISE_FLOOR ** 2)
    Sigma = G @ S @ np.swapaxes(G, 1, 2) + s2 * np.eye(m)
    L = np.linalg.cholesky(Sigma)
    W = np.linalg.inv(L)
    return W, {"coupling_noise": float(np.sqrt(s2))}


def _row_covariance(J, r, n_rows, ident) -> tuple[np.ndarray, np.ndarray]:
    """Parameter covariance robust to errors shared by the entries of a row (sandwich
    estimator with rows as clusters, White 1980; Liang and Zeger 1986).

    A reference pose error moves all ``n_so x n_se`` couplings of its row together, so the
    residuals are not independent within a row and ``s^2 (J^T J)^-1`` misstates the spread:
    ``cov = (J^T J)^+ (sum_i g_i g_i^T) (J^T J)^+ m / (m - rank)`` with ``g_i = J_i^T r_i``
    summed over row i. Undetermined parameters keep an infinite standard error.
    """
    m, p = J.shape
    bread = ident.covariance / ident.sigma2 if ident.sigma2 > 0 else ident.covariance
    g = (J.reshape(n_rows, -1, p) * r.reshape(n_rows, -1, 1)).sum(axis=1)
    cov = bread @ (g.T @ g) @ bread * (m / max(m - ident.rank, 1))
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return cov, np.where(np.isfinite(ident.standard_errors), se, np.inf)


def reference_errors(calibration, couplings, B, *, X=None, Y=None):
    """Per-pose errors of a calibration against reference poses: ``(trans (N,) m, rot (N,)
    rad, solve result)``, as :func:`score_reference` computes them (solved from no prior pose,
    hemisphere from the truth ``Y B_i X^-1``; X, Y from the calibration's reference block
    unless given)."""
    from ..align import reference_in_measured_frame
    from ..evaluate import pose_error_magnitudes
    from ..solve import hemisphere_from_positions

    block = (calibration.extra or {}).get("reference") or {}
    X = np.asarray(block.get("X") if X is None else X, dtype=np.float64)
    Y = np.asarray(block.get("Y") if Y is None else Y, dtype=np.float64)
    if X.shape != (4, 4) or Y.shape != (4, 4):
        raise InputError("expected X and Y (4, 4), from the calibration's reference block or "
                         "given, got none")
    D = reference_in_measured_frame(B, X, Y)
    res = solve_cold(calibration.model, couplings, hemisphere_from_positions(D[:, :3, 3]))
    trans, rot = pose_error_magnitudes(res.poses, D)
    return trans, rot, res


def score_reference(calibration, couplings, B, *, X=None, Y=None, noise_trans=None,
                    noise_rot=None) -> dict:
    """Solve couplings with a calibration and compare with the reference, as the paper's
    Table II (docs/paper-procedure.md#test-error, eq. 10).

    The truth of row i is ``Y B_i X^-1`` (X, Y from ``calibration.extra['reference']`` unless
    given); poses are solved by the LM solver from the Kim18 start, hemisphere from the truth.
    The error is ``E = M^-1 (Y B X^-1)``: translation magnitude (mm) and rotation angle (deg).

    Returns
    -------
    dict
        ``n``, ``trans_rms_mm``, ``trans_max_mm``, ``rot_rms_deg``, ``rot_max_deg``,
        ``n_not_converged``, and with a stated reference noise ``reference_noise_mm``,
        ``reference_noise_deg``, ``trans_uncert_mm``, ``rot_uncert_deg`` (eq. 10).
    """
    from ..evaluate import combined_uncertainty, error_summary
    from ..solve import Status

    trans, rot, res = reference_errors(calibration, couplings, B, X=X, Y=Y)
    s = error_summary(trans, rot)
    out = {"n": s["n"], "trans_rms_mm": s["trans_rms_mm"], "trans_max_mm": s["trans_max_mm"],
           "rot_rms_deg": s["rot_rms_deg"], "rot_max_deg": s["rot_max_deg"],
           "n_not_converged": int(np.sum(res.status != Status.CONVERGED))}
    if noise_trans is not None:
        out["reference_noise_mm"] = 1e3 * float(noise_trans)
        out["trans_uncert_mm"] = float(combined_uncertainty(s["trans_rms_mm"],
                                                            1e3 * float(noise_trans)))
    if noise_rot is not None:
        out["reference_noise_deg"] = float(np.rad2deg(noise_rot))
        out["rot_uncert_deg"] = float(combined_uncertainty(s["rot_rms_deg"],
                                                          float(np.rad2deg(noise_rot))))
    return out


def _split(B, holdout, seed):
    """Training and held-out rows (:func:`~openemt.calibrate.holdout_split`; ``location``
    blocks by the reference's positions)."""
    test = holdout_split(holdout, len(B), points=B[:, :3, 3], seed=seed,
                         min_train=MIN_REFERENCE_POSES, what="poses")
    return np.flatnonzero(~test), np.flatnonzero(test)


def fit_reference(dataset, start, *, hemisphere=None, freeze=(), holdout: float = 0.0,
                  seed: int = 0, weighting: str = "auto", max_nfev: int = 200,
                  tol: float = 1e-12, warn: bool = True,
                  accept_residual: bool = False) -> ReferenceFit:
    """Fit the coil model, X and Y to couplings measured at reference poses.

    Parameters
    ----------
    dataset : Dataset
        Couplings with reference poses ``extra['reference_poses']`` (:func:`reference_poses`).
    start : Calibration
        Start model (gauge of docs/paper-procedure.md#gauge); its ``extra['reference']`` X and
        Y when present, else the hand-eye start.
    hemisphere : str or (3,), optional
        Hemisphere of the sensor for the start solve; default ``meta['reference']
        ['hemisphere']`` or ``'+x'``.
    freeze : sequence of str
        Further parameter groups to hold (layout names: ``st_fix`` is Y, ``se_fix`` is X^-1,
        e.g. ``z_se_fix`` holds X^-1's z translation, the gauge of rotations about one axis).
    holdout : float or str
        Fraction of poses held out at random (``seed``), or ``'location'`` (regions of the
        volume, :func:`~openemt.calibrate.holdout_split`), scored by :func:`score_reference`
        with the calibration fitted on the others.
    weighting : {'auto', 'errors-in-variables', 'ordinary'}
        How rows are weighted. ``ordinary``: the paper's normalised residual, every entry alike.
        ``errors-in-variables``: each row's residual whitened by the covariance the stated
        reference noise gives it (:func:`errors_in_variables_whitening`; needs
        ``noise_trans_m`` and ``noise_rot_rad`` in ``meta['reference']``). ``auto`` (default):
        errors-in-variables when the dataset states its reference noise, else ordinary.
    max_nfev, tol : passed to ``scipy.optimize.least_squares``.
    warn : bool
        Warn (:class:`IdentifiabilityWarning`) when X, Y or a coil group is undetermined or
        the X/Y block is ill-conditioned (e.g. too little rotation diversity).
    accept_residual : bool
        Return the fit even when its reference residual exceeds the stated reference noise
        more than :data:`REFERENCE_RESIDUAL_FACTOR` times (else :class:`InputError`; not
        checked when X or Y is undetermined, which the warning says).

    Returns
    -------
    ReferenceFit
    """
    from ..geometry import vector_from_pose

    check_inputs(dataset, start)
    B_all, info = reference_poses(dataset)
    method, S = _weighting(weighting, info)
    C_all = dataset.signed_real()
    ok = np.all(np.isfinite(B_all), axis=(1, 2)) & np.all(np.isfinite(C_all), axis=(1, 2))
    if not ok.all():
        raise InputError(f"expected finite couplings and reference poses, got "
                         f"{int((~ok).sum())} rows with NaN or inf")
    t0 = time.perf_counter()
    train, test = _split(np.where(np.isfinite(B_all), B_all, 0.0), holdout, seed)
    C, B = C_all[train], B_all[train]
    hemi = _hemisphere(info, hemisphere)
    X0, Y0, start_info = _start_xy(start, dataset.couplings[train], B, hemi)

    layout = ParameterLayout.for_model(start.model)
    n = len(train)
    so_J = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    norms = spectral_norms(C)
    if np.any(norms <= 0):
        raise InputError("expected non-zero coupling matrices, got zero rows")
    prob = CalibrationProblem(layout=layout, C_meas=C, weight=1.0 / norms, so_J=so_J,
                              st_J=np.ascontiguousarray(B),
                              gain=getattr(layout.template, "gain", None))
    from ..geometry import invert

    x0 = layout.pack(start.model, np.zeros(6), vector_from_pose(Y0),
                     vector_from_pose(invert(X0)))
    # the model's default groups (the paper's XYZ mode for a dipole model) with X and Y
    optimize = tuple(start.model.fit_groups) + ("st_fix", "se_fix")
    frz = tuple(start.model.fixed_groups) + tuple(freeze)
    free = layout.free_indices(optimize, frz)

    groups = [g for g in optimize if g not in frz]
    # the standard errors and identifiability come from the last fit only
    passes = 0 if S is None else EIV_PASSES
    f = fit_problem(prob, x0, free, groups, tol=tol, max_nfev=max_nfev,
                    uncertainty=passes == 0, warn=False)
    weighting_out = {"method": method}
    # whiten at the ordinary fit's solution, then once more at the weighted one (the
    # coupling noise re-estimated without the pose noise's leverage)
    for k in range(passes):
        W, noise = errors_in_variables_whitening(prob, f.x, S, n_free=free.size)
        f = fit_problem(prob.with_whitening(W), f.x, free, groups, tol=tol,
                        max_nfev=max_nfev, uncertainty=k == passes - 1, warn=False)
        weighting_out = {"method": method, **noise}
    x, r, J, ident = f.x, f.residuals, f.jacobian, f.identifiability
    xy = _xy_identifiability(J[:, free], free, layout, ident, optimize)
    messages = []
    if xy["undetermined"]:
        messages.append(f"the reference poses cannot determine {', '.join(xy['undetermined'])} "
                        f"(Jacobian rank {ident.rank} of {ident.n_free}); add poses rotated "
                        f"about other axes, or hold the undetermined part")
    elif xy["ill_conditioned"]:
        messages.append(f"X and Y are poorly determined by the reference poses (condition "
                        f"{xy['xy_condition']:.3g} of the X/Y block, limit "
                        f"{XY_CONDITION_LIMIT:g}); add poses with larger rotations about "
                        f"several axes")
    if warn:
        for m in messages:
            warnings.warn(m, IdentifiabilityWarning, stacklevel=2)

    cov_free, se_free = _row_covariance(J[:, free], r, n, ident)
    se_full = np.zeros(layout.size)
    se_full[free] = se_free
    fix_idx = np.concatenate([layout.groups["st_fix"], layout.groups["se_fix"]])
    pos = {int(k): i for i, k in enumerate(free)}
    cov_vec = np.zeros((12, 12))
    bad = np.zeros(12, dtype=bool)
    for a, ka in enumerate(fix_idx):
        if int(ka) not in pos:
            continue
        bad[a] = not np.isfinite(se_free[pos[int(ka)]])
        for b, kb in enumerate(fix_idx):
            if int(kb) in pos:
                cov_vec[a, b] = cov_free[pos[int(ka)], pos[int(kb)]]
    _, F_st, F_se = layout.fixtures(x)
    X, Y = _xy_of(F_st, F_se)
    cov_xy, X_se, Y_se = _xy_covariance(F_st, F_se, cov_vec, bad)
    seconds = time.perf_counter() - t0

    # the paper's rms_residue (normalised, not whitened) whatever the weighting
    plain = residue_block(prob.residuals(x), n)
    d = reference_residuals(prob, x)
    t, a = np.linalg.norm(d[:, :3], axis=1), np.linalg.norm(d[:, 3:], axis=1)
    weighting_out["reference_residual_trans_m"] = float(np.sqrt(np.mean(t ** 2)))
    weighting_out["reference_residual_rot_rad"] = float(np.sqrt(np.mean(a ** 2)))
    if not accept_residual and not xy["undetermined"]:    # (undetermined: warned above;
        _check_residual(weighting_out, info)            # its residual has no meaning)
    rms = plain["rms_residue"]
    stats = {**f.stats, **plain, "weighting": weighting_out, "fit_seconds": seconds,
             "xy_condition": xy["xy_condition"],
             "undetermined_groups": list(xy["undetermined"])}
    provenance = fit_provenance(
        "reference", dataset, train, held_out_rows=test.tolist(), holdout=holdout,
        seed=int(seed),
        start={"mode": start.mode, "file": start.provenance.get("file"),
               "xy": start_info["method"]})
    block = _reference_block(X, Y, info, X_se, Y_se)
    cal = Calibration(model=layout.model(x), source_fixture=np.zeros(6),
                      stage_fixture=F_st, sensor_fixture=F_se, mode="reference",
                      free=tuple(groups), frozen=frz,
                      standard_errors=layout.as_fields(se_full), stats=stats,
                      provenance=provenance, extra={"reference": block})
    holdout_out = {}
    if test.size:
        holdout_out = score_reference(cal, dataset.couplings[test], B_all[test],
                                      noise_trans=info.get("noise_trans_m"),
                                      noise_rot=info.get("noise_rot_rad"))
        cal = cal.replace(stats={**stats, "holdout": holdout_out})
    return ReferenceFit(calibration=cal, X=X, Y=Y, X_se=X_se, Y_se=Y_se, covariance_xy=cov_xy,
                        rms_residue=rms, n_train=int(n), identifiability=xy,
                        warnings=messages, start=start_info, holdout=holdout_out, train=train,
                        test=test, x=x, free=free, layout=layout, weighting=weighting_out,
                        seconds=time.perf_counter() - t0)


def _check_residual(w, info) -> None:
    """InputError when the fitted reference residual is many times the stated noise."""
    for key, stated, unit, scale in (("reference_residual_trans_m", "noise_trans_m", "mm", 1e3),
                                     ("reference_residual_rot_rad", "noise_rot_rad", "deg",
                                      float(np.rad2deg(1.0)))):
        s = info.get(stated)
        if s is not None and s > 0 and not w[key] <= REFERENCE_RESIDUAL_FACTOR * s:
            raise InputError(
                f"expected a fitted reference residual within {REFERENCE_RESIDUAL_FACTOR:g} "
                f"times the stated reference noise ({scale * s:.4g} {unit}), got "
                f"{scale * w[key]:.4g} {unit} RMS: reference poses that do not belong to the "
                f"couplings (another motion, mispaired dwells, another unit) or a noise stated "
                f"too low (--accept-reference-residual keeps the fit)")


def _reference_block(X, Y, info, X_se, Y_se) -> dict:
    return reference_block(X, Y, kind=str(info.get("kind", "")),
                           noise_trans=info.get("noise_trans_m"),
                           noise_rot=info.get("noise_rot_rad"), X_se=X_se, Y_se=Y_se)
