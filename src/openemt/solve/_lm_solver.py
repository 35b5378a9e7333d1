"""Public entry point of the compiled Levenberg-Marquardt solver (see ``_lm.py``): one call that
prepares a solver (:func:`openemt.solve.prepare`, a :class:`openemt.solve._prepared.PreparedLM`)
and solves."""

from __future__ import annotations

from ..field import check_dipole_model
from ._options import SolveOptions
from ._prepared import PreparedLM
from ._result import SolveResult

__all__ = ["solve_lm"]


def solve_lm(couplings, model=None, options: SolveOptions | dict | None = None,
             **overrides) -> SolveResult:
    """Levenberg-Marquardt pose solution for any dipole model, compiled and batched.

    The options are the fields of :class:`~openemt.solve.SolveOptions` (a record, or single
    fields as keywords); their defaults are written there once, and the dipole LM's values of
    the fields left at None are resolved in one place (``SolveOptions.lm_kwargs``).

    Parameters
    ----------
    couplings : ndarray, shape (N, n_source, n_sensor)
        Signed real couplings (complex phasors are accepted: target ``sign(Re z)|z|``, residual
        normalised by the complex spectral norm, as ILEMT).
    model : DipoleModel, optional
        The coil model (concentric or not; ideal concentric coils with gain 1/250 if omitted).
        6-DOF needs >= 6 couplings; a single-coil sensor (``n_sensor == 1``) gives a 5-DOF
        solve whose roll about the sensor axis is reported as zero (shortest-arc rotation of
        the coil axis).
    hemisphere : None, str, (3,), (N,) str or (N, 3)
        Constraint ``t . n >= 0`` (ILEMT's hemisphere bound); default ``'+x'`` as every solver;
        ``None`` for no constraint (the closed-form start then uses ``'+x'``).
    initial : {'kim18', 'svd', 'kuipers', 'track', 'multistart'} or array (N, 6) / (6,)
        Closed-form start (needs a 3x3 model; uses ``concentric_model`` as is, or else the
        model's moments with the coil offsets dropped and a fixed-point correction of the offset
        effect, see ``closed_form_start``; ``'kim18'`` on a model with coil offsets and no
        ``concentric_model``: the cold start of docs/solve.md#cold-start, candidates from a
        table of rotation-invariant couplings and the closed form, restarts only for samples
        whose residual is above ``explore_above``), tracking (each sample starts from the previous valid
        solution; the first and any failed sample from the Kim18 closed form when available,
        else multi-start), a coarse multi-start grid, or given pose vectors.
    max_iter : int
        Iterations per LM run.
    max_relative_residual, max_range : float or None
        The validity rule (docs/solve.md#validity-rule): a solution is CONVERGED only if it
        is finite, within ``max_range`` m of the source (default ``MAX_RANGE_M`` = 3), the LM
        run converged and ``||C_model(pose) - C||_F / ||C||_F <= max_relative_residual``
        (default ``MAX_RELATIVE_RESIDUAL`` = 0.01). ``None`` disables a test.
    retries : bool
        Re-solve a sample failing the retry test from the initial pose with one pose-vector
        component's sign flipped, each of the 6 in turn (ILEMT,
        docs/paper-procedure.md#iterative-solution).
    retry_resnorm : float, optional
        The retry test. ``None`` (default): retry while the relative residual is above
        ``max_relative_residual``. A number: ILEMT's own test instead, retry while the resnorm
        (sum of squared residuals / spectral norm of C, in the couplings' units) is at least
        this; for reproducing the paper's procedure. Either way the status follows the
        validity rule.
    explore_above : float or None
        A sample whose relative residual is above this after the solve (default
        ``EXPLORE_RELATIVE_RESIDUAL`` = 1e-3) is solved again from more starts, keeping the
        lowest residual: the 6 sign-flip retries from the solution found, then (if still above)
        the multi-start grid. A wrong local minimum can leave a residual below the validity
        threshold (about 1 sample in 1000 with a 45 mm coil-offset source at 5-60 cm); this
        finds the right one. It costs time only for samples above the level (noisy data).
        A sample the cold start settled (two independent starts to one minimum that passes the
        retry test, docs/solve.md#cold-start) gets the sign-flip retries only.
        ``None`` disables it; it is off with ``retry_resnorm`` (the paper's procedure).
    concentric_model : DipoleModel, optional
        Concentric model for the closed-form start (ILEMT: the concentric calibration).
    bounds : float or array (3, 2), optional
        Position box (half-width in m, or [low, high] per axis); a solution on its boundary is
        OUT_OF_VOLUME. ILEMT uses ``ILEMT_POSITION_BOX_M`` (0.4 m).
    xtol : float
        Convergence when the relative translation step and the rotation step (rad) are below it
        (the step after that would be ~xtol^2 for these small-residual problems).
    ambiguity_tol : float
        A solution with ``t . n <= ambiguity_tol * |t|`` (on the hemisphere plane) is AMBIGUOUS.
    covariance : bool
        Also return the Gauss-Newton pose-vector covariance ``s^2 (J^T J)^-1`` with
        ``s^2 = SSR / (m - dof)`` (see :func:`openemt.solve.cramer_rao`).
    fallback : None or 'multistart'
        Re-solve samples still NOT_CONVERGED / MAX_ITERATIONS from the best of a coarse grid
        of 56 starts, keeping the better result (slow; off by default, and off for ILEMT
        reproduction).

    Returns
    -------
    SolveResult

    Notes
    -----
    ``solve_lm`` is ``prepare(model, **options).solve(couplings, initial)``, a
    :class:`~openemt.solve._prepared.PreparedLM`
    (:func:`openemt.solve.prepare`, docs/solve.md#one-solver-factory); for many calls with one
    model and one set of options, prepare once and call the prepared solver (same results, bit
    for bit).

    Examples
    --------
    A source whose coils sit 45 mm apart (the simulator's ``dipole-approx`` preset), couplings
    at a known pose, solved back:

    >>> import numpy as np
    >>> from openemt import solve_lm
    >>> from openemt.geometry import pose_from_vector
    >>> from openemt.simulate import truth_calibration
    >>> model = truth_calibration("dipole-approx").model
    >>> truth = pose_from_vector(np.array([[0.3, 0.1, -0.05, 0.2, -0.4, 1.0]]))  # m, rad
    >>> result = solve_lm(model.coupling(truth), model)
    >>> result.status, np.round(result.pose_vectors, 6)
    (array([0], dtype=int8), array([[ 0.3 ,  0.1 , -0.05,  0.2 , -0.4 ,  1.  ]]))
    """
    if model is not None:
        check_dipole_model(model)
    opts = SolveOptions.of(options, overrides)
    # the solver prepare(model, options) makes for a dipole model
    solver = PreparedLM(model, opts)
    return solver.solve(couplings, "kim18" if opts.initial is None else opts.initial,
                        covariance=opts.covariance, fallback=opts.fallback)
