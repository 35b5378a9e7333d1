"""The one calibration engine: a :class:`~openemt.calibrate.CalibrationProblem` of any coupling
model and kinematics, solved over its free parameters, with the fit statistics, standard
errors, identifiability and provenance every calibration carries (docs/calibration.md#one-engine-three-kinematics).

The kinematics are the caller's (the ILEMT rig in :func:`~openemt.calibrate.fit`, a reference
chain in :func:`~openemt.calibrate.fit_reference`, known poses in
:func:`~openemt.calibrate.fit_planar`); everything after "here are the problem, the start and
the free parameters" is here, once.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .. import __version__
from ._identifiability import Identifiability, analyse_identifiability
from ._lsq import fit_free_parameters

__all__ = ["EngineFit", "fit_problem", "fit_provenance", "residue_block"]

#: The optimiser every fit names in its provenance.
OPTIMIZER = "scipy.optimize.least_squares(lm), analytic Jacobian"


@dataclass(frozen=True, eq=False)
class EngineFit:
    """A solved calibration problem.

    Attributes
    ----------
    x : ndarray, shape (layout.size,)
        Full parameter vector at the solution.
    free : ndarray of int
        Full-vector indices of the fitted parameters.
    residuals, jacobian : ndarray
        Normalised residuals ``(m,)`` and their Jacobian ``(m, layout.size)`` at ``x``.
    identifiability : Identifiability or None
        Rank, condition, covariance and standard errors of the free parameters (None when not
        asked for).
    standard_errors : ndarray, shape (layout.size,)
        Standard errors in full-vector order (0 for held parameters).
    stats : dict
        ``rms_residue`` (``sqrt(SSR / rows)``), ``sum_squared_residue``, ``num_points``,
        ``nfev``, ``optimizer_status``, ``fit_seconds`` and, with the identifiability,
        ``jacobian_rank``, ``n_free``, ``condition``, ``undetermined_groups``.
    result : scipy.optimize.OptimizeResult
    seconds : float
    """

    x: np.ndarray
    free: np.ndarray
    residuals: np.ndarray
    jacobian: np.ndarray
    identifiability: Identifiability | None
    standard_errors: np.ndarray
    stats: dict
    result: object
    seconds: float

    @property
    def converged(self) -> bool:
        """scipy's status says a tolerance was met (not the evaluation limit)."""
        return int(self.result.status) > 0


def residue_block(r: np.ndarray, n_rows: int) -> dict:
    """``rms_residue``, ``sum_squared_residue`` and ``num_points`` of normalised residuals
    (docs/paper-procedure.md#calibration-objective)."""
    ss = float(r @ r)
    return {"rms_residue": float(np.sqrt(ss / n_rows)), "sum_squared_residue": ss,
            "num_points": int(n_rows)}


def fit_problem(prob, x0, free, groups=(), *, tol: float = 1e-12, max_nfev=200,
                uncertainty: bool = True, warn: bool = True) -> EngineFit:
    """Fit ``prob`` over ``x0[free]`` (the rest held) and describe the fit.

    Parameters
    ----------
    prob : CalibrationProblem
    x0 : ndarray, shape (layout.size,)
    free : ndarray of int
    groups : sequence of str
        The free group names, checked for identifiability (warned about with ``warn``).
    tol, max_nfev
        scipy's ``ftol = xtol = gtol`` and evaluation limit.
    uncertainty : bool
        Compute the identifiability and standard errors at the solution.
    """
    t0 = time.perf_counter()
    x, res = fit_free_parameters(prob, x0, free, tol=tol, max_nfev=max_nfev)
    seconds = time.perf_counter() - t0
    r, J = prob.residuals_and_jacobian(x)
    ident = None
    se = np.zeros(prob.layout.size)
    stats = residue_block(r, prob.n_rows)
    stats.update(nfev=int(res.nfev), optimizer_status=int(res.status), fit_seconds=seconds)
    if uncertainty:
        ident = analyse_identifiability(J[:, free], r, free, prob.layout, list(groups),
                                        warn=warn)
        se[free] = ident.standard_errors
        stats.update(jacobian_rank=ident.rank, n_free=ident.n_free,
                     condition=ident.to_dict()["condition"],
                     undetermined_groups=list(ident.undetermined))
    return EngineFit(x=x, free=free, residuals=r, jacobian=J, identifiability=ident,
                     standard_errors=se, stats=stats, result=res, seconds=seconds)


def fit_provenance(mode: str, dataset=None, rows=None, start_calibration=None, **more) -> dict:
    """The provenance block of a fitted calibration: openemt version, mode, optimiser, the
    input files of the fitted ``rows`` of ``dataset`` with their hashes, the start calibration
    (its mode, file, inputs and start mode) and anything in ``more``."""
    out = {"openemt_version": __version__, "mode": mode, "optimizer": OPTIMIZER}
    if dataset is not None:
        part = dataset if rows is None else dataset.select(rows)
        hashes = dict(dataset.meta.get("provenance", {}).get("inputs", {}))
        files = sorted(set(part.file_names().tolist()) - {""})
        out["inputs"] = {f: hashes.get(f) for f in files}
        out["num_rows"] = int(len(part))
    if start_calibration is not None:
        start = start_calibration
        sp = start.provenance
        out["start"] = {"mode": start.mode, "file": sp.get("file"), "inputs": sp.get("inputs"),
                        "start_mode": (sp.get("start") or {}).get("mode")}
    out.update(more)
    return out
