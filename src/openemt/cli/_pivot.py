"""``openemt pivot POSES -o tip.json``: pivot calibration of a tracked tool (tool-tip offset in
the tool frame, pivot point in the tracker frame) from poses recorded while pivoting its tip in
a divot.

POSES: an ``openemt solve`` poses file, a pose dataset (.h5) or a pose CSV (docs/navigation.md).
The output file holds the summary, the tip transform (m) that ``track`` applies with the tracker
file's ``tip`` key, and the per-pose residuals.
"""

from __future__ import annotations

from pathlib import Path

from . import command_help
from ._common import add_common, emit
from ._navcommon import add_units, write_json

__all__ = ["register", "run"]


def register(sub) -> None:
    from ..navigate import MAX_PIVOT_RMS_MM

    p = sub.add_parser("pivot", help=command_help("pivot"), description=__doc__.splitlines()[0])
    p.add_argument("poses", help="tool poses: openemt poses/dataset file (.h5) or pose CSV")
    p.add_argument("-o", "--output", required=True, help="tool-calibration JSON to write")
    p.add_argument("--method", choices=("algebraic", "sphere", "ransac"), default="algebraic",
                   help="algebraic least squares (default), sphere fit, or RANSAC with outlier "
                        "rejection")
    p.add_argument("--max-rms-mm", type=float, default=MAX_PIVOT_RMS_MM,
                   help=f"refuse a residual RMS above this (mm; default {MAX_PIVOT_RMS_MM:g})")
    p.add_argument("--threshold-mm", type=float,
                   help="ransac: inlier distance (mm; default from the noise scale)")
    p.add_argument("--seed", type=int, default=0, help="ransac: seed of the minimal sets")
    add_units(p)
    add_common(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from .._errors import check_nonnegative
    from ..navigate import TOOL_FORMAT, pivot_calibration, read_tool_poses

    t = read_tool_poses(args.poses, length_unit=args.length_unit, angle_unit=args.angle_unit)
    if not t.has_orientation:
        from .._errors import InputError

        raise InputError(f"expected tool poses with orientations in {args.poses}, got "
                         f"positions only")
    res = pivot_calibration(t.poses, args.method,
                            max_rms_mm=check_nonnegative(args.max_rms_mm, "--max-rms-mm"),
                            threshold_mm=None if args.threshold_mm is None
                            else check_nonnegative(args.threshold_mm, "--threshold-mm"),
                            seed=args.seed)
    summary = {"output": str(Path(args.output)), "input": str(args.poses), **res.to_dict()}
    write_json(args.output, {"format": TOOL_FORMAT, "version": 1, "kind": "pivot",
                             "tip_transform": res.tip_transform, **summary,
                             "per_pose": res.per_pose()})
    tip, se = summary["tip_mm"], summary["tip_se_mm"]
    human = [f"pivot calibration ({res.method}) of {res.n} poses, {res.n_inliers} inliers:",
             "  tip (tool frame)   " + ", ".join(f"{v:.3f}+-{s:.3f}" for v, s in zip(tip, se))
             + f" mm (length {summary['tip_length_mm']:.3f} mm)",
             "  pivot (tracker)    " + ", ".join(
                 f"{v:.3f}+-{s:.3f}" for v, s in zip(summary["pivot_mm"],
                                                     summary["pivot_se_mm"])) + " mm",
             f"  residual RMS {summary['rms_mm']:.3f} mm (3-D), {summary['rms_component_mm']:.3f}"
             f" mm per axis, max {summary['max_mm']:.3f} mm",
             f"  -> {args.output}"]
    emit(args, summary, human)
    return 0
