"""Per-sample solver status codes and the batched solve result."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from .._errors import InputError

__all__ = ["SolveResult", "Status", "status_count_names"]


class Status(IntEnum):
    """Outcome of one sample's pose solution.

    CONVERGED
        The solver converged, the pose is finite and within the plausible range, and the
        relative residual is at most the validity threshold (docs/solve.md#validity-rule).
    MAX_ITERATIONS
        The iteration limit was reached before the convergence tests held.
    INVALID_INPUT
        The coupling matrix is NaN/inf, zero or rank deficient; the pose is NaN.
    AMBIGUOUS
        The position lies (numerically) on the hemisphere boundary, so the +/- dipole
        ambiguity could not be resolved; the pose returned is one of the two candidates.
    OUT_OF_VOLUME
        The pose is not finite, farther than the plausible range from the source origin, or on
        or beyond the allowed position box.
    NOT_CONVERGED
        The solver stopped (converged or stalled) but the relative residual is above the
        validity threshold.
    """

    CONVERGED = 0
    MAX_ITERATIONS = 1
    INVALID_INPUT = 2
    AMBIGUOUS = 3
    OUT_OF_VOLUME = 4
    NOT_CONVERGED = 5


def status_count_names(counts) -> dict[str, int]:
    """Counts per status code (an array indexed by ``Status`` value) as ``{status name in lower
    case: count}``, every status listed, zeros included: the one form every summary uses."""
    return {s.name.lower(): int(counts[s.value]) for s in Status}


#: the per-row fields a retry's rows replace (:meth:`SolveResult.with_rows`)
ROW_FIELDS = ("poses", "pose_vectors", "status", "residual", "iterations", "relative_residual")

# the codes as int8 module constants, usable inside compiled kernels
ST_CONVERGED = np.int8(Status.CONVERGED)
ST_MAX_ITERATIONS = np.int8(Status.MAX_ITERATIONS)
ST_INVALID_INPUT = np.int8(Status.INVALID_INPUT)
ST_AMBIGUOUS = np.int8(Status.AMBIGUOUS)
ST_OUT_OF_VOLUME = np.int8(Status.OUT_OF_VOLUME)
ST_NOT_CONVERGED = np.int8(Status.NOT_CONVERGED)


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
    relative_residual : ndarray, shape (N,), optional
        ``||C_pred - C_meas||_F / ||C_meas||_F``, the unit-free residual the status is judged
        by (docs/solve.md#validity-rule); NaN where the input is invalid.
    """

    poses: np.ndarray
    pose_vectors: np.ndarray
    status: np.ndarray
    residual: np.ndarray
    iterations: np.ndarray
    covariance: np.ndarray | None = None
    solver: str = ""
    relative_residual: np.ndarray | None = None

    def __len__(self) -> int:
        return self.status.shape[0]

    @property
    def valid(self) -> np.ndarray:
        """Boolean mask of samples with ``status == CONVERGED``."""
        return self.status == Status.CONVERGED

    def status_counts(self) -> dict[str, int]:
        """Number of samples per status name (every status listed, zeros included)."""
        return status_count_names(np.bincount(self.status.astype(np.int64),
                                              minlength=len(Status)))

    def select(self, rows) -> SolveResult:
        """A result with the rows picked by a boolean mask or index array."""
        idx = np.flatnonzero(rows) if np.asarray(rows).dtype == bool else np.asarray(rows)
        return SolveResult(self.poses[idx], self.pose_vectors[idx], self.status[idx],
                           self.residual[idx], self.iterations[idx],
                           None if self.covariance is None else self.covariance[idx], self.solver,
                           None if self.relative_residual is None
                           else self.relative_residual[idx])

    @staticmethod
    def concatenate(results) -> SolveResult:
        """Join results of consecutive chunks."""
        results = list(results)
        if not results:
            raise InputError("expected at least one SolveResult to concatenate, got none")
        opt = {}
        for f in ("covariance", "relative_residual"):
            opt[f] = None
            if all(getattr(r, f) is not None for r in results):
                opt[f] = np.concatenate([getattr(r, f) for r in results])
        return SolveResult(*(np.concatenate([getattr(r, f) for r in results])
                             for f in ("poses", "pose_vectors", "status", "residual",
                                       "iterations")),
                           solver=results[0].solver, **opt)

    def replace(self, **fields) -> SolveResult:
        """A copy with the given fields replaced."""
        return dataclasses.replace(self, **fields)

    def with_rows(self, rows, other: SolveResult, picked=slice(None)) -> SolveResult:
        """A copy whose rows ``rows`` are the rows ``picked`` of ``other`` (e.g. a retry's
        better rows put into the first run; the fields of :data:`ROW_FIELDS` this result
        has)."""
        fields = {}
        for name in ROW_FIELDS:
            a = getattr(self, name)
            if a is not None:
                a = a.copy()
                a[rows] = getattr(other, name)[picked]
                fields[name] = a
        return self.replace(**fields)
