"""``openemt calibrate DATASET``: fit a calibration (one mode) starting from another calibration."""

from __future__ import annotations

import math
import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

from .._compile_notice import PLANAR_KERNELS, announce_compile
from .._errors import InputError
from . import command_help
from ._common import add_common, emit, stage

__all__ = ["load_dataset", "register", "run"]


def register(sub) -> None:
    from ..calibrate import MODES

    p = sub.add_parser(
        "calibrate", help=command_help("calibrate"),
        description="Fit a calibration (MacLachlan et al. 2025, §VI) to DATASET, starting from --from CAL. "
                    "DATASET is an ILEMT folder, a dataset file (.h5) or a CSV export.")
    p.add_argument("dataset", metavar="DATASET", help="ILEMT folder, dataset .h5 or .csv")
    p.add_argument("--from", dest="start", metavar="CAL",
                   help="starting calibration (.json or ILEMT .mat); default: the folder's "
                        "base_calibration.mat")
    p.add_argument("--mode", default="XYZ",
                   choices=sorted(MODES) + ["improved", "planar", "reference"],
                   help="calibration mode (default XYZ); 'improved': openemt's rig and "
                        "octupole model on the md rows (start from an XYZ calibration); "
                        "'planar': per-coil gain and offset of an Anser-style board from a "
                        "grid CSV (x, y, z, ux, uy, uz, one column per coil) or a simulated "
                        "dataset with known poses; 'reference': coil model and the X, Y of "
                        "A X = Y B against the reference poses of a robot arm or optical tracker "
                        "(docs/reference-calibration.md)")
    p.add_argument("--holdout", default=None, metavar="FRACTION|checkerboard|location",
                   help="reference mode: hold out this fraction of the poses at random, or "
                        "'location' (alternate regions of the volume), and report their error "
                        "with the calibration fitted on the others; planar mode: "
                        "'checkerboard' fits on alternate grid points and solves the others, "
                        "'location' holds out alternate regions (docs/calibration.md)")
    p.add_argument("--seed", type=int, default=0,
                   help="reference mode: seed of the held-out choice (default 0)")
    p.add_argument("--weighting", default="auto",
                   choices=["auto", "errors-in-variables", "ordinary"],
                   help="reference mode: 'errors-in-variables' weights each pose's couplings "
                        "by the covariance the stated reference noise gives them, 'ordinary' "
                        "weights every coupling alike (the paper's residual); default 'auto': "
                        "errors-in-variables when the dataset states its reference noise "
                        "(docs/reference-calibration.md#errors-in-variables)")
    p.add_argument("--accept-reference-residual", action="store_true",
                   help="reference mode: keep a fit whose reference residual exceeds the "
                        "stated reference noise more than 10 times (refused otherwise)")
    p.add_argument("--hemisphere", default=None,
                   help="reference mode: hemisphere of the sensor for the start solve (+x, "
                        "-x, ...; default: the dataset's, else +x)")
    p.add_argument("--sensor-length", type=float, default=None, metavar="M",
                   help="planar mode: sensor coil length (m) for the field average "
                        "(default: the board file's sensor length)")
    p.add_argument("--board", metavar="BOARD",
                   help="planar mode: board geometry file (.toml/.json) or built-in name "
                        "(default: anser); see docs/planar.md")
    p.add_argument("--tilt", action="store_true",
                   help="planar mode: also fit a small tilt of each coil")
    p.add_argument("-o", "--output", metavar="CAL.json", help="write the calibration here")
    p.add_argument("--all-rows", action="store_true",
                   help="fit every row instead of the rows the mode names")
    p.add_argument("--optimize", metavar="G1,G2", help="override the free parameter groups")
    p.add_argument("--freeze", metavar="G1,G2", help="override the frozen parameter groups")
    p.add_argument("--correction", choices=("auto", "none", "lm", "kim18"), default="auto",
                   help="fit the DLT output correction on the calibration rows with this pose "
                        "solver (auto: kim18 for concentric modes, lm otherwise)")
    add_common(p)
    p.set_defaults(func=run)


def load_dataset(path):
    """A Dataset from an ILEMT folder, a dataset file or a CSV export."""
    from ..io import import_csv, import_ilemt_folder, read_dataset

    path = Path(path)
    if path.is_dir():
        return import_ilemt_folder(path)
    if not path.exists():
        raise FileNotFoundError(f"expected a dataset folder or file, got missing {str(path)!r}")
    if path.suffix.lower() == ".csv":
        return import_csv(path)
    return read_dataset(path)


def _groups(text):
    if text is None:
        return None
    return tuple(g.strip() for g in text.split(",") if g.strip())


