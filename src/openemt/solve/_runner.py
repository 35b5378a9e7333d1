"""High-level solving with a calibration, and chunked (Dask) streaming of large datasets."""

from __future__ import annotations

import numpy as np

from .._errors import InputError
from ..io import Calibration
from ._factory import SOLVERS, apply_position_correction, prepare
from ._hemisphere import DEFAULT_HEMISPHERE
from ._options import SolveOptions
from ._result import SolveResult
from ._series import solve_series

__all__ = ["SOLVERS", "apply_position_correction", "solve", "solve_chunks"]


def solve(couplings, calibration: Calibration, *, solver: str = "lm",
          hemisphere=DEFAULT_HEMISPHERE,
          apply_correction: bool = True, concentric_calibration: Calibration | None = None,
          **options) -> SolveResult:
    """Solve poses with a calibration's model, then apply its output correction if present.

    Parameters
    ----------
    couplings : ndarray, shape (N, n_source, n_sensor)
        Signed real couplings (or complex phasors, see :func:`solve_lm`).
    calibration : Calibration
        Provides the model and, optionally, ``linear_correction``. Octupole terms of an
        improved calibration (:attr:`Calibration.coupling_model`) are used by refining the
        dipole solution for them (:func:`refine_poses`).
    solver : {'lm', 'svd', 'kuipers', 'kim18'}
        ``svd``, ``kuipers`` and ``kim18`` need a concentric 3x3 model.
    hemisphere : see :func:`solve_lm`
        Default ``'+x'``; ``None`` (LM only) for no constraint.
    apply_correction : bool
        Apply ``calibration.linear_correction`` to the positions when present.
    concentric_calibration : Calibration, optional
        Its model starts the LM solver (ILEMT's ``concentric_cal_file``).
    **options
        Passed to the solver (``max_iter``, ``max_relative_residual``, ``max_range``,
        ``bounds``, ``initial``, ...). ``max_relative_residual`` also judges the refinement
        under an improved calibration's octupole terms.
    """
    if not isinstance(calibration, Calibration):
        raise TypeError(f"expected a Calibration, got {type(calibration).__name__}")
    options = SolveOptions.of(None, options)
    prepared = _prepared(calibration, solver, hemisphere, apply_correction,
                         concentric_calibration, options)
    if _is_series(solver, options):
        return solve_series(prepared, couplings, for_rows=_subsets(
            calibration, solver, hemisphere, apply_correction, concentric_calibration,
            options))[0]
    return prepared(couplings)


def _is_series(solver: str, options: SolveOptions) -> bool:
    """The LM with ``initial='track'``: rows solved as one time series
    (:func:`openemt.solve._series.solve_series`, with its cold retries)."""
    return solver == "lm" and isinstance(options.initial, str) and options.initial == "track"


def _subsets(calibration, solver, hemisphere, apply_correction, concentric_calibration,
             options):
    """``for_rows`` of :func:`solve_series` when the hemisphere is given per row, else None."""
    if hemisphere is None or isinstance(hemisphere, str):
        return None
    hemi = np.asarray(hemisphere)
    if not (hemi.ndim == 2 or (hemi.ndim == 1 and hemi.dtype.kind in "UO")):
        return None
    return lambda rows: _prepared(calibration, solver, hemi[rows], apply_correction,
                                  concentric_calibration, options)


def _prepared(calibration, solver, hemisphere, apply_correction, concentric_calibration,
              options: SolveOptions):
    """:func:`prepare` with the arguments of :func:`solve` (``hemisphere`` None: no constraint
    for LM, ``'+x'`` for a closed form)."""
    if solver not in SOLVERS:
        raise InputError(f"expected solver in {SOLVERS}, got {solver!r}")
    over = {"hemisphere": hemisphere}
    if solver == "lm" and concentric_calibration is not None \
            and options.concentric_model is None:
        over["concentric_model"] = concentric_calibration.model
    return prepare(calibration, options.replace(**over), solver=solver,
                   apply_correction=apply_correction)


def _per_row(hemisphere, n: int):
    """The row-sliceable ``(n, 3)`` hemisphere directions, or None for one spec for all rows
    (the shape is read from ``.shape``, so a lazy object is never iterated)."""
    if hemisphere is None or isinstance(hemisphere, str):
        return None
    shape = getattr(hemisphere, "shape", None)
    if shape is None:
        hemisphere = np.asarray(hemisphere)
        shape = hemisphere.shape
    if len(shape) < 2:
        return None
    if tuple(shape) != (n, 3):
        raise InputError(f"expected one hemisphere for all rows or one per row, shape ({n}, 3), "
                         f"got {tuple(shape)}")
    return hemisphere


