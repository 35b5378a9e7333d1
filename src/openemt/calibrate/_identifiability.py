"""Identifiability of a calibration: Jacobian rank and condition, covariance, standard errors.

At the solution the Jacobian ``J`` of the normalised residuals over the free parameters is
column-scaled (each column to unit norm) so that the condition number does not depend on units.
Its SVD gives the numerical rank; right singular vectors with singular values below
``rtol * s_max`` span directions the data cannot determine. A free parameter with a noticeable
component in that null space gets an infinite standard error, and its group is reported as
undetermined (for example ``so_fix`` and ``st_fix`` when only one source fixture was used: the
data see only their product).

The covariance is the Gauss-Newton estimate ``s^2 (J^T J)^+`` with ``s^2 = SSR / (m - rank)``.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from ._layout import ParameterLayout

__all__ = ["Identifiability", "IdentifiabilityWarning", "analyse_identifiability"]


class IdentifiabilityWarning(UserWarning):
    """The data cannot determine some free parameter group."""


@dataclass(frozen=True, eq=False)
class Identifiability:
    """Rank, conditioning and uncertainty of the free parameters at a solution.

    Attributes
    ----------
    n_free : int
        Number of free parameters.
    rank : int
        Numerical rank of the column-scaled Jacobian.
    condition : float
        Ratio of largest to smallest singular value of the column-scaled Jacobian (inf when
        rank deficient).
    singular_values : ndarray, shape (n_free,)
        Singular values of the column-scaled Jacobian, descending.
    covariance : ndarray, shape (n_free, n_free)
        Parameter covariance (pseudo-inverse on the determined subspace).
    standard_errors : ndarray, shape (n_free,)
        Square roots of the covariance diagonal; inf for undetermined parameters.
    null_weight : ndarray, shape (n_free,)
        Squared norm of each parameter's component in the numerical null space (0..1).
    undetermined : tuple of str
        Free groups with at least one undetermined parameter.
    sigma2 : float
        Residual variance estimate ``SSR / (m - rank)``.
    """

    n_free: int
    rank: int
    condition: float
    singular_values: np.ndarray
    covariance: np.ndarray
    standard_errors: np.ndarray
    null_weight: np.ndarray
    undetermined: tuple[str, ...]
    sigma2: float

    def to_dict(self) -> dict:
        """JSON-ready summary (no arrays)."""
        return {"n_free": self.n_free, "rank": self.rank,
                "condition": float(self.condition) if np.isfinite(self.condition) else None,
                "undetermined_groups": list(self.undetermined), "sigma2": self.sigma2}


def analyse_identifiability(J, residuals, free, layout: ParameterLayout, groups=(),
                            rtol: float = 1e-9, null_tol: float = 1e-4, warn: bool = True
                            ) -> Identifiability:
    """Analyse the Jacobian ``J (m, n_free)`` of the free parameters ``free`` (full indices).

    Parameters
    ----------
    J : ndarray, shape (m, n_free)
    residuals : ndarray, shape (m,)
    free : ndarray of int, shape (n_free,)
        Full-vector indices of the columns of ``J``.
    layout : ParameterLayout
    groups : sequence of str
        Free group names to check (those of the mode's ``optimize``).
    rtol : float
        Relative singular-value threshold of the numerical rank.
    null_tol : float
        Null-space weight above which a parameter counts as undetermined.
    warn : bool
        Emit an :class:`IdentifiabilityWarning` naming the undetermined groups.
    """
    J = np.asarray(J, dtype=np.float64)
    r = np.asarray(residuals, dtype=np.float64)
    m, n = J.shape
    scale = np.linalg.norm(J, axis=0)
    zero_col = scale == 0.0
    scale = np.where(zero_col, 1.0, scale)
    # the SVD of the triangular factor has the same singular values and right vectors as J's
    R = np.linalg.qr(J / scale, mode="r") if m > n else J / scale
    _, s, Vt = np.linalg.svd(R, full_matrices=False)
    smax = s[0] if s.size else 0.0
    keep = s > rtol * smax
    rank = int(keep.sum())
    cond = float(smax / s[-1]) if rank == n and n else float("inf")
    V = Vt.T
    null_weight = np.sum(V[:, ~keep] ** 2, axis=1)
    null_weight[zero_col] = 1.0
    dof = max(m - rank, 1)
    sigma2 = float(r @ r / dof)
    Vk = V[:, keep] / s[keep]
    cov_scaled = sigma2 * (Vk @ Vk.T)
    cov = cov_scaled / np.outer(scale, scale)
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    bad = null_weight > null_tol
    se = np.where(bad, np.inf, se)
    pos = {int(k): i for i, k in enumerate(free)}
    undetermined = []
    for g in groups:
        idx = [pos[int(k)] for k in layout.groups[g] if int(k) in pos]
        if idx and np.any(bad[idx]):
            undetermined.append(g)
    if warn and undetermined:
        warnings.warn(f"the data cannot determine the free parameter groups {undetermined} "
                      f"(Jacobian rank {rank} of {n}); freeze them or add data that moves them",
                      IdentifiabilityWarning, stacklevel=3)
    return Identifiability(n_free=n, rank=rank, condition=cond, singular_values=s,
                           covariance=cov, standard_errors=se, null_weight=null_weight,
                           undetermined=tuple(undetermined), sigma2=sigma2)
