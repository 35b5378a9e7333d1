"""The one validity rule of every pose solver: when is a solution called ``CONVERGED``.

A solved pose is only as good as the agreement between the couplings it predicts and the ones
measured. openemt judges that agreement without units, so the rule holds alike for ILEMT
couplings near 1, tesla-scale planar-board data near 1e-8 and couplings scaled by any factor:

``relative residual  rho = ||C_pred - C_meas||_F / ||C_meas||_F``

A sample is ``CONVERGED`` only if all of these hold (checked in this order, the first failure
names the status):

1. the input is finite and non-zero (else ``INVALID_INPUT``, pose NaN);
2. the pose is finite and its position lies inside the plausible range ``|t| <= max_range``
   and inside the caller's position box, if any (else ``OUT_OF_VOLUME``);
3. the position is not on the hemisphere plane (else ``AMBIGUOUS``);
4. the solver stopped by its convergence test, not by its iteration limit (else
   ``MAX_ITERATIONS``);
5. ``rho <= max_relative_residual`` (else ``NOT_CONVERGED``).

The defaults are the named constants ``MAX_RELATIVE_RESIDUAL`` (0.01) and ``MAX_RANGE_M``
(3 m) of ``openemt._constants``, re-exported here; every solver takes them as keyword arguments
(``max_relative_residual=``, ``max_range=``) and the CLI as options. See docs/solve.md.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .._constants import EXPLORE_RELATIVE_RESIDUAL, MAX_RANGE_M, MAX_RELATIVE_RESIDUAL
from .._errors import InputError
from ._packing import O_AMBIGUITY_TOL, O_MAX_RANGE, O_MAX_RELATIVE_RESIDUAL
from ._result import (
    ST_AMBIGUOUS,
    ST_CONVERGED,
    ST_MAX_ITERATIONS,
    ST_NOT_CONVERGED,
    ST_OUT_OF_VOLUME,
)

__all__ = ["EXPLORE_RELATIVE_RESIDUAL", "MAX_RANGE_M", "MAX_RELATIVE_RESIDUAL", "SAME_MINIMUM_RTOL",
           "better_run", "check_validity_options", "classify", "rejudge", "relative_residual",
           "relative_residuals"]

#: Two solutions of one sample whose relative residuals agree to this fraction are at the same
#: minimum: of those, the one whose solver met its convergence test is kept, so a sample's status
#: never depends on which of several runs reached one minimum first (the last-bit rounding of a
#: CPU, or couplings scaled by a power of ten, decide that; docs/solve.md#validity).
SAME_MINIMUM_RTOL = 1e-9


@njit(inline="always")
def better_run(cost, stop_ok, best, best_stop_ok) -> bool:
    """Whether a run ending at ``cost`` (a residual norm or its square, ``stop_ok``: the solver
    met its convergence test) replaces the best so far: a lower cost at another minimum, or at
    the same minimum (costs within :data:`SAME_MINIMUM_RTOL`) a run that converged where the
    best one hit its iteration limit, or, alike in that, the lower cost."""
    if not cost == cost:
        return False
    if not best < np.inf:
        return True
    if abs(cost - best) > SAME_MINIMUM_RTOL * abs(best):
        return cost < best
    if stop_ok != best_stop_ok:
        return stop_ok
    return cost < best


def check_validity_options(max_relative_residual, max_range) -> tuple[float, float]:
    """Validate the two thresholds of the rule (positive; ``None`` or ``inf`` disables one)."""
    out = []
    for name, v in (("max_relative_residual", max_relative_residual), ("max_range", max_range)):
        v = np.inf if v is None else v
        try:
            f = float(v)
        except (TypeError, ValueError):
            raise InputError(f"expected a positive number for `{name}`, got {v!r}") from None
        if not f > 0:  # also rejects NaN
            raise InputError(f"expected a positive number for `{name}`, got {v!r}")
        out.append(f)
    return out[0], out[1]


@njit(inline="always")
def relative_residual(Cp, Cm):
    """``||Cp - Cm||_F / ||Cm||_F`` of one coupling matrix (NaN if ``Cm`` is zero), computed on
    the matrices divided by ``max |Cm|`` so that no scale under- or overflows."""
    mx = 0.0
    for i in range(Cm.shape[0]):
        for j in range(Cm.shape[1]):
            mx = max(mx, abs(Cm[i, j]))
    if not mx > 0.0:
        return np.nan
    num = 0.0
    den = 0.0
    for i in range(Cm.shape[0]):
        for j in range(Cm.shape[1]):
            r = (Cp[i, j] - Cm[i, j]) / mx
            c = Cm[i, j] / mx
            num += r * r
            den += c * c
    return np.sqrt(num / den)


def rejudge(status, rho, max_relative_residual) -> np.ndarray:
    """Statuses after the relative residual changed (e.g. a refinement under a fuller model):
    CONVERGED and NOT_CONVERGED samples are judged again by step 5 of the rule; the others keep
    their status."""
    status = np.array(status, dtype=np.int8)
    open_ = (status == ST_CONVERGED) | (status == ST_NOT_CONVERGED)
    good = np.asarray(rho) <= max_relative_residual
    status[open_ & good] = ST_CONVERGED
    status[open_ & ~good] = ST_NOT_CONVERGED
    return status


def relative_residuals(predicted, measured) -> np.ndarray:
    """Batched :func:`relative_residual`: arrays ``(N, n_source, n_sensor)`` -> ``(N,)``."""
    p = np.asarray(predicted, dtype=np.float64)
    m = np.asarray(measured, dtype=np.float64)
    n = p.shape[0]
    num = np.linalg.norm((p - m).reshape(n, -1), axis=1)
    den = np.linalg.norm(m.reshape(n, -1), axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(den > 0, num / den, np.nan)


@njit(inline="always")
def classify(hit_limit, rho, t, n, box, opts):
    """Status of one solved sample with finite input (see the module docstring).

    Parameters
    ----------
    hit_limit : bool
        The solver stopped at its iteration limit.
    rho : float
        Relative residual of the solution.
    t : array (3,)
        Solved position (m).
    n : array (3,)
        Hemisphere direction (zeros: none).
    box : array (2, 3)
        Position box ``[lo, hi]`` (``-inf``/``inf`` for none); a position on or beyond it is
        out of volume.
    opts : array
        Solver options (``openemt.solve._packing``): ``t . n <= opts[O_AMBIGUITY_TOL] * |t|``
        is on the hemisphere plane; ``opts[O_MAX_RELATIVE_RESIDUAL]``, ``opts[O_MAX_RANGE]``
        are the thresholds of the rule.
    """
    lo = box[0]
    hi = box[1]
    ambig_tol = opts[O_AMBIGUITY_TOL]
    max_rel = opts[O_MAX_RELATIVE_RESIDUAL]
    max_range = opts[O_MAX_RANGE]
    nt2 = t[0] * t[0] + t[1] * t[1] + t[2] * t[2]
    if not np.isfinite(nt2):
        return ST_OUT_OF_VOLUME
    nt = np.sqrt(nt2)
    if nt > max_range:
        return ST_OUT_OF_VOLUME
    for a in range(3):
        if t[a] <= lo[a] or t[a] >= hi[a]:
            return ST_OUT_OF_VOLUME
    has_n = n[0] != 0.0 or n[1] != 0.0 or n[2] != 0.0
    if has_n and t[0] * n[0] + t[1] * n[1] + t[2] * n[2] <= ambig_tol * nt:
        return ST_AMBIGUOUS
    if hit_limit:
        return ST_MAX_ITERATIONS
    if not rho <= max_rel:
        return ST_NOT_CONVERGED
    return ST_CONVERGED