class BlockPlan:
    """What both block runners (:func:`solve_chunks`, :func:`openemt.solve.solve_to_file`)
    share: the inputs checked once, the blocks, each block's hemispheres, and the solver of a
    block, prepared once per run in each process (or per block for per-row hemispheres)."""

    def __init__(self, n, calibration, chunk_rows, solver, hemisphere, apply_correction,
                 options):
        import uuid

        self.n, self.rows = int(n), int(chunk_rows)
        if self.rows < 1:
            raise InputError(f"expected a positive `chunk_rows`, got {chunk_rows!r}")
        self.per_row = _per_row(hemisphere, self.n)
        self.hemisphere = hemisphere
        opts = SolveOptions.of(None, options)              # checked once, before any block
        # one solver for all blocks (also checks the calibration and solver before any block)
        whole = _prepared(calibration, solver, hemisphere if self.per_row is None else None,
                          apply_correction, None, opts)
        self.whole = whole if self.per_row is None else None
        self.spec = (calibration, solver, apply_correction, opts)
        self.series = _is_series(solver, opts)
        self.token = uuid.uuid4().hex
        self.starts = list(range(0, self.n, self.rows))

    def block(self, s: int):
        """(start, stop, hemisphere of the block's rows) of the block starting at ``s``."""
        e = min(self.n, s + self.rows)
        hemi = self.hemisphere if self.per_row is None else \
            np.asarray(self.per_row[s:e], dtype=np.float64)
        return s, e, hemi


#: per process: the prepared solver of the current run (token -> solver)
_SOLVERS: dict = {}


def solve_rows(C, spec, hemi, series: bool, token, prepared=None):
    """``(SolveResult, cold retries)`` of the rows ``C`` of one block (``spec`` and ``token``
    of a :class:`BlockPlan`; ``prepared`` skips the solver lookup, in the planning process)."""
    calibration, name, apply_correction, options = spec
    if prepared is None:
        per_row = isinstance(hemi, np.ndarray) and hemi.ndim == 2
        prepared = None if per_row else _SOLVERS.get(token)
        if prepared is None:
            prepared = _prepared(calibration, name, hemi, apply_correction, None, options)
            if not per_row:
                _SOLVERS.clear()
                _SOLVERS[token] = prepared
    if series:
        return solve_series(prepared, C, for_rows=_subsets(
            calibration, name, hemi, apply_correction, None, options))
    return prepared(C), 0


def _chunk(couplings, s, e, spec, hemi, series, token, prepared=None):
    return solve_rows(couplings[s:e], spec, hemi, series, token, prepared)[0]


def solve_chunks(couplings, calibration: Calibration, *, chunk_rows: int = 262144,
                 scheduler=None, max_in_flight: int = 2, solver: str = "lm",
                 hemisphere=DEFAULT_HEMISPHERE,
                 apply_correction: bool = True, **options):
    """Solve a (possibly larger-than-memory) coupling array block by block.

    Yields ``(start, SolveResult)`` in row order, so the caller can write each block out and
    drop it; at most ``max_in_flight`` blocks are held at once. On a cluster every result
    comes back through the client: :func:`openemt.solve.solve_to_file` (what ``openemt
    solve`` runs) has the workers write their blocks into the output file instead.
    ``initial='track'`` (LM) solves each block as a time series with cold retries
    (:func:`openemt.solve.solve_series`).

    Parameters
    ----------
    couplings : array-like, shape (N, n_source, n_sensor)
        Anything sliceable by rows: an ndarray, an h5py dataset, or
        :class:`openemt.io.CouplingReader` (pickles by path, so it works on a cluster).
    chunk_rows : int
        Rows per block (a 3x3 block of 262144 rows is ~19 MB of couplings, ~50 MB of results).
    scheduler : None, str or dask.distributed.Client
        ``None``: blocks are computed one after another in this process (Dask's synchronous
        scheduler; the compiled solver itself uses all cores). A ``dask.distributed`` scheduler
        address (``'tcp://host:8786'``) or a ``Client``: blocks are submitted to that cluster,
        ``max_in_flight`` at a time.
    solver, apply_correction, **options
        As in :func:`solve`.
    hemisphere : None, str, array_like (3,) or row-sliceable (N, 3)
        One spec for all rows, or one direction per row: an ``(N, 3)`` array or any object
        with that ``shape`` whose ``[start:stop]`` gives the rows' directions (read block by
        block, like the couplings).
    """
    if max_in_flight < 1:
        raise InputError(f"expected `max_in_flight` >= 1, got {max_in_flight!r}")
    plan = BlockPlan(len(couplings), calibration, chunk_rows, solver, hemisphere,
                     apply_correction, options)
    if scheduler is None:
        for s in plan.starts:
            s, e, hemi = plan.block(s)
            yield s, _chunk(couplings, s, e, plan.spec, hemi, plan.series, plan.token,
                            plan.whole)
        return
    from ._dask import cluster, run_blocks

    def submit(k):
        s, e, hemi = plan.block(plan.starts[k])
        return client.submit(_chunk, couplings, s, e, plan.spec, hemi, plan.series,
                             plan.token, pure=False)

    with cluster(scheduler) as client:
        for k, res in run_blocks(client, submit, len(plan.starts),
                                 max_in_flight=max_in_flight):
            yield plan.starts[k], res
