"""The Levenberg-Marquardt solver with its arguments checked and packed once.

:func:`openemt.solve.solve_lm` checks the model and options, packs them for the compiled
kernels (``_packing``), derives the concentric start model and the hemisphere vectors, and then
solves. :class:`PreparedLM` does the first part once, at construction; each call then only
checks the couplings (a warm start: only their shape and type) and runs the kernels. ``solve_lm`` is ``PreparedLM(...).solve``, so
both give the same result bit for bit. A live tracker solving a few samples per chunk calls the
prepared solver (``openemt.live``), where the per-call checks and packing would otherwise
cost more than the solve itself.
"""

from __future__ import annotations

import numpy as np

from .._errors import InputError
from ..field import DipoleModel
from ..geometry import check_pose_vectors
from ._closed_form import (
    RANK_TOL,
    check_couplings,
    new_outputs,
    result_from_outputs,
    whitening,
)
from ._cold_start import table_for
from ._hemisphere import DEFAULT_HEMISPHERE, hemisphere_vectors
from ._lm import lm_batch, lm_track
from ._lm_starts import (
    _CLOSED,
    _bounds,
    _check_model,
    _concentric_for,
    _first_start,
    _keep_better,
    _multistart_init,
    _run_batch,
    _table_solve,
    canonical_5dof,
    closed_form_start,
)
from ._options import SolveOptions
from ._packing import (
    O_RETRIES,
    O_RETRY_RELATIVE,
    O_RETRY_RESNORM,
    pack_box,
    pack_model,
    pack_options,
)
from ._result import SolveResult, Status
from ._validity import check_validity_options

#: Relative residual above which the table start's solution is checked from independent
#: starts, a tenth of the exploration level (docs/solve.md#cold-start): noise-free couplings
#: whose best candidate ends in a wrong minimum at 4e-4 are restarted too
TABLE_RESTART_LEVEL = 1e-4

__all__ = ["PreparedLM"]

# below this many samples one kernel call on this thread (as ``_run_batch``)
_SMALL = 512


def _uniform(hemisphere) -> bool:
    """One hemisphere spec for all samples (None, a string or a numeric 3-vector)."""
    if hemisphere is None or isinstance(hemisphere, str):
        return True
    a = np.asarray(hemisphere)
    return a.dtype.kind in "iuf" and a.shape == (3,)


def uses_invariant_table(model, concentric_given: bool, retry_resnorm=None) -> bool:
    """Whether the LM solver's Kim18 start of ``model`` is the cold start of the invariant
    table (``_table_solve``, the ``table_candidates`` kernel): a 3x3 dipole model with coil
    offsets, no concentric model given, and not the paper's procedure (``retry_resnorm``: its
    Kim18 start and retries are kept as ILEMT has them)."""
    return (not concentric_given and not model.is_concentric and model.n_source == 3
            and model.n_sensor == 3 and retry_resnorm is None)


