"""One solver factory: :func:`prepare` turns a calibration or a model and the options
(:class:`~openemt.solve.SolveOptions`) into a prepared solver
``solver(couplings, initial=None) -> SolveResult``.

Every entry point that solves poses goes through here: :func:`openemt.solve.solve` and
:func:`~openemt.solve.solve_chunks`, :func:`~openemt.solve.solve_lm`, the live pipeline's default
solvers (dipole and board), ``openemt solve`` and the benchmarks. The options are checked once,
when their record is made; the model, its packed form and the options' packed form once, when
the solver is prepared.
"""

from __future__ import annotations

import numpy as np

from .._errors import InputError
from ..field import check_dipole_model, solver_family
from ._hemisphere import DEFAULT_HEMISPHERE
from ._options import DEFAULT, SolveOptions
from ._result import SolveResult, Status

__all__ = ["SOLVERS", "SOLVER_FAMILIES", "apply_position_correction", "prepare"]

#: Solver names accepted by :func:`prepare`, :func:`openemt.solve.solve` and
#: ``openemt solve --solver``.
SOLVERS = ("lm", "svd", "kuipers", "kim18")

# options only the dipole Levenberg-Marquardt solver has (a closed form or the board solver
# refuses a value other than the default)
_LM_ONLY = ("max_iter", "retries", "retry_resnorm", "explore_above", "concentric_model",
            "bounds", "xtol", "covariance", "fallback", "initial")
_BOARD_REFUSED = ("retries", "retry_resnorm", "explore_above", "concentric_model",
                  "covariance", "fallback")



def apply_position_correction(result: SolveResult, L) -> SolveResult:
    """Apply a 4x4 homogeneous output correction to the solved positions (orientation kept),
    docs/paper-procedure.md#applying-correction."""
    from ..correct import apply_linear_correction

    xyz = apply_linear_correction(L, result.pose_vectors[:, :3])
    poses = result.poses.copy()
    vecs = result.pose_vectors.copy()
    poses[:, :3, 3] = xyz
    vecs[:, :3] = xyz
    return result.replace(poses=poses, pose_vectors=vecs)


class _Shape:
    """``n_source``, ``n_sensor`` and ``dof`` of a model."""

    def _shape_of(self, n_source, n_sensor):
        self.n_source, self.n_sensor = int(n_source), int(n_sensor)
        self.dof = 5 if self.n_sensor == 1 else 6


class ClosedFormSolver(_Shape):
    """A closed form (``'svd'``, ``'kuipers'``, ``'kim18'``) on a concentric 3x3 model."""

    serial = True

    def __init__(self, model, method, options: SolveOptions):
        from ._closed_form import solve_kim18, solve_kuipers, solve_svd

        try:
            check_dipole_model(model)
        except TypeError:
            raise InputError(f"expected a DipoleModel for the {method!r} closed form, got "
                             f"{type(model).__name__}") from None
        extra = options.changed(_LM_ONLY)
        if extra:
            raise InputError(f"expected no {', '.join(extra)} with the {method!r} closed form "
                             f"(options of the LM solver), got them set")
        self._f = {"kim18": solve_kim18, "svd": solve_svd, "kuipers": solve_kuipers}[method]
        self.cold_start = None                  # every sample is solved from no prior
        self.model = model
        self.method = method
        self.options = options
        h = options.hemisphere
        self._kw = {"hemisphere": DEFAULT_HEMISPHERE if h is None or (isinstance(h, str)
                                                                      and h == DEFAULT) else h,
                    "max_relative_residual": options.max_relative_residual,
                    "max_range": options.max_range}
        if options.ambiguity_tol is not None:
            self._kw["ambiguity_tol"] = options.ambiguity_tol
        self._shape_of(model.n_source, model.n_sensor)

    def __call__(self, couplings, initial=None) -> SolveResult:
        if initial is not None:
            raise InputError(f"expected no start for the {self.method!r} closed form, got one")
        return self._f(couplings, self.model, **self._kw)


