"""``openemt solve``: poses from a dataset file and a calibration, streamed in blocks."""

from __future__ import annotations

import time
from pathlib import Path

from .._constants import MAX_RANGE_M, MAX_RELATIVE_RESIDUAL
from .._errors import InputError

__all__ = ["register", "run"]


def register(subparsers) -> None:
    from . import command_help
    from ._common import add_common

    p = subparsers.add_parser(
        "solve", help=command_help("solve"),
        description="Solve sensor poses for every row of an openemt HDF5 dataset with a "
                    "calibration's model and write them to an HDF5 poses file. Large files are "
                    "streamed in blocks (Dask; local by default, --scheduler for a cluster).")
    p.add_argument("dataset", type=Path, help="openemt dataset HDF5 file")
    p.add_argument("--calibration", "-c", type=Path, required=True,
                   help="calibration (openemt JSON or ILEMT .mat)")
    p.add_argument("--solver", choices=("lm", "svd", "kuipers", "kim18"), default="lm")
    p.add_argument("-o", "--output", type=Path, required=True, help="output poses HDF5 file")
    p.add_argument("--hemisphere", default="+x",
                   help="hemisphere of the sensor: +x, -x, +y, -y, +z, -z (default +x); "
                        "'none': unconstrained (lm only)")
    p.add_argument("--concentric-calibration", type=Path, default=None,
                   help="concentric calibration whose Kim18 solution starts the LM solver")
    p.add_argument("--initial", default="kim18",
                   choices=("kim18", "svd", "kuipers", "track", "multistart"),
                   help="LM start (default kim18)")
    p.add_argument("--max-iter", type=int, default=100)
    p.add_argument("--max-relative-residual", type=float, default=MAX_RELATIVE_RESIDUAL,
                   help="largest relative coupling residual ||C_pred - C||/||C|| of a "
                        f"converged pose (default {MAX_RELATIVE_RESIDUAL}; all solvers)")
    p.add_argument("--max-range", type=float, default=MAX_RANGE_M,
                   help="largest plausible sensor distance from the source in m (default "
                        f"{MAX_RANGE_M}); farther poses are out_of_volume")
    p.add_argument("--bounds", type=float, default=None,
                   help="position box half-width in m (LM); solutions on it are out_of_volume")
    p.add_argument("--no-correction", action="store_true",
                   help="do not apply the calibration's linear output correction")
    p.add_argument("--chunk-rows", type=int, default=262144, help="rows per block")
    p.add_argument("--scheduler", default=None,
                   help="dask.distributed scheduler address (default: local, in process)")
    add_common(p)
    p.set_defaults(func=run)


def run(args) -> int:

    from ._solve_planar import read_board_calibration, solve_board
    board = read_board_calibration(args.calibration)
    if board is not None:  # a finite-coil board: the 5-DOF solver (docs/planar.md#solving)
        return solve_board(args, board)

    from ..io import open_dataset_couplings, read_calibration
    from ..solve import solve_chunks
    from ._common import emit

    cal = read_calibration(args.calibration)
    options = {"max_relative_residual": args.max_relative_residual,
               "max_range": args.max_range}
    hemisphere = None if args.hemisphere.lower() == "none" else args.hemisphere
    if hemisphere is None and args.solver != "lm":
        raise InputError(f"expected a hemisphere such as +x for --solver {args.solver}, got "
                         f"'none'")
    if args.solver == "lm":
        options.update(max_iter=args.max_iter, bounds=args.bounds, initial=args.initial)
        if args.concentric_calibration is not None:
            options["concentric_model"] = read_calibration(args.concentric_calibration).model
    elif args.bounds is not None or args.concentric_calibration is not None:
        raise InputError(f"expected --bounds/--concentric-calibration only with --solver lm, "
                         f"got --solver {args.solver}")
    if args.chunk_rows < 1:
        raise InputError(f"expected a positive --chunk-rows, got {args.chunk_rows}")
    t0 = time.perf_counter()
    with open_dataset_couplings(args.dataset) as reader:
        n = reader.shape[0]
        if (reader.shape[1], reader.shape[2]) != (cal.model.n_source, cal.model.n_sensor):
            raise InputError(f"expected couplings of shape (N, {cal.model.n_source}, "
                             f"{cal.model.n_sensor}) for this calibration, got {reader.shape}")
        meta = {"dataset": str(args.dataset), "calibration": str(args.calibration),
                "hemisphere": args.hemisphere,
                "correction_applied": bool(cal.linear_correction is not None
                                           and not args.no_correction)}
        chunks = solve_chunks(reader, cal, chunk_rows=args.chunk_rows,
                              scheduler=args.scheduler, solver=args.solver,
                              hemisphere=hemisphere, apply_correction=not args.no_correction,
                              **options)
        writer = write_solved(args, n, args.solver, meta, chunks)
    elapsed = time.perf_counter() - t0
    counts = writer.status_counts()
    summary = {"dataset": str(args.dataset), "calibration": str(args.calibration),
               "output": str(args.output), "solver": args.solver, "n_samples": n,
               "status_counts": counts, "correction_applied": meta["correction_applied"],
               "elapsed_s": elapsed, "poses_per_s": n / elapsed if elapsed > 0 else None}
    human = [f"solved {n} samples with {args.solver} in {elapsed:.2f} s -> {args.output}",
             "status: " + ", ".join(f"{k} {v}" for k, v in counts.items() if v)]
    emit(args, summary, human)
    return 0


def write_solved(args, n: int, solver: str, meta: dict, chunks):
    """Write the ``(start, SolveResult)`` blocks of ``chunks`` to the poses file ``args.output``
    (atomically, with a progress bar); returns the :class:`~openemt.solve._output.PoseWriter`,
    whose status counts outlive the file."""
    from ..io import atomic_h5
    from ..solve._output import PoseWriter
    from ._common import progress

    with atomic_h5(args.output) as f:
        writer = PoseWriter(f, n, solver, meta)
        with progress(total=n, desc="solve", args=args, unit="pose") as bar:
            for start, res in chunks:
                writer.write(start, res)
                bar.update(len(res))
    return writer
