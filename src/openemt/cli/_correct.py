"""``openemt correct fit|apply``: output correction of tracker poses against a reference.

``fit`` reads pose-pair CSV files (measured ``x, y, z, ...`` and reference ``ref_x, ...``
columns, see ``openemt.io.read_poses_csv``), fits a DLT, polynomial, grid or RBF correction
and prints its in-sample and held-out errors. ``apply`` corrects the poses of a CSV file and,
if the file has reference columns, reports the errors before and after.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._errors import InputError
from . import command_help
from ._common import add_common, emit

__all__ = ["register", "run_apply", "run_fit"]


def register(sub) -> None:
    p = sub.add_parser("correct", help=command_help("correct"),
                       description=__doc__.splitlines()[0])
    actions = p.add_subparsers(dest="action", metavar="ACTION")
    actions.required = True

    f = actions.add_parser("fit", help="fit a correction to pose pairs (CSV)")
    f.add_argument("pairs", nargs="+", help="pose-pair CSV file(s) with ref_ columns")
    f.add_argument("-o", "--output", required=True, help="correction JSON to write")
    f.add_argument("--method", choices=("dlt", "poly", "grid", "rbf"), default="poly")
    f.add_argument("--folds", type=int, default=5, help="k of the k-fold held-out errors")
    f.add_argument("--seed", type=int, default=0)
    f.add_argument("--holdout-files", action="store_true",
                   help="hold out one input file at a time instead of k random folds")
    f.add_argument("--order", type=int, help="poly: position order (default: by CV, 1-5)")
    f.add_argument("--rot-order", type=int, help="poly: orientation order (default: by CV)")
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
    a.add_argument("poses", help="pose CSV to correct (reference columns optional)")
    a.add_argument("-o", "--output", required=True, help="corrected pose CSV to write")
    _units(a)
    add_common(a)
    a.set_defaults(func=run_apply)


def _units(p) -> None:
    p.add_argument("--length-unit", choices=("m", "mm"), default="m",
                   help="unit of position columns without a _m/_mm suffix")
    p.add_argument("--angle-unit", choices=("rad", "deg"), default="rad",
                   help="unit of rotation-vector columns without a _rad/_deg suffix")


def _read_pairs(args):
    from ..io import average_static, read_poses_csv

    M, D, groups, rot = [], [], [], True
    for i, path in enumerate(args.pairs):
        t = read_poses_csv(path, length_unit=args.length_unit, angle_unit=args.angle_unit)
        if t.reference is None:
            raise InputError(f"expected reference columns ref_x, ref_y, ref_z in {path}, "
                             f"got none")
        rot &= t.has_orientation and t.reference_has_orientation
        Pm, Pd = t.poses, t.reference
        if args.average_static:
            if t.group is None:
                raise InputError(f"expected a pose_id column for --average-static in {path}, "
                                 f"got none")
            am, ad = average_static(Pm, t.group), average_static(Pd, t.group)
            Pm, Pd = am.poses, ad.poses
        M.append(Pm)
        D.append(Pd)
        groups.append(np.full(len(Pm), i))
    return np.concatenate(M), np.concatenate(D), np.concatenate(groups), rot


def run_fit(args) -> int:
    from ..correct import fit_correction, write_correction

    M, D, file_groups, has_rot = _read_pairs(args)
    opts = {}
    if args.method == "poly":
        if args.order is not None:
            opts["order"] = args.order
        if args.rot_order is not None:
            opts["rot_order"] = args.rot_order
    if args.method in ("grid", "rbf") and args.smoothing is not None:
        opts["smoothing"] = args.smoothing
    if args.method == "grid" and args.grid_shape:
        try:
            opts["shape"] = tuple(int(v) for v in args.grid_shape.split(","))
        except ValueError:
            raise InputError(f"expected --grid-shape like 5,5,5, got {args.grid_shape!r}") \
                from None
    positions_only = args.positions_only or not has_rot
    measured = M[:, :3, 3] if positions_only else M
    reference = D[:, :3, 3] if positions_only else D
    groups = file_groups if args.holdout_files else None
    meta = {"inputs": [str(p) for p in args.pairs], "positions_only": positions_only}
    corr = fit_correction(measured, reference, args.method, k=args.folds, seed=args.seed,
                          groups=groups, meta=meta, **opts)
    write_correction(corr, args.output)
    st = corr.stats
    summary = {"output": str(Path(args.output)), "method": corr.method, "n": st["n"],
               "positions_only": positions_only, "selected": _selected(corr),
               "in_sample": st["in_sample"], "held_out": st["held_out"]}
    emit(args, summary, _human(corr.method, st))
    return 0


def _selected(corr) -> dict:
    p = corr.params
    keys = {"dlt": ("method", "refined"), "poly": ("pos_order", "rot_order"),
            "grid": ("shape", "smoothing"), "rbf": ("smoothing", "kernel")}[corr.method]
    return {k: p.get(k) for k in keys}


def _line(label, s) -> str:
    rot = (f", rot rms {s['rot_rms_deg']:.4f} max {s['rot_max_deg']:.4f} deg"
           if "rot_rms_deg" in s else "")
    return (f"  {label:<22s} trans rms {s['trans_rms_mm']:.4f} max {s['trans_max_mm']:.4f} mm"
            + rot)


def _human(method, st) -> list:
    lines = [f"{method} correction on {st['n']} pairs:",
             _line("uncorrected", st["in_sample"]["uncorrected"]),
             _line("in-sample corrected", st["in_sample"]["corrected"])]
    if "held_out" in st:
        lines.append(_line(f"held-out ({st['held_out']['scheme']})", st["held_out"]["corrected"]))
    return lines


def run_apply(args) -> int:
    from ..correct import evaluate_correction, read_correction
    from ..io import read_poses_csv, write_poses_csv

    corr = read_correction(args.correction)
    t = read_poses_csv(args.poses, length_unit=args.length_unit, angle_unit=args.angle_unit)
    if t.has_orientation:
        P = corr.apply(t.poses)
    else:
        P = t.poses.copy()
        P[:, :3, 3] = corr.apply(t.poses[:, :3, 3])
    write_poses_csv(args.output, P, t.reference, group=t.group, time=t.time)
    summary = {"output": str(Path(args.output)), "method": corr.method, "n": len(P),
               "orientation_corrected": bool(corr.corrects_orientation and t.has_orientation)}
    human = [f"applied {corr.method} correction to {len(P)} poses -> {args.output}"]
    if t.reference is not None:
        both = t.has_orientation and t.reference_has_orientation
        m = t.poses if both else t.poses[:, :3, 3]
        d = t.reference if both else t.reference[:, :3, 3]
        ev = evaluate_correction(corr, m, d)
        summary["errors"] = ev
        human += [_line("uncorrected", ev["uncorrected"]), _line("corrected", ev["corrected"])]
    emit(args, summary, human)
    return 0