def _planar(args) -> int:
    """Planar mode: fit a finite-coil board to a grid CSV (docs/planar.md#calibration)."""
    from ..board import BoardModel
    from ..calibrate._planar import (
        GridData,
        check_grid_units,
        fit_planar,
        planar_accuracy,
        read_grid,
    )
    from ..calibrate._split import holdout_split
    from ..io import atomic_path, load_board, read_calibration, write_calibration

    if args.holdout not in (None, "checkerboard", "location"):
        raise InputError(f"expected --holdout checkerboard (or location) in planar mode, got "
                         f"{args.holdout!r}")
    t0 = time.perf_counter()
    data = read_grid(args.dataset)
    check_grid_units(data, args.sensor_length)
    if args.start is not None:
        start = read_calibration(args.start)
        if not isinstance(start.model, BoardModel):
            raise InputError(f"expected a finite-coil (planar) calibration for --from in planar "
                             f"mode, got a {start.model.kind!r} model calibration")
        if args.board is not None:
            raise InputError("expected either --from CAL or --board BOARD in planar mode, "
                             "got both")
        start_model = start.model
    else:
        start_model = load_board(args.board)           # least-squares gains, zero offsets
    if args.sensor_length is not None:
        board = start_model.board if isinstance(start_model, BoardModel) else start_model
        board = replace(board, sensor=replace(board.sensor, length=float(args.sensor_length)))
        start_model = (start_model.replace(board=board)
                       if isinstance(start_model, BoardModel) else board)
    fit_mask = (~holdout_split(args.holdout, len(data.points), points=data.points)
                if args.holdout else np.ones(len(data.points), bool))
    need = 7 if args.tilt else 5                     # more points than parameters per coil
    if fit_mask.sum() < need or (args.holdout and (~fit_mask).sum() < 1):
        raise InputError(f"expected at least {need} grid points to fit"
                         f"{' and one to hold out' if args.holdout else ''}, got "
                         f"{len(data.points)} points")

    def subset(mask):
        return GridData(data.points[mask], data.axes[mask], data.couplings[mask],
                        data.coil_names)

    announce_compile(args, "finite-coil kernels", kernels=PLANAR_KERNELS)
    stage(args, f"fitting the gains and offsets of {data.couplings.shape[1]} coils on "
                f"{int(fit_mask.sum())} grid points ...")
    fit = fit_planar(subset(fit_mask), start_model, fit_tilt=args.tilt)
    stage(args, "solving the grid points with the fitted board (5-DOF) to score it ...")
    summary = {"mode": "planar", "output": args.output, "board": fit.model.board.name,
               "start": args.start, **fit.to_dict(),
               "insample": planar_accuracy(fit.model, subset(fit_mask))}
    if args.holdout:
        summary["holdout"] = planar_accuracy(fit.model, subset(~fit_mask))
        summary["holdout"]["scheme"] = args.holdout
    warns = []
    if fit.status != "converged":
        warns.append(f"the planar fit ended with status {fit.status!r} after {fit.iterations} "
                     f"iterations (condition {fit.condition:.3g}): its parameters are not a "
                     f"converged least-squares solution")
    summary["warnings"] = warns
    summary["seconds"] = time.perf_counter() - t0
    if args.output:
        cal = fit.to_calibration(
            insample=summary["insample"], holdout=summary.get("holdout"),
            provenance={"grid_file": str(args.dataset), "start_file": args.start,
                        "board": args.board or (None if args.start else "anser"),
                        "fit_tilt": bool(args.tilt), "holdout": args.holdout})
        with atomic_path(args.output) as tmp:
            write_calibration(cal, tmp)
    ins = summary["insample"]
    human = [(f"planar: {len(fit.model.gains)} coils, fit {fit.status} in {fit.iterations} "
              f"iterations, max |offset| {np.abs(fit.model.offsets).max() * 1e3:.3f} mm, "
              f"in-sample {ins['position_rms_mm']:.3f} mm RMS over {ins['n']} points")]
    if "holdout" in summary:
        h = summary["holdout"]
        human.append(f"held out ({args.holdout}): {h['position_rms_mm']:.3f} mm RMS, "
                     f"{h['position_max_mm']:.3f} mm max, {h['axis_rms_deg']:.3f} deg RMS over "
                     f"{h['n']} points")
    human += [f"warning: {w}" for w in warns]
    if args.output:
        human.append(f"wrote {args.output}")
    emit(args, summary, human)
    return 0


