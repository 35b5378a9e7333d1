"""Rows of a recording solved as a time series: each sample warm-started from the previous
converged one (``initial='track'``), with a cold retry of every failed or suspicious sample.

The compiled tracking kernel (:func:`openemt.solve._lm.lm_track`) already restarts a sample
that fails the retry test from its Kim18 closed form. What it cannot see is a sample that
converges from the previous pose to a fit that is poor for clean data: after a glitch or a
jump the previous pose can lie in the basin of a wrong local minimum. So every sample whose
status is not ``converged`` (invalid input aside) or whose relative residual is above the
exploration level (``explore_above``, default
:data:`~openemt._constants.EXPLORE_RELATIVE_RESIDUAL`: far above the residual of a right
solution of clean data) is solved again cold, exactly as an independent row
(``initial='kim18'``, or the multi-start grid for a model without a concentric start), and the
cold answer replaces the tracked one where it is better: converged where the tracked one is
not, else a lower relative residual.
"""

from __future__ import annotations

import numpy as np

from ._result import SolveResult, Status

__all__ = ["cold_start_name", "solve_series"]

def cold_start_name(solver) -> str:
    """The independent-row start of a prepared dipole LM solver: ``'kim18'`` where a
    concentric start model exists (a 3x3 model or ``concentric_model``), else
    ``'multistart'``."""
    opts = solver.options
    conc = solver.n_source == 3 and solver.n_sensor == 3 or opts.concentric_model is not None
    return "kim18" if conc else "multistart"


def suspicious(result: SolveResult, level: float | None) -> np.ndarray:
    """Rows to solve again cold: not converged (invalid input aside) or, when ``level`` is
    set, a relative residual above it."""
    bad = (result.status != Status.CONVERGED) & (result.status != Status.INVALID_INPUT)
    if level is not None and result.relative_residual is not None:
        with np.errstate(invalid="ignore"):
            bad |= (result.relative_residual > level) & (result.status != Status.INVALID_INPUT)
    return np.flatnonzero(bad)


def _better(old: SolveResult, rows, new: SolveResult) -> np.ndarray:
    """Which of ``new`` (solved for ``rows``) beat ``old``'s rows: converged where the old
    is not, else (same convergence) a lower relative residual."""
    ok_new = new.status == Status.CONVERGED
    ok_old = old.status[rows] == Status.CONVERGED
    with np.errstate(invalid="ignore"):
        lower = new.relative_residual < old.relative_residual[rows]
        lower |= np.isfinite(new.relative_residual) & ~np.isfinite(old.relative_residual[rows])
    return (ok_new & ~ok_old) | ((ok_new == ok_old) & lower)


def solve_series(solver, couplings, *, for_rows=None) -> tuple[SolveResult, int]:
    """Solve the rows of ``couplings`` (one recording, in time order) with the prepared dipole
    LM ``solver`` (:func:`openemt.solve.prepare`) warm-started from sample to sample, then
    solve the failed or suspicious samples again cold (see the module docstring).

    Parameters
    ----------
    solver : prepared solver
        ``solver(C, initial) -> SolveResult`` with ``options`` (its ``explore_above`` is the
        suspicion level; None: only failed samples are retried).
    couplings : ndarray (N, n_source, n_sensor)
    for_rows : callable, optional
        ``for_rows(rows) -> solver`` for a subset of the rows (needed when the solver was
        prepared with one hemisphere per row); default ``solver`` itself.

    Returns
    -------
    (SolveResult, int)
        The result and the number of samples solved again cold.
    """
    C = np.asarray(couplings)
    result = solver(C, "track")
    level = solver.options.explore_above
    if solver.options.retry_resnorm is not None:   # the paper's procedure: no exploration
        level = None
    rows = suspicious(result, level)
    if not rows.size:
        return result, 0
    cold = (solver if for_rows is None else for_rows(rows))(C[rows], cold_start_name(solver))
    take = _better(result, rows, cold)
    if take.any():
        result = result.with_rows(rows[take], cold, take)
    return result, int(rows.size)
