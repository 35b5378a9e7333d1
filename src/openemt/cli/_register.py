"""``openemt register FIXED MOVING -o reg.json``: paired-point registration (rigid, or similarity
with ``--scale``) of MOVING onto FIXED, with the fiducial registration error per point and the
predicted target registration error at ``--targets`` (Fitzpatrick & West).

FIXED and MOVING hold the same points in the same order: CSV with ``x, y, z`` columns (suffix
``_mm`` or ``_m``), 3D Slicer markups (``.fcsv``, ``.mrk.json``) or pose files (their positions).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from . import command_help
from ._common import add_common, emit
from ._navcommon import add_units, write_json

__all__ = ["REGISTRATION_FORMAT", "register", "run"]

REGISTRATION_FORMAT = "openemt.registration"


def register(sub) -> None:
    p = sub.add_parser("register", help=command_help("register"),
                       description=__doc__.splitlines()[0])
    p.add_argument("fixed", help="points of the fixed frame (e.g. fiducials in the image)")
    p.add_argument("moving", help="the same points in the moving frame (e.g. the tracker)")
    p.add_argument("-o", "--output", required=True, help="registration JSON to write")
    p.add_argument("--scale", action="store_true", help="fit a uniform scale too (similarity)")
    p.add_argument("--weights", help="comma-separated weight per point pair")
    p.add_argument("--targets", help="points of the moving frame (CSV or markups) where the "
                                     "TRE is predicted")
    p.add_argument("--fle-mm", type=float,
                   help="RMS fiducial localisation error (mm; default: estimated from the FRE)")
    add_units(p, angles=False)
    add_common(p)
    p.set_defaults(func=run)


def _points(path, unit) -> np.ndarray:
    from .._errors import InputError
    from ..navigate import read_tool_poses

    t = read_tool_poses(path, length_unit=unit)
    pts = t.poses[:, :3, 3]
    bad = np.flatnonzero(~np.all(np.isfinite(pts), axis=1))
    if len(bad):
        raise InputError(f"expected finite points in {path}, got {len(bad)} missing or "
                         f"non-finite (rows {', '.join(map(str, bad[:10]))})")
    return pts


def run(args) -> int:
    from .._errors import InputError, check_nonnegative
    from ..navigate import register_points

    fixed, moving = _points(args.fixed, args.length_unit), _points(args.moving, args.length_unit)
    if len(fixed) != len(moving):
        raise InputError(f"expected as many points in {args.moving} as in {args.fixed}, got "
                         f"{len(moving)} and {len(fixed)}")
    weights = None
    if args.weights:
        try:
            weights = np.array([float(v) for v in args.weights.split(",")])
        except ValueError:
            raise InputError(f"expected --weights like 1,1,0.5, got {args.weights!r}") from None
    targets = None if args.targets is None else _points(args.targets, args.length_unit)
    fle = None if args.fle_mm is None else 1e-3 * check_nonnegative(args.fle_mm, "--fle-mm")
    reg = register_points(fixed, moving, weights, scale=args.scale, targets=targets,
                          fle_rms=fle)
    summary = {"output": str(Path(args.output)), "fixed": str(args.fixed),
               "moving": str(args.moving), "similarity": bool(args.scale), **reg.to_dict()}
    write_json(args.output, {"format": REGISTRATION_FORMAT, "version": 1, **summary})
    human = [f"registered {reg.n} point pairs ({'similarity' if args.scale else 'rigid'}): "
             f"FRE RMS {summary['fre_rms_mm']:.3f} mm, max {summary['fre_max_mm']:.3f} mm",
             "  translation " + ", ".join(f"{v:.3f}" for v in summary["translation_mm"])
             + " mm, rotation vector " + ", ".join(
                 f"{v:.3f}" for v in summary["rotation_vector_deg"]) + " deg"]
    if args.scale:
        human.append(f"  scale {reg.scale:.6f}+-{reg.scale_se:.6f}")
    if len(reg.targets):
        tre = summary["predicted_tre_mm"]
        human.append(f"  predicted TRE at {len(tre)} targets (FLE {summary['fle_rms_mm']:.3f} "
                     f"mm): {min(tre):.3f}-{max(tre):.3f} mm RMS")
    human.append(f"  -> {args.output}")
    emit(args, summary, human)
    return 0