def _improved(args, dataset, start, start_path) -> int:
    from ..calibrate import improved_calibration
    from ..io import atomic_path, write_calibration

    t0 = time.perf_counter()
    announce_compile(args, "solver kernels")
    stage(args, f"fitting the improved rig and octupole model on the md rows of {args.dataset} "
                "...")
    imp = improved_calibration(dataset, start, None)
    cal = imp.to_calibration(start)
    if args.output:
        with atomic_path(args.output) as tmp:
            write_calibration(cal, tmp)
    summary = {"mode": "improved", "output": args.output, "start": str(start_path),
               **imp.to_dict(), "seconds": time.perf_counter() - t0}
    human = [(f"improved: rms_residue {imp.rms_residue:.7g}, {imp.n_free} free parameters "
              f"({imp.extra_parameters()} beyond XYZ)")]
    emit(args, summary, human)
    return 0


def _reference_start(args, dataset):
    from ..io import read_calibration

    if args.start is not None:
        return read_calibration(args.start), str(args.start)
    cand = Path(args.dataset) / "base_calibration.mat"
    if cand.is_file():
        return read_calibration(cand), str(cand)
    preset = dataset.meta.get("preset")
    if preset is None:
        raise InputError("expected --from CAL (the dataset names no simulated preset and has "
                         "no base_calibration.mat), got none")
    from ..simulate import nominal_calibration

    return nominal_calibration(preset), f"nominal model of preset {preset}"


def _reference(args) -> int:
    from ..calibrate import fit_reference, reference_poses
    from ..io import atomic_path, write_calibration

    t0 = time.perf_counter()
    dataset = load_dataset(args.dataset)
    note = None
    reference_poses(dataset)                  # none: one error line, exit 2
    start, start_path = _reference_start(args, dataset)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        f = fit_reference(dataset, start, hemisphere=args.hemisphere,
                          freeze=_groups(args.freeze) or (), holdout=_fraction(args.holdout),
                          seed=args.seed, weighting=args.weighting,
                          accept_residual=args.accept_reference_residual)
    cal = f.calibration
    stats = {**cal.stats, "seconds": time.perf_counter() - t0}
    cal = cal.replace(stats=stats, provenance={**cal.provenance, "start_file": start_path})
    if args.output:
        with atomic_path(args.output) as tmp:
            write_calibration(cal, tmp)
    ident = f.identifiability
    summary = {
        "mode": "reference",
        "output": args.output,
        "start": start_path,
        "start_xy": f.start,
        "weighting": f.weighting,
        "rms_residue": f.rms_residue,
        "num_points": f.n_train,
        "n_free": int(f.free.size),
        "jacobian_rank": ident["rank"],
        "condition": ident["condition"],
        "xy_condition": ident["xy_condition"],
        "undetermined": ident["undetermined"],
        "ill_conditioned": ident["ill_conditioned"],
        "X": f.X, "Y": f.Y, "X_se": f.X_se, "Y_se": f.Y_se,
        "se_units": "m, m, m, rad, rad, rad (translation; left rotation about parent axes)",
        "holdout": f.holdout or None,
        "reference": {k: v for k, v in cal.extra["reference"].items()
                      if k in ("kind", "noise_trans_m", "noise_rot_rad")},
        "note": note,
        "warnings": [str(w.message) for w in caught],
        "seconds": {"fit": f.seconds, "total": stats["seconds"]},
    }
    human = [(f"reference: rms_residue {f.rms_residue:.7g} over {f.n_train} poses, "
              f"{f.free.size} free parameters (rank {ident['rank']}), X/Y condition "
              f"{ident['xy_condition'] or float('inf'):.3g}")]
    w = f.weighting
    ref = cal.extra["reference"]
    stated = ("" if ref.get("noise_trans_m") is None else
              f" (stated {1e3 * ref['noise_trans_m']:.4g} mm, "
              f"{np.rad2deg(ref['noise_rot_rad']):.4g} deg)")
    human.append(f"weighting: {w['method']}; the reference poses' residual "
                 f"{1e3 * w['reference_residual_trans_m']:.4g} mm, "
                 f"{np.rad2deg(w['reference_residual_rot_rad']):.4g} deg RMS{stated}")
    if f.holdout:
        h = f.holdout
        human.append(f"held out {h['n']} poses: {h['trans_rms_mm']:.4f} mm RMS "
                     f"({h['trans_max_mm']:.4f} max), {h['rot_rms_deg']:.4f} deg RMS")
    if note:
        human.append(f"note: {note}")
    human += [f"warning: {w}" for w in summary["warnings"]]
    if args.output:
        human.append(f"wrote {args.output}")
    emit(args, summary, human)
    return 0


def run(args) -> int:
    code = _run(args)
    if code == 0 and not args.output and not args.quiet:
        print("note: the calibration was not written: no -o given (add -o CAL.json to keep it)",
              file=sys.stderr)
    return code


