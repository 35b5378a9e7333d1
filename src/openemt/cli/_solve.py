"""``openemt solve``: poses from a dataset file and a calibration, streamed in blocks (the
workflow is :func:`openemt.solve.solve_file`)."""

from __future__ import annotations

import sys
import time

__all__ = ["register", "run"]


def register(subparsers) -> None:
    from ..solve import SolveFileOptions
    from ._common import add_command

    p = add_command(
        subparsers, "solve", run, SolveFileOptions,
        description="Solve sensor poses for every row of an openemt HDF5 dataset with a "
                    "calibration's model and write them to an HDF5 poses file. Large files are "
                    "streamed in blocks (Dask; local by default, --scheduler for a cluster).")
    p.add_argument("--progress", action="store_true",
                   help="a line on stderr about every second: rows done, rate and time left "
                        "(across the cluster with --scheduler)")


def run(args) -> int:
    from .._compile_notice import announce_compile, solve_kernels
    from ..solve import SolveFileOptions, solve_file
    from ._common import emit, options_from

    progress = _Progress(args)

    def start(n, model, cold_start_table):
        what, kernels = solve_kernels(model, cold_start_table)
        announce_compile(args, what, kernels=kernels)
        progress.start(n)

    try:
        result = solve_file(options_from(SolveFileOptions, args), on_start=start,
                            on_block=progress.update)
    finally:
        progress.close()
    emit(args, result.to_dict(), result.lines())
    return 0


class _Progress:
    """Progress of a solve on stderr: with ``--progress`` a plain line about every second
    (rows done, rate, time left; also when stderr is not a terminal), else the progress bar
    of the other commands (terminals only)."""

    def __init__(self, args):
        self.args, self.bar, self.total, self.done = args, None, 0, 0
        self.lines = bool(getattr(args, "progress", False)) and not args.quiet

    def start(self, total: int) -> None:
        from ._common import progress

        self.total, self.t0 = int(total), time.perf_counter()
        self.last = self.t0
        if not self.lines:
            self.bar = progress(total=self.total, desc="solve", args=self.args, unit="pose")

    def update(self, rows: int, _summary=None) -> None:
        self.done += rows
        if self.bar is not None:
            self.bar.update(rows)
            return
        now = time.perf_counter()
        if self.lines and (now - self.last >= 1.0 or self.done >= self.total):
            self.last = now
            rate = self.done / max(now - self.t0, 1e-9)
            left = (self.total - self.done) / rate if rate > 0 else float("inf")
            print(f"solve: {self.done}/{self.total} rows "
                  f"({100 * self.done / max(self.total, 1):.1f} %), {rate:,.0f} rows/s, "
                  f"{left:.1f} s left", file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
