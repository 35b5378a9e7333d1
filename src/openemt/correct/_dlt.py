"""Projective (DLT) position correction (docs/paper-procedure.md#applying-correction, docs/paper-procedure.md#output-correction).

A 4x4 homogeneous matrix ``L`` maps a measured position ``m`` to the corrected position
``q[:3] / q[3]`` with ``q = L @ [m, 1]``. ``fit_dlt`` compares three candidates (identity,
least-squares affine, direct linear transformation), refines the best one over all 16 entries
with bounded least squares and keeps the refinement if it lowers the error.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from .._errors import InputError
from ..geometry import check_points

__all__ = [
    "DltFit",
    "apply_linear_correction",
    "fit_dlt",
    "linear_correction_rms",
]

#: Bounds on every entry of L during the refinement (docs/paper-procedure.md#output-correction, step 3).
REFINE_BOUND = 10.0


def _check_matrix(L) -> np.ndarray:
    arr = np.asarray(L)
    if arr.dtype.kind not in "iuf":
        raise TypeError(f"expected `L` to be real numbers, got dtype {arr.dtype}")
    if arr.shape != (4, 4):
        raise InputError(f"expected `L` to have shape (4, 4), got {arr.shape}")
    return arr.astype(np.float64, copy=False)


def _float_or_nan(x) -> float:
    return float("nan") if x is None else float(x)


def _apply(L: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    q = xyz @ L[:3, :3].T + L[:3, 3]
    w = xyz @ L[3, :3] + L[3, 3]
    return q / w[..., None]


def apply_linear_correction(L, xyz) -> np.ndarray:
    """Apply a homogeneous 4x4 correction to positions (docs/paper-procedure.md#applying-correction).

    Parameters
    ----------
    L : array_like, shape (4, 4)
        Homogeneous correction matrix (any scale).
    xyz : array_like, shape (..., 3)
        Positions (m). The input rank is kept.

    Returns
    -------
    ndarray, shape (..., 3)
        ``q[:3] / q[3]`` with ``q = L @ [x, y, z, 1]``. Orientation is not touched.
    """
    return _apply(_check_matrix(L), check_points(xyz))


def _rms(L: np.ndarray, m: np.ndarray, d: np.ndarray) -> float:
    e = _apply(L, m) - d
    return float(np.sqrt(np.mean(np.sum(e * e, axis=-1))))


def linear_correction_rms(L, measured_xyz, reference_xyz) -> float:
    """RMS over points of ``|L m / (L m)[3] - d|`` (metres if the inputs are metres)."""
    m = check_points(measured_xyz, "measured_xyz").reshape(-1, 3)
    d = check_points(reference_xyz, "reference_xyz").reshape(-1, 3)
    if m.shape != d.shape:
        raise InputError(f"expected `reference_xyz` of shape {m.shape}, got {d.shape}")
    return _rms(_check_matrix(L), m, d)


def _pinv_candidate(m: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Least-squares affine map: ``L = (pinv(M^T) D^T)^T`` with M, D the 4 x k stacks."""
    M = np.vstack([m.T, np.ones(len(m))])
    D = np.vstack([d.T, np.ones(len(d))])
    return (np.linalg.pinv(M.T) @ D.T).T


def _dlt_candidate(m: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Direct linear transformation (Sutherland 1974), as described in docs/paper-procedure.md#output-correction.

    For point k and output row j, the 4x4 matrix E has row j = m_k^T and row 3 =
    -(d_k[j] / d_k[3]) m_k^T; ``vec(E) . vec(L) = 0`` for the exact L. The column-major
    flattened E are the columns of A (16 x 3k); L is the eigenvector of A A^T with the
    smallest eigenvalue, scaled to unit spectral norm and a positive L[0, 0].
    """
    k = len(m)
    mh = np.hstack([m, np.ones((k, 1))])
    dh = np.hstack([d, np.ones((k, 1))])
    E = np.zeros((k, 3, 4, 4))
    for j in range(3):
        E[:, j, j, :] = mh
        E[:, j, 3, :] = -(dh[:, j] / dh[:, 3])[:, None] * mh
    # column-major flattening of each 4x4 E: index = col * 4 + row
    A = np.swapaxes(E, -1, -2).reshape(3 * k, 16).T
    w, V = np.linalg.eigh(A @ A.T)
    L = V[:, np.argmin(w)].reshape(4, 4, order="F")
    L = L / np.linalg.norm(L, 2)
    s = np.sign(L[0, 0])
    return L * (s if s != 0 else 1.0)


@dataclass(frozen=True)
class DltFit:
    """Result of :func:`fit_dlt`.

    Attributes
    ----------
    matrix : ndarray, shape (4, 4)
        The correction L (homogeneous; only its action matters).
    rms_uncorrected : float
        RMS error of the identity (no correction), in the units of the input (m).
    rms_corrected : float
        RMS error after applying ``matrix``.
    method : str
        Candidate that was best before refinement: ``"none"``, ``"pinv"`` or ``"dlt"``.
    refined : bool
        True if the bounded least-squares refinement improved the best candidate and was kept.
    candidates : dict
        RMS error of every candidate (``none``, ``pinv``, ``dlt``) and of the refinement.
    n_points : int
    """

    matrix: np.ndarray
    rms_uncorrected: float
    rms_corrected: float
    method: str
    refined: bool = False
    candidates: dict = field(default_factory=dict)
    n_points: int = 0

    def apply(self, xyz) -> np.ndarray:
        """Corrected positions, shape of ``xyz``."""
        return apply_linear_correction(self.matrix, xyz)

    def predict(self, xyz, R=None):
        """Corrected positions (N, 3); rotations are returned unchanged (position-only)."""
        return _apply(self.matrix, np.asarray(xyz, dtype=np.float64)), R

    def to_params(self) -> dict:
        return {"matrix": self.matrix, "rms_uncorrected": self.rms_uncorrected,
                "rms_corrected": self.rms_corrected, "method": self.method,
                "refined": self.refined, "candidates": self.candidates,
                "n_points": self.n_points}

    @classmethod
    def from_params(cls, p: dict) -> DltFit:
        return cls(matrix=_check_matrix(p["matrix"]),
                   rms_uncorrected=_float_or_nan(p.get("rms_uncorrected")),
                   rms_corrected=_float_or_nan(p.get("rms_corrected")),
                   method=str(p.get("method", "dlt")), refined=bool(p.get("refined", False)),
                   candidates=dict(p.get("candidates") or {}),
                   n_points=int(p.get("n_points", 0)))


def fit_dlt(measured_xyz, reference_xyz, *, refine: bool = True) -> DltFit:
    """Fit a projective position correction (docs/paper-procedure.md#output-correction, steps 2-4).

    Parameters
    ----------
    measured_xyz : array_like, shape (N, 3)
        Solved (measured) positions, m. N >= 5 (the DLT has 15 degrees of freedom and each
        point gives 3 equations).
    reference_xyz : array_like, shape (N, 3)
        Ground-truth positions, m.
    refine : bool
        Refine the best candidate over all 16 entries with bounded least squares (bounds
        +-10) and keep the result if better (default, as the reference procedure does).

    Returns
    -------
    DltFit

    References
    ----------
    Sutherland, "Three-dimensional data input by tablet", Proc. IEEE 62(4), 1974.
    MacLachlan et al. 2025, output correction.
    """
    m = check_points(measured_xyz, "measured_xyz")
    d = check_points(reference_xyz, "reference_xyz")
    if m.ndim != 2:
        raise InputError(f"expected `measured_xyz` to have shape (N, 3), got {m.shape}")
    if d.shape != m.shape:
        raise InputError(f"expected `reference_xyz` of shape {m.shape}, got {d.shape}")
    if len(m) < 5:
        raise InputError(f"expected at least 5 point pairs for a DLT fit, got {len(m)}")
    if not (np.all(np.isfinite(m)) and np.all(np.isfinite(d))):
        raise InputError("expected finite positions, got NaN or inf (drop invalid solves first)")

    cands = {"none": np.eye(4), "pinv": _pinv_candidate(m, d), "dlt": _dlt_candidate(m, d)}
    errs = {name: _rms(L, m, d) for name, L in cands.items()}
    errs = {k: (v if np.isfinite(v) else np.inf) for k, v in errs.items()}
    best = min(errs, key=errs.get)
    L, err = cands[best], errs[best]
    refined = False
    if refine:
        x0 = L.ravel()
        if np.max(np.abs(x0)) >= REFINE_BOUND:
            # L is homogeneous: rescaling leaves the error unchanged and brings x0 in bounds
            x0 = x0 / np.linalg.norm(L, 2)

        def resid(x):
            return (_apply(x.reshape(4, 4), m) - d).ravel()

        sol = least_squares(resid, x0, bounds=(-REFINE_BOUND, REFINE_BOUND), method="trf",
                            x_scale="jac", ftol=1e-12, xtol=1e-12, gtol=1e-12, max_nfev=2000)
        L_ref = sol.x.reshape(4, 4)
        err_ref = _rms(L_ref, m, d)
        errs["refined"] = err_ref
        if np.isfinite(err_ref) and err_ref < err:
            L, err, refined = L_ref, err_ref, True
    return DltFit(matrix=np.array(L), rms_uncorrected=errs["none"], rms_corrected=float(err),
                  method=best, refined=refined, candidates={k: float(v) for k, v in errs.items()},
                  n_points=len(m))
