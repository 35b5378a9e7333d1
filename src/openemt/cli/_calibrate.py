"""``openemt calibrate DATASET``: fit a calibration (one mode) starting from another calibration."""

from __future__ import annotations

import time
import warnings
from pathlib import Path

import numpy as np

from .._errors import InputError
from . import command_help
from ._common import add_common, emit

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
                        "grid CSV (x, y, z, ux, uy, uz, one column per coil); 'reference': "
                        "coil model and the X, Y of A X = Y B against the reference poses of "
                        "a robot arm or optical tracker (docs/reference-calibration.md)")
    p.add_argument("--holdout", type=float, default=0.0, metavar="FRACTION",
                   help="reference mode: hold out this fraction of the poses at random and "
                        "report their error with the calibration fitted on the others")
    p.add_argument("--seed", type=int, default=0,
                   help="reference mode: seed of the held-out choice (default 0)")
    p.add_argument("--hemisphere", default=None,
                   help="reference mode: hemisphere of the sensor for the start solve (+x, "
                        "-x, ...; default: the dataset's, else +x)")
    p.add_argument("--sensor-length", type=float, default=0.0, metavar="M",
                   help="planar mode: sensor coil length (m) for the field average")
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
    import json

    from ..calibrate import calibrate_planar, read_grid_csv
    from ..io import atomic_path

    t0 = time.perf_counter()
    cal = calibrate_planar(read_grid_csv(args.dataset), sensor_length=args.sensor_length)
    summary = {"mode": "planar", "output": args.output, **cal.to_dict(),
               "seconds": time.perf_counter() - t0}
    if args.output:
        with atomic_path(args.output) as tmp:
            Path(tmp).write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    human = [(f"planar: {len(cal.gains)} coils, rms residue {cal.rms_residue:.3g} of the rms "
              f"coupling, max |offset| {np.abs(cal.offsets).max() * 1e3:.3f} mm")]
    emit(args, summary, human)
    return 0


def _improved(args, dataset, start, start_path) -> int:
    from ..calibrate import improved_calibration
    from ..io import atomic_path, write_calibration

    t0 = time.perf_counter()
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
    from ..calibrate import fit_reference, stage_reference
    from ..io import atomic_path, write_calibration

    t0 = time.perf_counter()
    dataset = load_dataset(args.dataset)
    note = None
    if "reference_poses" not in dataset.extra:
        dataset = stage_reference(dataset)
        note = ("no reference poses in the dataset: the stage motion of the home fixture "
                "combination's md rows is the reference")
    start, start_path = _reference_start(args, dataset)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        f = fit_reference(dataset, start, hemisphere=args.hemisphere,
                          freeze=_groups(args.freeze) or (), holdout=args.holdout,
                          seed=args.seed)
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
    from ..calibrate import fit, fit_output_correction, get_mode, select_rows
    from ..io import atomic_path, read_calibration, write_calibration

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
    if args.mode == "improved":
        return _improved(args, dataset, start, start_path)
    mode = get_mode(args.mode)
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