class PlanarSolver(_Shape):
    """The 5-DOF finite-coil board solver (:class:`~openemt.solve._planar.PreparedPlanar`).

    ``initial`` is a start name (``'track'``, ``'grid'``), start poses ``(N, 4, 4)``, or pose
    vectors ``(N, 6)`` (a warm start, the live pipeline's): a sample that does not converge
    from its start is solved again cold, from the seed grid.
    """

    serial = True

    def __init__(self, model, options: SolveOptions):
        from ._planar import PreparedPlanar

        extra = options.changed(_BOARD_REFUSED)
        if extra:
            raise InputError(f"expected no {', '.join(extra)} with a finite-coil board "
                             f"(options of the dipole LM solver), got them set")
        h = options.hemisphere
        hemi = None if isinstance(h, str) and h == DEFAULT else "none" if h is None else h
        kw = {"max_relative_residual": options.max_relative_residual,
              "max_range": options.max_range, "bounds": options.bounds, "hemisphere": hemi}
        for name in ("max_iter", "xtol", "ambiguity_tol"):
            if getattr(options, name) is not None:
                kw[name] = getattr(options, name)
        self.prepared = PreparedPlanar(model, **kw)
        self.model = model
        self.options = options
        self._initial = "track" if options.initial is None else options.initial
        self.cold_start = model.cold_start
        self._shape_of(model.n_coils, 1)

    def __call__(self, couplings, initial=None) -> SolveResult:
        if initial is None:
            initial = self._initial
        if isinstance(initial, str) or np.ndim(initial) == 3:
            return self.prepared.solve(couplings, initial)
        from ..geometry import pose_from_vector

        return self._warm(couplings, pose_from_vector(np.asarray(initial, dtype=np.float64)))

    def _warm(self, C, start) -> SolveResult:
        res = self.prepared.solve(C, start)
        again = np.isin(res.status, _RETRY)
        if not np.any(again):
            return res
        cold = self.prepared.solve(np.asarray(C)[again], "track")
        pick = cold.status == int(Status.CONVERGED)
        return res.with_rows(np.flatnonzero(again)[pick], cold, pick)


_RETRY = np.array([int(Status.NOT_CONVERGED), int(Status.MAX_ITERATIONS),
                   int(Status.AMBIGUOUS), int(Status.OUT_OF_VOLUME)])


class CalibrationSolver:
    """A solver of a calibration's dipole model followed by what the calibration adds: the
    refinement under an improved calibration's octupole terms and the linear output
    correction."""

    def __init__(self, inner, full_model=None, correction=None):
        self.inner = inner
        self.full_model = full_model
        self.correction = correction
        self.options = inner.options
        self.n_source, self.n_sensor, self.dof = inner.n_source, inner.n_sensor, inner.dof
        self.cold_start = getattr(inner, "cold_start", None)

    def __call__(self, couplings, initial=None) -> SolveResult:
        result = self.inner(couplings, initial)
        if self.full_model is not None:
            from ._refine import refine_result

            C = np.asarray(couplings)
            if C.ndim == 2:                    # a single coil's (N, n_source) couplings
                C = C[:, :, None]
            result = refine_result(result, self.full_model, C,
                                   max_relative_residual=self.options.max_relative_residual)
        if self.correction is not None:
            result = apply_position_correction(result, self.correction)
        return result


