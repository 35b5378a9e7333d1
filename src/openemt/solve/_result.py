"""Per-sample solver status codes and the batched solve result."""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from .._errors import InputError

__all__ = ["SolveResult", "Status"]


class Status(IntEnum):
    """Outcome of one sample's pose solution.

    CONVERGED
        The solver converged and the normalised residual is below the validity threshold.
    MAX_ITERATIONS
        The iteration limit was reached before the convergence tests held.
    INVALID_INPUT
        The coupling matrix is NaN/inf, zero or rank deficient; the pose is NaN.
    AMBIGUOUS
        The position lies (numerically) on the hemisphere boundary, so the +/- dipole
        ambiguity could not be resolved; the pose returned is one of the two candidates.
    OUT_OF_VOLUME
        The solution lies on or beyond the allowed position box.
    NOT_CONVERGED
        The solver stopped (converged or stalled) but the residual is above the validity
        threshold (ILEMT's "invalid" solutions, docs/paper-procedure.md#iterative-solution).
    """

    CONVERGED = 0
    MAX_ITERATIONS = 1
    INVALID_INPUT = 2
    AMBIGUOUS = 3
    OUT_OF_VOLUME = 4
    NOT_CONVERGED = 5


@dataclass(frozen=True, eq=False)
class SolveResult:
    """Poses solved from a batch of coupling matrices.

    Attributes
    ----------
    poses : ndarray, shape (N, 4, 4)
        Sensor poses in the source frame (NaN where ``status == INVALID_INPUT``).
    pose_vectors : ndarray, shape (N, 6)
        The same as ``[x, y, z, rx, ry, rz]`` with rotation angle in [0, pi].
    status : ndarray of int8, shape (N,)
        :class:`Status` code of each sample.
    residual : ndarray, shape (N,)
        Sum of squared coupling residuals divided by the spectral norm of the measured coupling
        matrix (ILEMT's ``resnorm``, docs/paper-procedure.md#iterative-solution).
    iterations : ndarray of int32, shape (N,)
        Solver iterations (summed over retries); 0 for closed forms.
    covariance : ndarray, shape (N, 6, 6), optional
        Pose-vector covariance from the solver's Gauss-Newton approximation, when requested.
    solver : str
        Name of the solver that produced the result.
    """

    poses: np.ndarray
    pose_vectors: np.ndarray
    status: np.ndarray
    residual: np.ndarray
    iterations: np.ndarray
    covariance: np.ndarray | None = None
    solver: str = ""

    def __len__(self) -> int:
        return self.status.shape[0]

    @property
    def valid(self) -> np.ndarray:
        """Boolean mask of samples with ``status == CONVERGED``."""
        return self.status == Status.CONVERGED

    def status_counts(self) -> dict[str, int]:
        """Number of samples per status name (every status listed, zeros included)."""
        counts = np.bincount(self.status.astype(np.int64), minlength=len(Status))
        return {s.name.lower(): int(counts[s.value]) for s in Status}

    def select(self, rows) -> SolveResult:
        """A result with the rows picked by a boolean mask or index array."""
        idx = np.flatnonzero(rows) if np.asarray(rows).dtype == bool else np.asarray(rows)
        return SolveResult(self.poses[idx], self.pose_vectors[idx], self.status[idx],
                           self.residual[idx], self.iterations[idx],
                           None if self.covariance is None else self.covariance[idx], self.solver)

    @staticmethod
    def concatenate(results) -> SolveResult:
        """Join results of consecutive chunks."""
        results = list(results)
        if not results:
            raise InputError("expected at least one SolveResult to concatenate, got none")
        cov = None
        if all(r.covariance is not None for r in results):
            cov = np.concatenate([r.covariance for r in results])
        return SolveResult(*(np.concatenate([getattr(r, f) for r in results])
                             for f in ("poses", "pose_vectors", "status", "residual",
                                       "iterations")),
                           covariance=cov, solver=results[0].solver)
