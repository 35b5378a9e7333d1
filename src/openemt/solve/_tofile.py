"""Solve a dataset block by block straight into a poses file, in this process or on a Dask
cluster whose workers read their own blocks from the input file and write their own blocks of
the output, so that the client moves no coupling or pose data.

The output is laid out first (:class:`~openemt.solve._output.PoseLayout`: contiguous datasets
whose storage is allocated up front, in a temporary file beside the target), then every block
task reads its rows (:class:`openemt.io.CouplingReader`, through the safe reader
:func:`openemt.io._h5safe.open_h5`, opened once per worker process), solves them and writes
its rows at their offsets (:func:`openemt.io._h5write.write_at`). The client only gathers per
block status counts. The file becomes the output when every block is written
(:func:`openemt.io._h5write.atomic_h5_layout`); any failure (a bad block, a full disk, Ctrl-C)
leaves no file. Blocks are independent, so every scheduler gives the same file contents.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field

import numpy as np

from ._hemisphere import DEFAULT_HEMISPHERE
from ._result import Status

__all__ = ["FileSolveSummary", "solve_to_file"]


@dataclass
class FileSolveSummary:
    """What :func:`solve_to_file` gathered: ``counts`` per status code, per row group
    (``group_counts`` (K, n_status), sums and numbers of finite relative residuals
    ``group_residual_sum`` / ``group_residual_n``), ``cold_retries`` (samples of a
    warm-started series solved again cold), ``n_samples``, ``elapsed_s``, ``blocks``, per
    block the peak resident memory of the process that solved it (``block_rss_mb``), and the
    process CPU and wall seconds of all block tasks together (``block_cpu_s``,
    ``block_wall_s``)."""

    n_samples: int
    counts: np.ndarray
    group_counts: np.ndarray
    group_residual_sum: np.ndarray
    group_residual_n: np.ndarray
    cold_retries: int = 0
    elapsed_s: float = 0.0
    blocks: int = 0
    block_rss_mb: list = field(default_factory=list)
    block_cpu_s: float = 0.0
    block_wall_s: float = 0.0

    def add(self, part: dict) -> None:
        self.counts += part["counts"]
        self.group_counts += part["group_counts"]
        self.group_residual_sum += part["group_residual_sum"]
        self.group_residual_n += part["group_residual_n"]
        self.cold_retries += part["cold_retries"]
        self.blocks += 1
        self.block_rss_mb.append(part["rss_mb"])
        self.block_cpu_s += part["cpu_s"]
        self.block_wall_s += part["wall_s"]


# per process: open readers (path, real, size, mtime) -> CouplingReader; a worker opens and
# checks the input once
_READERS: dict = {}


def _peak_rss_mb() -> float:
    import resource
    import sys

    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / (1 << 20) if sys.platform == "darwin" else peak / 1024


def _reader(source):
    """The rows' source: an array-like as given, or a ``("file", path, real)`` reference
    opened once per process."""
    if not (isinstance(source, tuple) and source and source[0] == "file"):
        return source
    from ..io import open_dataset_couplings

    _, path, real = source
    st = os.stat(path)
    key = (str(path), bool(real), st.st_size, st.st_mtime_ns)
    reader = _READERS.get(key)
    if reader is None:
        for old in _READERS.values():
            old.close()
        _READERS.clear()
        reader = _READERS[key] = open_dataset_couplings(path, real=real)
    return reader


def solve_block(source, start: int, stop: int, spec, hemi, series: bool, token,
                tmp, layout, groups, n_groups: int, prepared=None) -> dict:
    """Solve rows ``start:stop`` and write them into the laid-out file ``tmp``; return the
    block's tallies (counts per status and per row group). ``prepared`` skips the solver
    lookup (the in-process path)."""
    from ._runner import solve_rows

    c0, w0 = time.process_time(), time.perf_counter()
    res, cold = solve_rows(_reader(source)[start:stop], spec, hemi, series, token, prepared)
    layout.write(tmp, start, res)
    n_status = len(Status)
    st = res.status.astype(np.int64)
    g = np.zeros(len(res), np.int64) if groups is None else np.asarray(groups, np.int64)
    gc = np.zeros((n_groups, n_status), np.int64)
    np.add.at(gc, (g, st), 1)
    rs = np.zeros((n_groups, n_status))
    rn = np.zeros((n_groups, n_status), np.int64)
    rr = res.relative_residual
    if rr is not None:
        ok = np.isfinite(rr)
        np.add.at(rs, (g[ok], st[ok]), rr[ok])
        np.add.at(rn, (g[ok], st[ok]), 1)
    return {"counts": np.bincount(st, minlength=n_status), "group_counts": gc,
            "group_residual_sum": rs, "group_residual_n": rn, "cold_retries": cold,
            "rss_mb": _peak_rss_mb(), "rows": len(res),
            "cpu_s": time.process_time() - c0, "wall_s": time.perf_counter() - w0}


def solve_to_file(couplings, calibration, output, *, chunk_rows: int = 262144,
                  scheduler=None, solver: str = "lm", hemisphere=DEFAULT_HEMISPHERE,
                  apply_correction: bool = True, meta: dict | None = None, groups=None,
                  on_block=None, solver_name: str | None = None,
                  **options) -> FileSolveSummary:
    """Solve every row of ``couplings`` and write the poses file ``output`` (the layout of
    :class:`~openemt.solve._output.PoseLayout`, docs/solve.md#command-line), block by block.

    Parameters
    ----------
    couplings : CouplingReader or array-like (N, n_source, n_sensor)
        A :class:`openemt.io.CouplingReader`: each block's rows are read where the block is
        solved (on a cluster the workers open the file themselves, so they must see it, and
        the output's folder). Any other row-sliceable array is sliced here.
    calibration, solver, apply_correction, **options
        As in :func:`openemt.solve.solve`. ``initial='track'`` (LM) solves each block as a
        time series: warm-started from sample to sample, failed or suspicious samples solved
        again cold (:func:`openemt.solve._series.solve_series`); the first sample of each
        block starts cold, so blocks stay independent.
    chunk_rows : int
        Rows per block: the memory of a worker is bounded by one block (a 3x3 block of
        262144 rows: about 19 MB of couplings and 50 MB of results).
    scheduler : None, str or dask.distributed.Client
        None: the blocks are solved one after another in this process. A scheduler address or
        a ``Client``: every block is a task of that cluster.
    hemisphere : as :func:`openemt.solve.solve_chunks` (one spec, or one direction per row)
    meta : dict, optional
        The poses file's ``meta`` attribute.
    groups : (index, n_groups), optional
        A row-sliceable group index of every row (e.g. its fixture pair) and the number of
        groups: the status counts and relative residual sums are also gathered per group.
    on_block : callable, optional
        ``on_block(rows, summary)`` after each finished block (in completion order), e.g. a
        progress line.
    solver_name : str, optional
        The solver's name in the file (default ``solver``).
    """
    from ..io import CouplingReader
    from ..io._h5write import atomic_h5_layout
    from ._output import PoseLayout
    from ._runner import BlockPlan

    n = len(couplings)
    plan = BlockPlan(n, calibration, chunk_rows, solver, hemisphere, apply_correction,
                     options)
    index, n_groups = (None, 1) if groups is None else groups
    source = ("file", os.path.abspath(couplings.path), couplings.real) \
        if isinstance(couplings, CouplingReader) else couplings
    summary = FileSolveSummary(n, np.zeros(len(Status), np.int64),
                               np.zeros((n_groups, len(Status)), np.int64),
                               np.zeros((n_groups, len(Status))),
                               np.zeros((n_groups, len(Status)), np.int64))

    def block_args(k):
        s, e, hemi = plan.block(plan.starts[k])
        g = None if index is None else np.asarray(index[s:e])
        return s, e, plan.spec, hemi, plan.series, plan.token, tmp, layout, g, n_groups

    def done(part):
        summary.add(part)
        if on_block is not None:
            on_block(part["rows"], summary)

    t0 = time.perf_counter()
    with atomic_h5_layout(output, PoseLayout.build(n, solver_name or solver, meta)) \
            as (tmp, layout):
        tmp = os.path.abspath(tmp)           # workers may run in another folder
        if scheduler is None:
            for k in range(len(plan.starts)):
                done(solve_block(couplings, *block_args(k), prepared=plan.whole))
        else:
            from ._dask import cluster, run_blocks

            with cluster(scheduler) as client:
                for _, part in run_blocks(
                        client, lambda k: client.submit(solve_block, source, *block_args(k),
                                                        pure=False),
                        len(plan.starts), ordered=False):
                    done(part)
        summary.elapsed_s = time.perf_counter() - t0
    return summary
