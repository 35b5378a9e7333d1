"""``openemt correct fit|apply``: output correction of tracker poses against a reference.

``fit`` reads pose-pair CSV files (measured ``x, y, z, ...`` and reference ``ref_x, ...``
columns, see ``openemt.io.read_poses_csv``; ``openemt align`` writes them), fits a DLT,
polynomial, tensor-product Bernstein, grid or RBF correction (or chooses one, "none" included,
with ``--method auto``)
and prints its in-sample and held-out errors beside those of no correction. ``apply``
corrects the poses of a CSV file or pose dataset and, if the file has reference columns,
reports the errors before and after.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._errors import InputError, check_nonnegative
from . import command_help
from ._common import add_common, emit

__all__ = ["register", "run_apply", "run_fit"]


def register(sub) -> None:
    p = sub.add_parser("correct", help=command_help("correct"),
                       description=__doc__.splitlines()[0])
    actions = p.add_subparsers(dest="action", metavar="ACTION")
    actions.required = True

    f = actions.add_parser("fit", help="fit a correction to pose pairs (CSV)")
    f.add_argument("pairs", nargs="+",
                   help="pose-pair CSV file(s) with ref_ columns (or pose datasets with "
                        "reference poses)")
    f.add_argument("-o", "--output", required=True, help="correction JSON to write")
    f.add_argument("--method", choices=("auto", "none", "dlt", "poly", "bernstein", "grid",
                                        "rbf"),
                   default="poly",
                   help="correction method; auto: the lowest held-out error, none included")
    f.add_argument("--folds", type=int, default=5,
                   help="k of the k-fold held-out errors (2 to 20)")
    f.add_argument("--seed", type=int, default=0)
    f.add_argument("--holdout-files", action="store_true",
                   help="hold out one input file at a time instead of k random folds")
    f.add_argument("--order", type=int, help="poly: position order (default: by CV, 1-5)")
    f.add_argument("--rot-order", type=int, help="poly: orientation order (default: by CV)")
    f.add_argument("--degree", type=int,
                   help="bernstein: position degree per axis (default: by CV, 1-6)")
    f.add_argument("--rot-degree", type=int, help="bernstein: orientation degree (default: by CV)")
    f.add_argument("--grid-shape", help="grid: nodes per axis, e.g. 5,5,5")
    f.add_argument("--smoothing", type=float, help="grid/rbf smoothing (default: by CV)")
    f.add_argument("--positions-only", action="store_true",
                   help="correct positions only, even if orientations are given")
    f.add_argument("--average-static", action="store_true",
                   help="average samples with the same pose_id before fitting")
    _units(f)
    add_common(f)
    f.set_defaults(func=run_fit)

    a = actions.add_parser("apply", help="apply a correction to poses (CSV)")
    a.add_argument("correction", help="correction JSON written by 'correct fit'")
    a.add_argument("poses", help="pose CSV or pose dataset (.h5) to correct (reference poses "
                                 "optional)")
    a.add_argument("-o", "--output", required=True,
                   help="corrected poses to write: pose dataset if it ends in .h5, else CSV")
    _units(a)
    add_common(a)
    a.set_defaults(func=run_apply)


def _units(p) -> None:
    p.add_argument("--length-unit", choices=("m", "mm"), default="m",
                   help="unit of position columns without a _m/_mm suffix")
    p.add_argument("--angle-unit", choices=("rad", "deg"), default="rad",
                   help="unit of rotation-vector columns without a _rad/_deg suffix")


def _read_one(args, path):
    """(measured, reference, pose_id or None, has_rotations, row report) of one pairs file."""
    from ..io import read_pose_dataset, read_poses_csv

    if _is_h5(path):
        ds = read_pose_dataset(path)
        ref = ds.extra.get("reference_poses")
        if ref is None:
            raise InputError(f"expected reference poses (extra/reference_poses) in {path}, got "
                             f"none (write pose pairs with 'openemt align')")
        ok = np.all(np.isfinite(ds.poses), axis=(1, 2)) & np.all(np.isfinite(ref), axis=(1, 2))
        bad = np.flatnonzero(~ok)
        row = {"file": str(path), "n_rows": ds.n_samples, "n_bad_rows": 0, "bad_lines": [],
               "n_nonfinite_rows": len(bad), "nonfinite_rows": bad[:20].tolist(),
               "nonfinite_lines": []}
        return ds.poses, np.asarray(ref, dtype=float), None, True, row
    t = read_poses_csv(path, length_unit=args.length_unit, angle_unit=args.angle_unit)
    if t.reference is None:
        raise InputError(f"expected reference columns ref_x, ref_y, ref_z in {path}, got none")
    row = {"file": str(path), "n_rows": len(t), "n_bad_rows": len(t.bad_lines),
           "bad_lines": list(t.bad_lines[:20]), "n_nonfinite_rows": len(t.nonfinite_lines),
           "nonfinite_lines": list(t.nonfinite_lines[:20])}
    return (t.poses, t.reference, t.group,
            t.has_orientation and t.reference_has_orientation, row)


def _read_pairs(args):
    from ..io import average_static

    M, D, groups, rot, rows = [], [], [], True, []
    for i, path in enumerate(args.pairs):
        Pm, Pd, group, has_rot, row = _read_one(args, path)
        rot &= has_rot
        rows.append(row)
        if args.average_static:
            if group is None:
                raise InputError(f"expected a pose_id column for --average-static in {path}, "
                                 f"got none")
            # rows not used (reported above) must not shift the groups of either side
            ok = np.all(np.isfinite(Pm), axis=(1, 2)) & np.all(np.isfinite(Pd), axis=(1, 2))
            Pm, Pd, group = Pm[ok], Pd[ok], group[ok]
            Pm, Pd = average_static(Pm, group).poses, average_static(Pd, group).poses
        M.append(Pm)
        D.append(Pd)
        groups.append(np.full(len(Pm), i))
    return np.concatenate(M), np.concatenate(D), np.concatenate(groups), rot, rows


def _method_options(args, method) -> dict:
    opts = {}
    if method == "poly":
        if args.order is not None:
            opts["order"] = args.order
        if args.rot_order is not None:
            opts["rot_order"] = args.rot_order
    if method == "bernstein":
        if args.degree is not None:
            opts["degree"] = args.degree
        if args.rot_degree is not None:
            opts["rot_degree"] = args.rot_degree
    if method in ("grid", "rbf") and args.smoothing is not None:
        opts["smoothing"] = check_nonnegative(args.smoothing, "--smoothing")
    if method == "grid" and args.grid_shape:
        try:
            opts["shape"] = tuple(int(v) for v in args.grid_shape.split(","))
        except ValueError:
            raise InputError(f"expected --grid-shape like 5,5,5, got {args.grid_shape!r}") \
                from None
    return opts


def _row_warnings(rows) -> list:
    out = []
    for r in rows:
        parts = []
        if r["n_bad_rows"]:
            parts.append(f"{r['n_bad_rows']} of the wrong length (lines "
                         f"{', '.join(map(str, r['bad_lines']))})")
        if r["n_nonfinite_rows"]:
            where = (f"lines {', '.join(map(str, r['nonfinite_lines']))}"
                     if r["nonfinite_lines"] else
                     f"rows {', '.join(map(str, r.get('nonfinite_rows', [])))}")
            parts.append(f"{r['n_nonfinite_rows']} with missing or non-finite values ({where})")
        if parts:
            out.append(f"{r['file']}: rows not used: " + "; ".join(parts))
    return out


def run_fit(args) -> int:
    from ..correct import check_folds, fit_auto_correction, fit_correction, write_correction

    if not args.holdout_files:
        check_folds(args.folds, "--folds")
    M, D, file_groups, has_rot, rows = _read_pairs(args)
    positions_only = args.positions_only or not has_rot
    measured = M[:, :3, 3] if positions_only else M
    reference = D[:, :3, 3] if positions_only else D
    groups = file_groups if args.holdout_files else None
    meta = {"inputs": [str(p) for p in args.pairs], "positions_only": positions_only}
    if args.method == "auto":
        corr = fit_auto_correction(
            measured, reference, k=args.folds, seed=args.seed, groups=groups, meta=meta,
            method_options={m: _method_options(args, m)
                            for m in ("poly", "bernstein", "grid", "rbf")})
    else:
        corr = fit_correction(measured, reference, args.method, k=args.folds, seed=args.seed,
                              groups=groups, meta=meta, **_method_options(args, args.method))
    write_correction(corr, args.output)
    st = corr.stats
    warnings = _row_warnings(rows) + list(st["warnings"])
    summary = {"output": str(Path(args.output)), "method": corr.method,
               "method_requested": args.method, "n": st["n"],
               "n_dropped": int(sum(r["n_bad_rows"] + r["n_nonfinite_rows"] for r in rows)),
               "input_rows": rows,
               "positions_only": positions_only, "selected": _selected(corr),
               "in_sample": st["in_sample"], "held_out": st["held_out"],
               "requirements": st["requirements"], "worse_than_none": st["worse_than_none"],
               "warnings": warnings}
    if "auto" in st:
        summary["auto"] = st["auto"]
    emit(args, summary, _human(corr.method, st))
    if warnings and not args.quiet:
        import sys

        for w in warnings:
            print(f"warning: {w}", file=sys.stderr)
    return 0


def _selected(corr) -> dict:
    p = corr.params
    keys = {"none": (), "dlt": ("method", "refined"), "poly": ("pos_order", "rot_order"),
            "bernstein": ("pos_degree", "rot_degree", "lower", "upper"),
            "grid": ("shape", "smoothing"), "rbf": ("smoothing", "kernel")}[corr.method]
    return {k: p.get(k) for k in keys}


def _fmt(s) -> str:
    rot = f", {s['rot_rms_deg']:.4f} deg" if "rot_rms_deg" in s else ""
    return f"{s['trans_rms_mm']:.4f} mm{rot}"


def _line(label, s) -> str:
    rot = (f", rot rms {s['rot_rms_deg']:.4f} max {s['rot_max_deg']:.4f} deg"
           if "rot_rms_deg" in s else "")
    return (f"  {label:<22s} trans rms {s['trans_rms_mm']:.4f} max {s['trans_max_mm']:.4f} mm"
            + rot)


def _human(method, st) -> list:
    """RMS errors per method, in-sample beside held-out (an exact interpolant's 0 mm in-sample
    figure never stands alone), "none" first."""
    ho = st.get("held_out")
    scheme = f"held out ({ho['scheme']})" if ho else "held out"
    lines = [f"{method} correction on {st['n']} pairs (RMS):",
             f"  {'method':<14s} {'in sample':<28s} {scheme}"]
    rows = [("none", st["in_sample"]["uncorrected"], ho["uncorrected"] if ho else None)]
    if "auto" in st:
        for m, c in st["auto"]["candidates"].items():
            if m == "none":
                continue
            if "skipped" in c:
                lines_skip = f"  {m:<14s} skipped: {c['skipped']}"
                rows.append((lines_skip, None, None))
                continue
            rows.append((m + (" (chosen)" if m == method else ""), c["in_sample"],
                         c["held_out"]))
    elif method != "none":
        rows.append((method, st["in_sample"]["corrected"], ho["corrected"] if ho else None))
    for label, ins, out in rows:
        if ins is None:
            lines.append(label)
            continue
        lines.append(f"  {label:<14s} {_fmt(ins):<28s} "
                     f"{_fmt(out) if out is not None else 'not computed'}")
    return lines


def _is_h5(path) -> bool:
    return str(path).lower().endswith((".h5", ".hdf5"))


def run_apply(args) -> int:
    from dataclasses import replace

    from ..correct import evaluate_correction, read_correction
    from ..io import read_pose_dataset, read_poses_csv, write_dataset, write_poses_csv

    corr = read_correction(args.correction)
    ds = None
    if _is_h5(args.poses):
        ds = read_pose_dataset(args.poses)
        poses, reference, has_rot, ref_rot = ds.poses, ds.extra.get("reference_poses"), True, True
        group, tm, frame = None, None, ds.extra.get("frame")
    else:
        t = read_poses_csv(args.poses, length_unit=args.length_unit, angle_unit=args.angle_unit)
        poses, reference, has_rot = t.poses, t.reference, t.has_orientation
        ref_rot, group, tm, frame = t.reference_has_orientation, t.group, t.time, t.frame
    if has_rot:
        P = corr.apply(poses)
    else:
        P = poses.copy()
        P[:, :3, 3] = corr.apply(poses[:, :3, 3])
    if _is_h5(args.output):
        from ..io import pose_dataset

        if ds is None:
            extra = {} if reference is None else {"reference_poses": reference}
            if frame is not None:
                extra["frame"] = frame
            out_ds = pose_dataset(P, file_index=np.zeros(len(P), np.int64),
                                  files=[Path(args.poses).name], extra=extra)
        else:
            out_ds = replace(ds, poses=P, meta={**ds.meta, "corrected_by": str(args.correction),
                                                "correction_method": corr.method})
        write_dataset(out_ds, args.output)
    else:
        write_poses_csv(args.output, P, reference, group=group, time=tm, frame=frame)
    summary = {"output": str(Path(args.output)), "method": corr.method, "n": len(P),
               "orientation_corrected": bool(corr.corrects_orientation and has_rot)}
    human = [f"applied {corr.method} correction to {len(P)} poses -> {args.output}"]
    if reference is not None:
        both = has_rot and ref_rot
        m = poses if both else poses[:, :3, 3]
        d = reference if both else reference[:, :3, 3]
        ev = evaluate_correction(corr, m, d)
        summary["errors"] = ev
        human += [_line("uncorrected", ev["uncorrected"]), _line("corrected", ev["corrected"])]
    emit(args, summary, human)
    return 0