def prepare(calibration_or_model, options: SolveOptions | dict | None = None, *,
            solver: str = "lm", apply_correction: bool = True, **overrides):
    """A prepared pose solver for a calibration or a model.

    Parameters
    ----------
    calibration_or_model : Calibration or coupling model
        A :class:`~openemt.io.Calibration` of any model (an improved one's octupole terms
        refine the dipole solution, its ``linear_correction`` is applied to the positions, as
        :func:`openemt.solve.solve` does) or a coupling model
        (:class:`openemt.field.CouplingModel`). The dipole model and the 5-DOF board have
        compiled solvers; any other model (a board read by a 6-DOF sensor of two coils, ...)
        is solved by :class:`~openemt.solve._model_lm.ModelSolver` from its interface.
    options : SolveOptions or dict, optional
        The options (default ``SolveOptions()``); ``overrides`` replace single fields.
    solver : {'lm', 'svd', 'kuipers', 'kim18'}
        The closed forms need a concentric 3x3 dipole model; other models have the LM solver
        only.
    apply_correction : bool
        Apply a calibration's linear output correction.

    Returns
    -------
    solver
        ``solver(couplings, initial=None) -> SolveResult`` (``initial``: a start name or start
        pose vectors (N, 6); None: ``options.initial``, else the solver's default) with the
        attributes ``options``, ``n_source``, ``n_sensor``, ``dof`` and ``cold_start`` (the
        start name of a sample with no prior pose, e.g. the first of a tracked series; None
        for a closed form). The solver is built by the registry entry
        (:data:`SOLVER_FAMILIES`) of the model's declared ``solver_family``. The dipole LM solver
        is a :class:`~openemt.solve._prepared.PreparedLM`.

    Examples
    --------
    >>> import numpy as np
    >>> from openemt.geometry import pose_from_vector
    >>> from openemt.simulate import truth_calibration
    >>> from openemt.solve import prepare
    >>> cal = truth_calibration("dipole-approx")
    >>> solver = prepare(cal, max_iter=50)
    >>> C = cal.model.coupling(pose_from_vector(np.array([[0.3, 0.1, -0.05, 0.2, -0.4, 1.0]])))
    >>> result = solver(C)
    >>> solver.dof, result.status, np.round(result.pose_vectors, 6)
    (6, array([0], dtype=int8), array([[ 0.3 ,  0.1 , -0.05,  0.2 , -0.4 ,  1.  ]]))
    """
    from ..field import check_coupling_model
    from ..io import Calibration

    opts = SolveOptions.of(options, overrides)
    if solver not in SOLVERS:
        raise InputError(f"expected solver in {SOLVERS}, got {solver!r}")
    cal = calibration_or_model if isinstance(calibration_or_model, Calibration) else None
    if cal is None:
        try:
            check_coupling_model(calibration_or_model, "calibration_or_model")
        except TypeError:
            raise TypeError(f"expected a Calibration or a coupling model, got "
                            f"{type(calibration_or_model).__name__}") from None
    model = calibration_or_model if cal is None else cal.coupling_model
    family = solver_family(model)
    if family not in SOLVER_FAMILIES:
        raise InputError(f"expected a model of a solver family in {sorted(SOLVER_FAMILIES)}, "
                         f"got {family!r} ({model.kind!r} model)")
    if solver != "lm" and not family.startswith("dipole"):
        raise InputError(f"expected solver 'lm' for a {model.kind!r} model (the closed forms "
                         f"need a concentric 3x3 dipole model), got {solver!r}")
    inner, refine = SOLVER_FAMILIES[family](model, solver, opts)
    corr = cal.linear_correction if cal is not None and apply_correction else None
    if refine is None and corr is None:
        return inner
    return CalibrationSolver(inner, refine, corr)


def _dipole(model, solver, opts):
    if solver == "lm":
        from ._prepared import PreparedLM

        return PreparedLM(model, opts)
    return ClosedFormSolver(model, solver, opts)


def _board_lm(model, solver, opts):
    from ._model_kernels import pack_board
    from ._model_lm import PackedModelSolver

    return PackedModelSolver(model, opts, pack_board(model)), None


def _model_lm(model, solver, opts):
    from ._model_lm import ModelSolver

    return ModelSolver(model, opts), None


#: The solver registry: a model's declared ``solver_family`` (docs/field-models.md) -> the
#: builder ``(model, solver name, SolveOptions) -> (inner solver, model refining its solution
#: or None)`` that :func:`prepare` calls. Register a new family here.
SOLVER_FAMILIES = {
    "dipole": lambda m, s, o: (_dipole(m, s, o), None),
    # a dipole model with further terms (octupoles): the dipole kernel, then refined
    "dipole-refined": lambda m, s, o: (_dipole(m.dipole, s, o), m),
    "planar": lambda m, s, o: (PlanarSolver(m, o), None),   # the compiled 5-DOF board solver
    # a 5-DOF board with further terms (environment terms): the board's solver, then refined
    "planar-refined": lambda m, s, o: (PlanarSolver(m.planar, o), m),
    "board": _board_lm,          # a board read by several sensor coils: the compiled 6-DOF LM
    "model": _model_lm,
}