def _run(args) -> int:
    from ..calibrate import fit, fit_output_correction, get_mode, select_rows
    from ..calibrate._fit import check_fit_inputs
    from ..field import DipoleModel
    from ..io import atomic_path, read_calibration, write_calibration

    if args.weighting != "auto" and args.mode != "reference":
        raise InputError(f"expected --weighting with --mode reference only, got --mode "
                         f"{args.mode}")
    if args.mode == "planar":
        return _planar(args)
    if args.mode == "reference":
        return _reference(args)
    t0 = time.perf_counter()
    dataset = load_dataset(args.dataset)
    start_path = args.start
    if start_path is None:
        cand = Path(args.dataset) / "base_calibration.mat"
        if not cand.is_file():
            raise InputError("expected --from CAL (no base_calibration.mat in the dataset "
                             "folder), got none")
        start_path = cand
    start = read_calibration(start_path)
    if not isinstance(start.model, DipoleModel):   # the rig's modes name dipole groups
        raise InputError(f"expected a dipole-model calibration for --from in mode "
                         f"{args.mode}, got a finite-coil board calibration (--mode planar)")
    if args.mode == "improved":
        return _improved(args, dataset, start, start_path)
    mode = get_mode(args.mode)
    check_fit_inputs(dataset, start, mode, select=not args.all_rows,
                     optimize=_groups(args.optimize), freeze=_groups(args.freeze))
    announce_compile(args, "solver kernels")
    stage(args, f"fitting mode {mode.name} from {start_path} ...")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        f = fit(dataset, start, mode, select=not args.all_rows, optimize=_groups(args.optimize),
                freeze=_groups(args.freeze))
    cal = f.calibration
    stats = dict(cal.stats)
    solver = args.correction
    if solver == "auto":
        solver = "kim18" if mode.concentric else "lm"
    corr = None
    if solver != "none":
        rows = dataset if args.all_rows else dataset.select(select_rows(dataset, mode))
        stage(args, f"fitting the output correction on {len(rows)} rows ({solver} poses) ...")
        corr = fit_output_correction(rows, cal, solver=solver)
        stats.update(num_invalid=corr.n_invalid, uncorrected=corr.rms_uncorrected,
                     corrected=corr.rms_corrected, correction_method=corr.method)
        cal = cal.replace(linear_correction=corr.matrix)
    stats["seconds"] = time.perf_counter() - t0
    cal = cal.replace(stats=stats, provenance={**cal.provenance,
                                               "start_file": str(start_path)})
    if args.output:
        with atomic_path(args.output) as tmp:
            write_calibration(cal, tmp)
    ident = f.identifiability
    summary = {
        "mode": mode.name,
        "output": args.output,
        "start": str(start_path),
        "rms_residue": stats["rms_residue"],
        "sum_squared_residue": stats["sum_squared_residue"],
        "num_points": stats["num_points"],
        "n_free": int(f.free.size),
        "free_groups": list(cal.free),
        "frozen_groups": list(cal.frozen),
        "jacobian_rank": ident.rank,
        "condition": ident.to_dict()["condition"],
        "undetermined_groups": list(ident.undetermined),
        "correction": None if corr is None else {
            "method": corr.method, "n_invalid": corr.n_invalid,
            "rms_uncorrected_mm": corr.rms_uncorrected * 1e3,
            "rms_corrected_mm": corr.rms_corrected * 1e3},
        "warnings": [str(w.message) for w in caught],
        "seconds": {"fit": f.seconds, "total": stats["seconds"]},
    }
    human = [(f"{mode.name}: rms_residue {stats['rms_residue']:.7g} over "
              f"{stats['num_points']} rows, {f.free.size} free parameters (rank {ident.rank}, "
              f"condition {ident.condition:.3g})")]
    if corr is not None:
        human.append(f"output correction ({corr.method}): {corr.rms_uncorrected * 1e3:.4f} -> "
                     f"{corr.rms_corrected * 1e3:.4f} mm on {corr.n_points - corr.n_invalid} "
                     f"valid rows")
    human += [f"warning: {w}" for w in summary["warnings"]]
    if args.output:
        human.append(f"wrote {args.output}")
    emit(args, summary, human)
    return 0


def _fraction(value):
    """``--holdout`` of the reference mode: a fraction in [0, 1) or ``'location'``."""
    if value is None:
        return 0.0
    if value == "location":
        return value
    try:
        f = float(value)
    except ValueError:
        f = math.nan
    if not 0.0 <= f < 1.0:
        raise InputError(f"expected --holdout FRACTION in [0, 1) (or location) in reference "
                         f"mode, got {value!r}")
    return f