class PreparedLM:
    """:func:`openemt.solve.solve_lm` for one model and one set of options, prepared once.

    Parameters: the model and the options (:class:`~openemt.solve.SolveOptions`, or its
    fields as keywords: those of :func:`~openemt.solve.solve_lm` other than ``couplings``);
    :func:`openemt.solve.prepare` makes it for a dipole model. ``initial``, ``covariance`` and
    ``fallback`` of the options apply to calls ``solver(couplings)``; :meth:`solve` takes
    them per call. A
    ``hemisphere`` given per sample (shape (N, 3) or (N,) strings) is resolved at each call;
    one hemisphere for all samples is resolved here.

    Calling the object, ``solver(couplings, initial=None)``, is the solver interface of
    :func:`~openemt.solve.prepare` and the live pipeline (:mod:`openemt.live`): ``initial`` is
    ``(N, 6)`` start pose vectors (a warm start;
    real float64 couplings of the model's shape go straight to the compiled kernel) or a start
    name such as ``"kim18"``. Either way the result equals
    ``solve_lm(couplings, model, initial=initial, ...)``.

    Examples
    --------
    >>> import numpy as np
    >>> from openemt.geometry import pose_from_vector
    >>> from openemt.simulate import truth_calibration
    >>> from openemt.solve import solve_lm
    >>> from openemt.solve._prepared import PreparedLM
    >>> model = truth_calibration("dipole-approx").model
    >>> C = model.coupling(pose_from_vector(np.array([[0.3, 0.1, -0.05, 0.2, -0.4, 1.0]])))
    >>> solver = PreparedLM(model)
    >>> a, b = solver.solve(C), solve_lm(C, model)
    >>> bool(np.array_equal(a.pose_vectors, b.pose_vectors)), a.status
    (True, array([0], dtype=int8))
    """

    #: the kernels called here start no parallel region (the pipeline need not confine them)
    serial = True
    #: the calls take ``explore=False`` (skip the extra starts above ``explore_above``; the
    #: live pipeline does so for distorted samples, which it does not send)
    explore_optional = True

    def __init__(self, model=None, options: SolveOptions | None = None, **overrides):
        model = _check_model(DipoleModel.concentric() if model is None else model)
        options = SolveOptions.of(options, overrides)     # checked there, once
        kw = options.lm_kwargs()
        hemisphere, max_iter = kw["hemisphere"], kw["max_iter"]
        retry_resnorm, concentric_model = kw["retry_resnorm"], kw["concentric_model"]
        max_rel, max_range = check_validity_options(kw["max_relative_residual"],
                                                    kw["max_range"])
        self.options = options
        self.model = model
        self.n_source, self.n_sensor = model.n_source, model.n_sensor
        self.dof = 5 if model.n_sensor == 1 else 6
        self.hemisphere = hemisphere
        # one hemisphere for all samples: its row, checked now
        self._hrow = hemisphere_vectors(hemisphere, 1)[0] if _uniform(hemisphere) else None
        self.box = pack_box(*_bounds(kw["bounds"]))
        if retry_resnorm is None:
            retry_res, retry_rel = np.inf, max_rel
        else:
            retry_res, retry_rel = float(retry_resnorm), np.inf
        self.retry_resnorm = retry_resnorm
        retries = bool(kw["retries"]) and (np.isfinite(retry_res) or np.isfinite(retry_rel))
        explore_above = kw["explore_above"]
        self.conc = _concentric_for(model, concentric_model)
        self.concentric_given = concentric_model is not None
        self.mdl = pack_model(model)
        self.opts = pack_options(max_iter=int(max_iter), xtol=kw["xtol"],
                                 retry_resnorm=retry_res, retry_relative=retry_rel,
                                 ambiguity_tol=kw["ambiguity_tol"],
                                 max_relative_residual=max_rel, max_range=max_range,
                                 retries=retries, five_dof=model.n_sensor == 1,
                                 use_closed_form=self.conc is not None,
                                 cf_gain=(self.conc or model).gain, rank_tol=RANK_TOL)
        self.explore = (None if explore_above is None or retry_resnorm is not None
                        else float(explore_above))
        # the cold start's restart level: the exploration level, else the retry test's
        self._level = self.explore if self.explore is not None else retry_rel
        # per-call options of ``solver(couplings)``
        self._initial = "kim18" if options.initial is None else options.initial
        self._per_call = options.covariance or options.fallback is not None
        self._shape = (model.n_source, model.n_sensor)
        self._W = None
        # the invariant table of the cold start (built at the first cold solve that uses it)
        self._table = None
        # per-call constants of warm starts, grown as needed: norms "compute here" (-1) and
        # the uniform hemisphere's rows
        self._neg = np.empty(0)
        self._hrows = np.empty((0, 3))

    @property
    def cold_start(self) -> str:
        """The start of a sample with no prior pose (the first one tracked, one after a
        failure): ``'kim18'`` where a concentric start model exists, else ``'multistart'``."""
        from ._series import cold_start_name

        return cold_start_name(self)

    def _use_table(self) -> bool:
        """The Kim18 start is the cold start of the invariant table (``_table_solve``):
        :func:`uses_invariant_table`."""
        return uses_invariant_table(self.model, self.concentric_given, self.retry_resnorm)

    def _constants(self, n: int):
        if self._neg.shape[0] < n:
            m = max(n, 2 * self._neg.shape[0], 64)
            self._neg = np.full(m, -1.0)
            self._hrows = np.ascontiguousarray(np.broadcast_to(
                self._hrow if self._hrow is not None else np.zeros(3), (m, 3)))
        return self._neg[:n], self._hrows[:n]

    def _nvec(self, n: int) -> np.ndarray:
        if self._hrow is None:
            return hemisphere_vectors(self.hemisphere, n)
        return self._constants(n)[1]

    def _table_level(self) -> float:
        """The table start's restart level: :data:`TABLE_RESTART_LEVEL` under the exploration
        level while exploring; without exploration (``explore_above=None``) the retry test's,
        as before (no residual-driven restarts beyond it)."""
        if self.explore is None:
            return self._level
        return min(self._level, TABLE_RESTART_LEVEL)

    def __call__(self, couplings, initial=None, *, explore: bool = True) -> SolveResult:
        C = couplings
        if initial is None or self._per_call:  # the options' start: the path of solve_lm
            return self.solve(C, self._initial if initial is None else initial,
                              covariance=self.options.covariance,
                              fallback=self.options.fallback, explore=explore)
        if (isinstance(initial, np.ndarray) and isinstance(C, np.ndarray)
                and C.dtype == np.float64 and C.ndim == 3 and C.shape[1:] == self._shape
                and initial.shape == (C.shape[0], 6) and initial.dtype == np.float64
                and self._hrow is not None and C.shape[0] < _SMALL):
            return self.warm(np.ascontiguousarray(C), np.ascontiguousarray(initial),
                             explore=explore)
        return self.solve(C, initial, explore=explore)

    def warm(self, C, init, *, explore: bool = True) -> SolveResult:
        """``solve(C, initial=init)`` for C-contiguous real float64 couplings ``C`` (N, n_so,
        n_se) of the model's shape and start pose vectors ``init`` (N, 6), fewer than 512
        samples, one hemisphere for all: the compiled kernel is called directly."""
        n = C.shape[0]
        cnorm, nvec = self._constants(n)
        out = new_outputs(n)
        lm_batch(self.mdl, C, cnorm, init, nvec, self.box, self.opts, out)
        return self._after(result_from_outputs(out, "lm"), C, cnorm, nvec, None,
                           explore=explore)

    def solve(self, couplings, initial="kim18", *, covariance=False,
              fallback=None, explore: bool = True) -> SolveResult:
        """:func:`openemt.solve.solve_lm` of ``couplings`` (see there for ``initial``,
        ``covariance`` and ``fallback``); ``explore=False`` skips the extra starts of samples
        above ``explore_above`` (then no longer :func:`~openemt.solve.solve_lm`'s result)."""
        model, conc = self.model, self.conc
        C, cnorm = check_couplings(couplings, model.n_source, model.n_sensor)
        n = C.shape[0]
        nvec = self._nvec(n)
        mdl, box, opts = self.mdl, self.box, self.opts
        if isinstance(initial, str) and initial == "track":
            first = _first_start(C, cnorm, model, conc, mdl, nvec, box, opts, self.hemisphere)
            if self._W is None:
                self._W = whitening(conc) if conc is not None else np.zeros((2, 3, 3))
            out = new_outputs(n)
            lm_track(mdl, C, cnorm, np.ascontiguousarray(first, dtype=np.float64), self._W,
                     nvec, box, opts, out)
            result = result_from_outputs(out, "lm")
        else:
            if isinstance(initial, str):
                if initial in _CLOSED:
                    if conc is None:
                        raise InputError(f"expected a 3x3 model or `concentric_model` for the "
                                         f"{initial!r} start, got a {model.n_source}x"
                                         f"{model.n_sensor} model; use initial='multistart'")
                    cf_hemi = (self.hemisphere if self.hemisphere is not None
                               else DEFAULT_HEMISPHERE)
                    if initial == "kim18" and self._use_table():
                        if self._table is None:
                            self._table = table_for(model)
                        result, settled = _table_solve(C, cnorm, couplings, model, conc,
                                                       cf_hemi, mdl, nvec, box, opts,
                                                       self._table, self._table_level())
                        return self._finish(result, C, cnorm, nvec, fallback, explore,
                                            covariance, settled)
                    init = closed_form_start(couplings, model, conc, initial, cf_hemi,
                                              self.concentric_given)
                elif initial == "multistart":
                    init = _multistart_init(C, cnorm, mdl, model, nvec, box, opts)
                else:
                    raise InputError(f"expected `initial` in 'kim18', 'svd', 'kuipers', "
                                     f"'track', 'multistart' or pose vectors (N, 6), got "
                                     f"{initial!r}")
            else:
                init = check_pose_vectors(initial, "initial")
                if init.shape == (6,):
                    init = np.tile(init, (n, 1))
                if init.shape != (n, 6):
                    raise InputError(f"expected `initial` pose vectors of shape ({n}, 6) or "
                                     f"(6,), got {init.shape}")
            result = _run_batch(C, cnorm, init, mdl, nvec, box, opts)
        return self._finish(result, C, cnorm, nvec, fallback, explore, covariance)

    def _finish(self, result, C, cnorm, nvec, fallback, explore, covariance,
                settled=None) -> SolveResult:
        result = self._after(result, C, cnorm, nvec, fallback, explore=explore,
                             settled=settled)
        if covariance:
            from ._crb import solver_covariance

            result = result.replace(covariance=solver_covariance(self.model, result, C, cnorm))
        return result

    def _after(self, result, C, cnorm, nvec, fallback, *, explore=True,
               settled=None) -> SolveResult:
        """The steps after the first solve: more starts for samples above the exploration
        level (unless not ``explore``; no multi-start grid for the rows of the mask
        ``settled``, which the cold start already solved from two starts to one minimum), the
        optional multi-start fallback, the 5-DOF canonical rotation."""
        model, mdl, box, opts = self.model, self.mdl, self.box, self.opts
        level = self.explore if explore else None
        if level is not None and (result.relative_residual > level).any():
            redo = np.flatnonzero((result.relative_residual > level)
                                  & (result.status != Status.INVALID_INPUT))
            if redo.size:
                # the sign-flip retries from the solution found, then the multi-start grid
                flips = opts.copy()
                flips[O_RETRIES] = 1.0
                flips[O_RETRY_RELATIVE] = level
                flips[O_RETRY_RESNORM] = np.inf
                sub = (C[redo], cnorm[redo])
                again = _run_batch(*sub, result.pose_vectors[redo], mdl, nvec[redo], box,
                                   flips)
                result = _keep_better(result, redo, again)
                redo = redo[result.relative_residual[redo] > level]
                if settled is not None:
                    redo = redo[~settled[redo]]
                if redo.size:
                    init2 = _multistart_init(C[redo], cnorm[redo], mdl, model, nvec[redo], box,
                                             opts)
                    result = _keep_better(result, redo, _run_batch(
                        C[redo], cnorm[redo], init2, mdl, nvec[redo], box, opts))
        if fallback is not None:
            if fallback != "multistart":
                raise InputError(f"expected fallback None or 'multistart', got {fallback!r}")
            redo = np.flatnonzero(np.isin(result.status, (Status.MAX_ITERATIONS,
                                                          Status.NOT_CONVERGED)))
            if redo.size:
                init2 = _multistart_init(C[redo], cnorm[redo], mdl, model, nvec[redo], box,
                                         opts)
                again = _run_batch(C[redo], cnorm[redo], init2, mdl, nvec[redo], box, opts)
                result = _keep_better(result, redo, again)
        if model.n_sensor == 1:
            result = canonical_5dof(result, model)
        return result
