"""``openemt assess MEASURED --nominal NOMINAL``: the standard accuracy assessment of a tracker
on a machined grid (Hummel et al. 2005): rigid-fit residuals, errors of the distances between
grid points (all, and the 50/150/300 mm classes), jitter of repeated samples and rotation
errors; ``-o report.html`` writes an HTML report with figures.

MEASURED: openemt pose files (.h5), a pose CSV (``pose_id`` marks repeated samples of one
point) or 3D Slicer markups (``.fcsv``, ``.mrk.json``; repeated labels mark repeated samples).
NOMINAL: a CSV with ``x_mm, y_mm, z_mm`` (or ``x, y, z`` in ``--length-unit``), or a regular
grid from ``--grid-pitch-mm`` and ``--grid-shape``.
"""

from __future__ import annotations

from pathlib import Path

from . import command_help
from ._common import add_common, emit
from ._navcommon import add_units

__all__ = ["register", "run"]


def register(sub) -> None:
    p = sub.add_parser("assess", help=command_help("assess"),
                       description=__doc__.splitlines()[0])
    p.add_argument("measured", help="measured points: pose file (.h5), pose CSV or Slicer "
                                    "markups (.fcsv, .mrk.json)")
    p.add_argument("--nominal", help="nominal positions CSV (x_mm, y_mm, z_mm)")
    p.add_argument("--grid-pitch-mm", help="nominal regular grid: pitch (mm), one value or x,y,z")
    p.add_argument("--grid-shape", help="nominal regular grid: nodes per axis, e.g. 4,4,3 "
                                        "(x fastest)")
    p.add_argument("--match", choices=("order", "nearest"), default="order",
                   help="pair measured and nominal points by row order (default) or by nearest "
                        "neighbour after a first fit")
    p.add_argument("--class-tolerance-mm", type=float, default=0.5,
                   help="half-width of the 50/150/300 mm distance classes (mm; default 0.5)")
    p.add_argument("-o", "--output", help="HTML report to write")
    add_units(p)
    add_common(p)
    p.set_defaults(func=run)


def _floats(text, name, n=None):
    from .._errors import InputError

    try:
        v = [float(x) for x in str(text).split(",")]
    except ValueError:
        v = []
    if not v or (n is not None and len(v) not in n):
        raise InputError(f"expected {name} as comma-separated numbers, got {text!r}")
    return v


def _nominal(args):
    from .._errors import InputError
    from ..navigate import read_points_csv, regular_grid

    grid = args.grid_pitch_mm is not None or args.grid_shape is not None
    if (args.nominal is None) == (not grid):
        raise InputError("expected either --nominal FILE or --grid-pitch-mm with --grid-shape, "
                         "got " + ("both" if args.nominal is not None else "neither"))
    if args.nominal is not None:
        return read_points_csv(args.nominal, length_unit=args.length_unit), str(args.nominal)
    if args.grid_pitch_mm is None or args.grid_shape is None:
        raise InputError("expected --grid-pitch-mm and --grid-shape together, got one of them")
    pitch = _floats(args.grid_pitch_mm, "--grid-pitch-mm", (1, 3))
    shape = _floats(args.grid_shape, "--grid-shape", (1, 2, 3))
    if any(s != int(s) for s in shape):
        raise InputError(f"expected whole node counts in --grid-shape, got {args.grid_shape!r}")
    return (regular_grid([1e-3 * p for p in pitch], [int(s) for s in shape]),
            f"grid {args.grid_shape} at {args.grid_pitch_mm} mm")


def run(args) -> int:
    from .._errors import check_nonnegative
    from ..navigate import assess_grid, read_tool_poses

    nominal, nominal_name = _nominal(args)
    tol = 1e-3 * check_nonnegative(args.class_tolerance_mm, "--class-tolerance-mm")
    t = read_tool_poses(args.measured, length_unit=args.length_unit, angle_unit=args.angle_unit)
    res = assess_grid(t.poses, nominal, match=args.match, groups=t.groups,
                      has_orientation=t.has_orientation, class_tolerance=tol)
    d = res.to_dict()
    if args.output:
        from ..report import assessment_document

        assessment_document(res, measured=str(args.measured), nominal=nominal_name
                            ).write(args.output)
    summary = {"measured": str(args.measured), "nominal": nominal_name,
               **({"output": str(Path(args.output))} if args.output else {}), **d}
    human = [f"grid assessment of {res.n} points ({args.match} match, {res.n_rows} rows read"
             + (f", {res.n_nonfinite} not finite" if res.n_nonfinite else "") + "):",
             f"  rigid fit residual RMS {d['rigid_rms_mm']:.3f} mm, mean "
             f"{d['rigid_mean_mm']:.3f} mm, max {d['rigid_max_mm']:.3f} mm",
             f"  distance errors ({d['n_distances']} pairs): mean |e| "
             f"{d['distance_error_mean_mm']:.3f} mm, RMS {d['distance_error_rms_mm']:.3f} mm, "
             f"max {d['distance_error_max_mm']:.3f} mm"]
    for c, s in d["distance_classes"].items():
        if s["n"]:
            human.append(f"    {c} mm class ({s['n']} pairs): mean |e| {s['mean_mm']:.3f} mm, "
                         f"RMS {s['rms_mm']:.3f} mm")
    if d["jitter"]:
        j = d["jitter"]
        human.append(f"  jitter RMS {j['jitter_trans_rms_mm']:.3f} mm"
                     + (f", {j['jitter_rot_rms_deg']:.3f} deg" if "jitter_rot_rms_deg" in j
                        else ""))
    if "rotation_error_rms_deg" in d:
        human.append(f"  rotation error RMS {d['rotation_error_rms_deg']:.3f} deg, max "
                     f"{d['rotation_error_max_deg']:.3f} deg")
    if args.output:
        human.append(f"  -> {args.output}")
    emit(args, summary, human)
    return 0
