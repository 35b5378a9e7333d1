"""``openemt spin POSES -o axis.json``: spin calibration of a tracked tool (its axis in the tool
frame and the spin axis in the tracker frame) from poses recorded while turning it about its
axis (a needle or stylus spun in a guide).

POSES as ``openemt pivot`` takes them; ``--tip tip.json`` (from ``openemt pivot``) signs the
axis towards the tip.
"""

from __future__ import annotations

from pathlib import Path

from . import command_help
from ._common import add_common, emit
from ._navcommon import add_units, write_json

__all__ = ["register", "run"]


def register(sub) -> None:
    from ..navigate import MAX_SPIN_RMS_DEG

    p = sub.add_parser("spin", help=command_help("spin"), description=__doc__.splitlines()[0])
    p.add_argument("poses", help="tool poses: openemt poses/dataset file (.h5) or pose CSV")
    p.add_argument("-o", "--output", required=True, help="tool-calibration JSON to write")
    p.add_argument("--method", choices=("algebraic", "ransac"), default="algebraic")
    p.add_argument("--tip", help="pivot calibration (openemt pivot -o) whose tip signs the axis")
    p.add_argument("--max-rms-deg", type=float, default=MAX_SPIN_RMS_DEG,
                   help=f"refuse an axis residual RMS above this (deg; default "
                        f"{MAX_SPIN_RMS_DEG:g})")
    p.add_argument("--max-rms-mm", type=float,
                   help="refuse an axis-point residual RMS above this (mm; default no limit)")
    p.add_argument("--threshold-deg", type=float,
                   help="ransac: inlier angle (deg; default from the noise scale)")
    p.add_argument("--seed", type=int, default=0)
    add_units(p)
    add_common(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from .._errors import InputError, check_nonnegative
    from ..navigate import TOOL_FORMAT, read_tip_transform, read_tool_poses, spin_calibration

    tip = None if args.tip is None else read_tip_transform(args.tip)[:3, 3]
    t = read_tool_poses(args.poses, length_unit=args.length_unit, angle_unit=args.angle_unit)
    if not t.has_orientation:
        raise InputError(f"expected tool poses with orientations in {args.poses}, got "
                         f"positions only")
    res = spin_calibration(
        t.poses, args.method, tip=tip,
        max_rms_deg=check_nonnegative(args.max_rms_deg, "--max-rms-deg"),
        max_rms_mm=None if args.max_rms_mm is None
        else check_nonnegative(args.max_rms_mm, "--max-rms-mm"),
        threshold_deg=None if args.threshold_deg is None
        else check_nonnegative(args.threshold_deg, "--threshold-deg"), seed=args.seed)
    summary = {"output": str(Path(args.output)), "input": str(args.poses), **res.to_dict()}
    write_json(args.output, {"format": TOOL_FORMAT, "version": 1, "kind": "spin", **summary,
                             "per_pose": res.per_pose()})
    human = [f"spin calibration ({res.method}) of {res.n} poses, {res.n_inliers} inliers, "
             f"turned {summary['spin_deg']:.1f} deg RMS:",
             "  axis (tool frame)    " + ", ".join(f"{v:.5f}" for v in summary["axis"])
             + f" (+-{summary['axis_se_deg']:.3f} deg)",
             "  axis (tracker frame) " + ", ".join(f"{v:.5f}" for v in summary["axis_tracker"]),
             "  axis point (tool)    " + ", ".join(f"{v:.3f}" for v in summary["point_mm"])
             + " mm",
             f"  residual RMS {summary['rms_deg']:.3f} deg, {summary['rms_mm']:.3f} mm",
             f"  -> {args.output}"]
    emit(args, summary, human)
    return 0
