"""``openemt solve`` with a finite-coil (board) calibration: the 5-DOF planar solver, block by
block (warm-started tracking; the first sample of a block and any sample after a failure start
cold from the seed grid). The sensor is on the board's front side (its coils' normal);
``--hemisphere`` and ``--initial`` do not apply. See docs/planar.md#solving."""

from __future__ import annotations

import time

from .._errors import InputError

__all__ = ["read_board_calibration", "solve_board"]


def read_board_calibration(path):
    """The finite-coil calibration in ``path``, or None for any other calibration file."""
    from pathlib import Path

    from ..io._board_calfile import board_calibration_from_dict, is_board_calibration
    from ..io._jsontext import load_json_file

    path = Path(path)
    if path.suffix.lower() == ".mat" or not path.is_file():
        return None
    try:
        doc = load_json_file(path, "an openemt calibration JSON file")
    except ValueError:
        return None                 # not JSON: the dipole reader reports it
    return board_calibration_from_dict(doc, path.name) if is_board_calibration(doc) else None


def solve_board(args, cal) -> int:
    from .._compile_notice import PLANAR_KERNELS, announce_compile
    from ..io import open_dataset_couplings
    from ..io._h5safe import open_h5
    from ..solve import prepare
    from ._common import emit, write_solved

    if args.solver != "lm":
        raise InputError(f"expected --solver lm with a finite-coil calibration, got "
                         f"--solver {args.solver}")
    if args.concentric_calibration is not None:
        raise InputError("expected no --concentric-calibration with a finite-coil calibration "
                         "(the 5-DOF solver starts from its seed grid), got one")
    if args.chunk_rows < 1:
        raise InputError(f"expected a positive --chunk-rows, got {args.chunk_rows}")
    model = cal.model
    # the validity rule's thresholds where the command has them; the side of the board is
    # its coils' normal (a --hemisphere default meant for dipole sources does not apply)
    rule = {k: getattr(args, k) for k in ("max_relative_residual", "max_range")
            if getattr(args, k, None) is not None}
    solver = prepare(cal, initial="track", max_iter=args.max_iter, bounds=args.bounds, **rule)
    t0 = time.perf_counter()
    with open_dataset_couplings(args.dataset, real=True) as reader, \
            open_h5(args.dataset, "an openemt dataset HDF5 file") as side:
        n = reader.shape[0]
        if reader.shape[1:] != (model.n_coils, 1):
            raise InputError(f"expected couplings of shape (N, {model.n_coils}, 1) for this "
                             f"board calibration, got {reader.shape}")
        meta = {"dataset": str(args.dataset), "calibration": str(args.calibration),
                "model": "finite", "board": model.board.name, "correction_applied": False}
        truth = _TruthScore(side.get("poses"), model, n, args.dataset)
        announce_compile(args, "finite-coil kernels", kernels=PLANAR_KERNELS)

        def chunks():
            for start in range(0, n, args.chunk_rows):
                C = reader[start:start + args.chunk_rows]
                res = solver(C)
                truth.add(start, C, res)
                yield start, res

        writer = write_solved(args, n, "planar-lm", meta, chunks())
    elapsed = time.perf_counter() - t0
    counts = writer.status_counts()
    summary = {"dataset": str(args.dataset), "calibration": str(args.calibration),
               "output": str(args.output), "solver": "planar-lm", "model": "finite",
               "n_samples": n, "status_counts": counts, "correction_applied": False,
               "elapsed_s": elapsed, "poses_per_s": n / elapsed if elapsed > 0 else None}
    human = [(f"solved {n} samples with the 5-DOF finite-coil solver in {elapsed:.2f} s -> "
              f"{args.output}"),
             "status: " + ", ".join(f"{k} {v}" for k, v in counts.items() if v)]
    acc = truth.summary()
    if acc is not None:
        summary["accuracy"] = acc
        human.append(f"accuracy against the dataset's poses: {acc['position_rms_mm']:.4f} mm "
                     f"RMS, {acc['position_max_mm']:.4f} mm max, {acc['axis_rms_deg']:.4f} deg "
                     f"axis RMS over {acc['n']} converged samples")
    emit(args, summary, human)
    return 0


class _TruthScore:
    """The accuracy block of a dataset that carries the true sensor poses (a simulated or
    measured grid): the keys of the planar calibration's accuracy blocks
    (docs/planar.md#accuracy), from the tracked solution instead of cold starts. ``poses`` is
    the dataset's ``poses`` (an h5py dataset read block by block) or None."""

    def __init__(self, poses, model, n, path):
        import h5py

        if poses is not None and (not isinstance(poses, h5py.Dataset)
                                  or poses.shape != (n, 4, 4)):
            got = poses.shape if isinstance(poses, h5py.Dataset) else "a group"
            raise InputError(f"{path}: expected `poses` to have shape ({n}, 4, 4) beside the "
                             f"couplings, got {got}")
        self.poses = poses
        self.model = model
        self.parts = []

    def add(self, start, C, res) -> None:
        if self.poses is None:
            return
        import numpy as np

        from ..calibrate._planar import GridData, planar_errors

        P = np.asarray(self.poses[start:start + len(res)], dtype=np.float64)
        C = np.asarray(C, dtype=np.float64).reshape(len(res), -1)
        if not (np.all(np.isfinite(P)) and np.all(np.isfinite(C))):
            self.poses, self.parts = None, []     # rows without a truth: no accuracy block
            return
        self.parts.append(planar_errors(self.model, GridData(P[:, :3, 3], P[:, :3, 2], C),
                                        result=res))

    def summary(self) -> dict | None:
        if not self.parts:
            return None
        from ..calibrate._planar import PlanarErrors

        return PlanarErrors.concatenate(self.parts).summary()
