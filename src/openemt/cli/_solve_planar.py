"""``openemt solve`` with a calibration of a model other than the dipole model (a finite-coil
board, read by a 5-DOF or a 6-DOF sensor): the solver of :func:`openemt.solve.prepare`, block by
block (warm-started tracking; the first sample and any sample after a failure start cold: from
the seed grid, or coil by coil for a multi-coil sensor). The sensor is on the board's front
side (its coils' normal); ``--hemisphere`` and ``--initial`` do not apply. See
docs/planar.md#solving."""

from __future__ import annotations

import time

from .._errors import InputError

__all__ = ["solve_board"]


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
        shape = (model.n_source, model.n_sensor)
        if reader.shape[1:] != shape:
            raise InputError(f"expected couplings of shape (N, {shape[0]}, {shape[1]}) for "
                             f"this {model.kind!r} calibration, got {reader.shape}")
        meta = {"dataset": str(args.dataset), "calibration": str(args.calibration),
                "model": model.kind, "dof": model.dof, "correction_applied": False,
                **({"board": model.board.name} if hasattr(model, "board") else {})}
        truth = _TruthScore(side.get("poses"), model, n, args.dataset)
        announce_compile(args, "finite-coil kernels", kernels=PLANAR_KERNELS)

        def chunks():
            for start in range(0, n, args.chunk_rows):
                C = reader[start:start + args.chunk_rows]
                res = solver(C)
                truth.add(start, C, res)
                yield start, res

        name = "planar-lm" if model.dof == 5 else f"{model.kind}-lm"
        writer = write_solved(args, n, name, meta, chunks())
    elapsed = time.perf_counter() - t0
    counts = writer.status_counts()
    summary = {"dataset": str(args.dataset), "calibration": str(args.calibration),
               "output": str(args.output), "solver": name, "model": model.kind,
               "dof": model.dof, "n_samples": n, "status_counts": counts,
               "correction_applied": False, "elapsed_s": elapsed,
               "poses_per_s": n / elapsed if elapsed > 0 else None}
    human = [(f"solved {n} samples with the {model.dof}-DOF {model.kind} solver in "
              f"{elapsed:.2f} s -> {args.output}"),
             "status: " + ", ".join(f"{k} {v}" for k, v in counts.items() if v)]
    acc = truth.summary()
    if acc is not None:
        summary["accuracy"] = acc
        rot = ("axis", acc["axis_rms_deg"]) if "axis_rms_deg" in acc else \
            ("rotation", acc["rot_rms_deg"])
        human.append(f"accuracy against the dataset's poses: {acc['position_rms_mm']:.4f} mm "
                     f"RMS, {acc['position_max_mm']:.4f} mm max, {rot[1]:.4f} deg "
                     f"{rot[0]} RMS over {acc['n']} converged samples")
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
        C = np.asarray(C, dtype=np.float64)
        if not (np.all(np.isfinite(P)) and np.all(np.isfinite(C))):
            self.poses, self.parts = None, []     # rows without a truth: no accuracy block
            return
        if self.model.dof == 6:                   # full poses: position and rotation error
            self.parts.append((res, P))
            return
        self.parts.append(planar_errors(self.model, GridData(P[:, :3, 3], P[:, :3, 2],
                                                             C.reshape(len(res), -1)),
                                        result=res))

    def summary(self) -> dict | None:
        if not self.parts:
            return None
        from ..calibrate._planar import PlanarErrors

        if self.model.dof == 6:
            import numpy as np

            from ..evaluate import error_summary, pose_error_magnitudes
            from ..solve import SolveResult

            res = SolveResult.concatenate([r for r, _ in self.parts])
            ok = res.valid
            t, r = pose_error_magnitudes(res.poses[ok], np.concatenate(
                [P for _, P in self.parts])[ok])
            s = error_summary(t, r)
            return {"n": int(ok.sum()), "n_failed": int((~ok).sum()),
                    "position_rms_mm": s["trans_rms_mm"], "position_max_mm": s["trans_max_mm"],
                    "rot_rms_deg": s["rot_rms_deg"], "rot_max_deg": s["rot_max_deg"]}
        return PlanarErrors.concatenate(self.parts).summary()
