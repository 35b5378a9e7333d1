"""The navigation steps as workflows: an options record in (its fields' metadata hold the help
texts, so ``openemt.cli._common.add_options`` builds each command's options from it), a
:class:`NavigationRun` out. Each workflow reads its files with :func:`read_tool_poses` (every
pose file openemt writes), fits, writes its output atomically and returns the summary that
``--json`` prints, the lines shown on stderr, the rows left out by reason (``dropped``) and the
``warnings`` (a residual above its expected level: flagged, not refused).
"""

from __future__ import annotations

import json
from dataclasses import MISSING, dataclass
from pathlib import Path

import numpy as np

from .._errors import InputError, check_nonnegative
from .._options import option as _opt
from .._result import Result, json_ready
from ._inputs import ToolPoses, read_tool_poses
from ._markups import _text
from ._pivot import MAX_PIVOT_RMS_MM, MAX_SPIN_RMS_DEG, PIVOT_METHODS, TOOL_FORMAT
from ._register import MAX_FRE_MM

__all__ = ["MAX_LOG_SECONDS", "REGISTRATION_FORMAT", "AlignOptions", "AssessOptions",
           "NavigationRun", "PivotOptions", "PointsOptions", "RegisterOptions", "SpinOptions",
           "align_poses", "assess", "pivot", "points", "read_registration", "register", "spin",
           "write_slicer_transform"]

#: Longest log ``points`` takes (s): its motion is analysed on a 2 ms grid (2e6 steps).
MAX_LOG_SECONDS = 4000.0
#: ``format`` of the registration file ``openemt register`` writes (:func:`read_registration`).
REGISTRATION_FORMAT = "openemt.registration"


def _pos(help: str, **meta):
    return _opt(MISSING, help, positional=True, **meta)


_POSES = ("tool poses: a solve output or track log (.h5), a track log or pose CSV (.csv), or a "
          "pose dataset (.h5)")


@dataclass(frozen=True, kw_only=True)
class _Inputs:
    length_unit: str = _opt("m", "unit of CSV position columns without a _m/_mm suffix",
                            choices=("m", "mm"))
    angle_unit: str = _opt("rad", "unit of CSV rotation columns without a _rad/_deg suffix",
                           choices=("rad", "deg"))
    sensor: str | None = _opt(None, "the sensor to read from a track log of several sensors")

    def read(self, path) -> ToolPoses:
        return read_tool_poses(path, length_unit=self.length_unit, angle_unit=self.angle_unit,
                               sensor=self.sensor)


@dataclass(frozen=True, eq=False)
class NavigationRun(Result):
    """What a navigation workflow returns.

    Attributes
    ----------
    result : object
        The fit (:class:`PivotResult`, :class:`SpinResult`, :class:`Registration`,
        :class:`GridAssessment`, a :class:`HandEyeResult`, or the points found).
    summary : dict
        The JSON summary (mm and deg), ``dropped`` rows by reason included.
    lines : tuple of str
        The human summary.
    warnings : tuple of str
        Figures above their expected level (flagged, not refused).
    """

    result: object
    summary: dict
    lines: tuple
    warnings: tuple = ()

    def _items(self) -> dict:
        return {**self.summary, "warnings": list(self.warnings)}


def _write_json(path, doc: dict) -> None:
    _text(path, json.dumps(json_ready(doc), indent=1) + "\n")


def _checked(output, *inputs):
    from .._atomic import check_output_path

    if output is not None:
        check_output_path(output, [i for i in inputs if i is not None])
    return output


def _limit(o, name: str):
    """Option ``name`` of ``o``, refused unless finite and >= 0 (naming ``--name``); None
    stays None."""
    v = getattr(o, name)
    return None if v is None else check_nonnegative(v, "--" + name.replace("_", "-"))


def _oriented(t: ToolPoses, path) -> np.ndarray:
    if not t.has_orientation:
        raise InputError(f"expected tool poses with orientations in {path}, got positions only")
    return t.poses


def _run(t, path, summary, lines, fit, output=None) -> NavigationRun:
    note = t.note(path) if t is not None else None
    warnings = tuple(getattr(fit, "warnings", ()))
    lines = list(lines) + ([f"  {note}"] if note else []) + (
        [f"  -> {output}"] if output else [])
    summary = {**summary, **({"dropped": dict(t.dropped)} if t is not None else {})}
    return NavigationRun(fit, summary, tuple(lines), warnings)


def _pm(v, se, fmt=".3f"):
    return ", ".join(f"{a:{fmt}}+-{s:{fmt}}" for a, s in zip(v, se))


# --------------------------------------------------------------------------------- pivot/spin


@dataclass(frozen=True, kw_only=True)
class PivotOptions(_Inputs):
    """Pivot calibration of a tracked tool: the tip offset in the tool frame and the pivot point
    in the tracker frame, from poses recorded while pivoting the tip in a divot. The output
    file holds the summary, the tip transform (m) that the tracker file's tip key applies, and
    the residual per pose. See docs/navigation.md."""

    poses: str = _pos(_POSES)
    output: str | None = _opt(None, "tool-calibration JSON to write", flag=("-o", "--output"))
    method: str = _opt("algebraic", "algebraic least squares, sphere fit, or RANSAC with "
                                    "outlier rejection (a slipped tip)", choices=PIVOT_METHODS)
    max_rms_mm: float = _opt(MAX_PIVOT_RMS_MM, "flag (not refuse) a residual RMS above this "
                                               "(mm, 3-D)")
    threshold_mm: float | None = _opt(None, "ransac: inlier distance (mm; default from the "
                                            "noise scale)")
    seed: int = _opt(0, "ransac: seed of the minimal sets")


def pivot(options: PivotOptions) -> NavigationRun:
    """Run a pivot calibration on a pose file (:class:`PivotOptions`)."""
    from ._pivot import pivot_calibration

    o = options
    _checked(o.output, o.poses)
    t = o.read(o.poses)
    res = pivot_calibration(_oriented(t, o.poses), o.method, max_rms_mm=_limit(o, "max_rms_mm"),
                            threshold_mm=_limit(o, "threshold_mm"), seed=o.seed)
    s = {"output": o.output, "input": str(o.poses), **res.to_dict(), "dropped": t.dropped}
    if o.output:
        _write_json(o.output, {"format": TOOL_FORMAT, "version": 1, "kind": "pivot",
                               "tip_transform": res.tip_transform, **s,
                               "per_pose": res.per_pose()})
    lines = [f"pivot calibration ({res.method}) of {res.n} poses, {res.n_inliers} inliers:",
             f"  tip (tool frame)   {_pm(s['tip_mm'], s['tip_se_mm'])} mm (length "
             f"{s['tip_length_mm']:.3f} mm)",
             f"  pivot (tracker)    {_pm(s['pivot_mm'], s['pivot_se_mm'])} mm",
             f"  residual RMS {s['rms_mm']:.3f} mm (3-D), {s['rms_component_mm']:.3f} mm per "
             f"axis, max {s['max_mm']:.3f} mm"]
    return _run(t, o.poses, s, lines, res, o.output)


@dataclass(frozen=True, kw_only=True)
class SpinOptions(_Inputs):
    """Spin calibration of a tracked tool: its axis in the tool frame and the spin axis in the
    tracker frame, from poses recorded while turning it about its axis (a needle or stylus
    spun in a guide). See docs/navigation.md."""

    poses: str = _pos(_POSES)
    output: str | None = _opt(None, "tool-calibration JSON to write", flag=("-o", "--output"))
    method: str = _opt("algebraic", "algebraic fit, or RANSAC screening poses by their angle "
                                    "residual", choices=("algebraic", "ransac"))
    tip: str | None = _opt(None, "pivot calibration (openemt pivot -o) whose tip signs the axis")
    max_rms_deg: float = _opt(MAX_SPIN_RMS_DEG, "flag (not refuse) an axis residual RMS above "
                                                "this (deg)")
    max_rms_mm: float | None = _opt(None, "flag an axis-point residual RMS above this (mm)")
    threshold_deg: float | None = _opt(None, "ransac: inlier angle (deg; default from the noise "
                                             "scale)")
    seed: int = _opt(0, "ransac: seed of the minimal sets")


def spin(options: SpinOptions) -> NavigationRun:
    """Run a spin calibration on a pose file (:class:`SpinOptions`)."""
    from ._pivot import read_tip_transform, spin_calibration

    o = options
    _checked(o.output, o.poses, o.tip)
    tip = None if o.tip is None else read_tip_transform(o.tip)[:3, 3]
    t = o.read(o.poses)
    res = spin_calibration(
        _oriented(t, o.poses), o.method, tip=tip, max_rms_deg=_limit(o, "max_rms_deg"),
        max_rms_mm=_limit(o, "max_rms_mm"), threshold_deg=_limit(o, "threshold_deg"),
        seed=o.seed)
    s = {"output": o.output, "input": str(o.poses), **res.to_dict(), "dropped": t.dropped}
    if o.output:
        _write_json(o.output, {"format": TOOL_FORMAT, "version": 1, "kind": "spin", **s,
                               "per_pose": res.per_pose()})
    f = ", ".join
    lines = [f"spin calibration ({res.method}) of {res.n} poses, {res.n_inliers} inliers, "
             f"turned {s['spin_deg']:.1f} deg RMS:",
             f"  axis (tool frame)    {f(f'{v:.5f}' for v in s['axis'])} "
             f"(+-{s['axis_se_deg']:.3f} deg)",
             f"  axis (tracker frame) {f(f'{v:.5f}' for v in s['axis_tracker'])}",
             f"  axis point (tool)    {f(f'{v:.3f}' for v in s['point_mm'])} mm",
             f"  residual RMS {s['rms_deg']:.3f} deg, {s['rms_mm']:.3f} mm"]
    return _run(t, o.poses, s, lines, res, o.output)


# ------------------------------------------------------------------------------- registration


@dataclass(frozen=True, kw_only=True)
class RegisterOptions(_Inputs):
    """Paired-point registration (rigid, or similarity with --scale) of MOVING onto FIXED, with
    the fiducial registration error per point and the predicted target registration error at
    --targets (Fitzpatrick and West). Points come from CSV (x, y, z columns with _mm or _m),
    3D Slicer markups (.fcsv, .mrk.json, read in RAS) or any pose file (their positions);
    they pair by label when both files carry labels. --slicer-transform also writes the
    registration as an ITK transform file that 3D Slicer loads. See docs/navigation.md."""

    fixed: str = _pos("points of the fixed frame (e.g. fiducials in the image)")
    moving: str = _pos("the same points in the moving frame (e.g. touched with the tracked tip)")
    output: str | None = _opt(None, "registration JSON to write (openemt.registration; the "
                                    "tracker file reads it)", flag=("-o", "--output"))
    slicer_transform: str | None = _opt(None, "ITK transform file (.tfm or .txt, LPS, mm) to "
                                              "write for 3D Slicer", metavar="PATH")
    match: str = _opt("label", "pair points by label when both files carry labels (else by "
                               "order), or by row order", choices=("label", "order"))
    scale: bool = _opt(False, "fit a uniform scale too (similarity)")
    weights: str | None = _opt(None, "comma-separated weight per point pair")
    targets: str | None = _opt(None, "points of the moving frame where the TRE is predicted")
    fle_mm: float | None = _opt(None, "RMS fiducial localisation error (mm; default: estimated "
                                      "from the FRE)")
    max_fre_mm: float = _opt(MAX_FRE_MM, "flag (not refuse) an FRE RMS above this (mm)")


def _points(o, path):
    from ._inputs import MAX_POSITION

    t = o.read(path)
    pts = t.poses[:, :3, 3]
    bad = np.flatnonzero(~np.all(np.isfinite(pts), axis=1))
    if len(bad):
        raise InputError(f"expected finite points within {MAX_POSITION:g} m in {path}, got "
                         f"{len(bad)} that are not (rows {', '.join(map(str, bad[:10]))})")
    return pts, t.labels


def _pair(o, fixed, fl, moving, ml):
    """Rows of ``moving`` in the order of ``fixed``: by label where both carry labels."""
    if o.match == "label" and fl is not None and ml is not None:
        for lab, path in ((fl, o.fixed), (ml, o.moving)):
            if len(set(lab.tolist())) != len(lab):
                raise InputError(f"expected distinct labels in {path} to pair by label, got "
                                 f"repeated ones: use --match order")
        only_f = sorted(set(fl.tolist()) - set(ml.tolist()))
        only_m = sorted(set(ml.tolist()) - set(fl.tolist()))
        if only_f or only_m:
            raise InputError(f"expected the same labels in {o.fixed} and {o.moving}, got "
                             f"{', '.join(only_f) or 'none'} only in the first and "
                             f"{', '.join(only_m) or 'none'} only in the second (--match order "
                             f"pairs by row)")
        index = {v: i for i, v in enumerate(ml.tolist())}
        return fixed, moving[[index[v] for v in fl.tolist()]], "label"
    if len(fixed) != len(moving):
        raise InputError(f"expected as many points in {o.moving} as in {o.fixed}, got "
                         f"{len(moving)} and {len(fixed)}")
    return fixed, moving, "order"


def register(options: RegisterOptions) -> NavigationRun:
    """Register two point files (:class:`RegisterOptions`); writes the registration file
    (:func:`read_registration`) and optionally the 3D Slicer transform."""
    from ._register import register_points

    o = options
    for out in (o.output, o.slicer_transform):
        _checked(out, o.fixed, o.moving, o.targets)
    if o.output and o.slicer_transform and Path(o.output).resolve() == Path(
            o.slicer_transform).resolve():
        raise InputError(f"expected different files for -o and --slicer-transform, got "
                         f"{o.output!r} for both")
    fixed, moving, how = _pair(o, *_points(o, o.fixed), *_points(o, o.moving))
    weights = None
    if o.weights:
        try:
            weights = np.array([float(v) for v in o.weights.split(",")])
        except ValueError:
            raise InputError(f"expected --weights like 1,1,0.5, got {o.weights!r}") from None
    targets = None if o.targets is None else _points(o, o.targets)[0]
    fle = None if o.fle_mm is None else 1e-3 * _limit(o, "fle_mm")
    reg = register_points(fixed, moving, weights, scale=o.scale, targets=targets, fle_rms=fle,
                          max_fre_mm=_limit(o, "max_fre_mm"))
    s = {"output": o.output, "slicer_transform": o.slicer_transform, "fixed": str(o.fixed),
         "moving": str(o.moving), "paired_by": how, "similarity": bool(o.scale),
         **reg.to_dict()}
    if o.output:
        _write_json(o.output, {"format": REGISTRATION_FORMAT, "version": 1,
                               "maps": "moving -> fixed (fixed = transform @ moving), metres",
                               **s})
    if o.slicer_transform:
        write_slicer_transform(o.slicer_transform, reg.transform)
    lines = [f"registered {reg.n} point pairs by {how} ({'similarity' if o.scale else 'rigid'})"
             f": FRE RMS {s['fre_rms_mm']:.3f} mm, max {s['fre_max_mm']:.3f} mm",
             "  translation " + ", ".join(f"{v:.3f}" for v in s["translation_mm"])
             + " mm, rotation vector " + ", ".join(f"{v:.3f}" for v in s["rotation_vector_deg"])
             + " deg"]
    if o.scale:
        lines.append(f"  scale {reg.scale:.6f}+-{reg.scale_se:.6f}")
    if len(reg.targets):
        tre = s["predicted_tre_mm"]
        lines.append(f"  predicted TRE at {len(tre)} targets (FLE {s['fle_rms_mm']:.3f} mm): "
                     f"{min(tre):.3f}-{max(tre):.3f} mm RMS")
    if o.slicer_transform:
        lines.append(f"  -> {o.slicer_transform} (3D Slicer: load as a transform)")
    return _run(None, None, s, lines, reg, o.output)


def read_registration(path) -> tuple[np.ndarray, dict]:
    """The registration written by ``openemt register``: ``(T, meta)`` with ``T`` the 4x4 (m)
    that maps the moving frame (the tracker) into the fixed frame (the image, RAS when the
    fixed points were markups): ``fixed = T @ [moving; 1]``.

    ``path`` is the JSON of ``-o`` (``meta`` is the rest of the file: ``fre_rms_mm``,
    ``fixed``, ``moving``, ...) or an ITK transform file as ``--slicer-transform`` writes it
    (or 3D Slicer saves a linear transform; ``meta`` is ``{"format": "itk"}``)."""
    from ..io._safefile import read_limited

    path = Path(path)
    raw = read_limited(path, "a registration file (openemt register)", 1 << 20)
    if raw.startswith(b"#Insight Transform File"):
        T, meta = _read_itk(raw.decode("utf-8", "replace"), path), {"format": "itk"}
    else:
        from ._inputs import read_transform_file

        T, d = read_transform_file(path, "a registration from 'openemt register -o'",
                                   REGISTRATION_FORMAT, "transform")
        meta = {k: v for k, v in d.items() if k != "transform"}
    ok = T.shape == (4, 4) and np.all(np.isfinite(T)) and np.allclose(T[3], [0, 0, 0, 1])
    if ok:
        s = np.cbrt(np.linalg.det(T[:3, :3]))
        ok = s > 0 and np.allclose(T[:3, :3].T @ T[:3, :3] / s ** 2, np.eye(3), atol=1e-6)
    if not ok:
        raise InputError(f"expected a finite 4x4 rigid (or similarity) transform in {path}, "
                         f"got {str(T.tolist())[:80]!r}")
    return T, meta


_LPS = np.diag([-1.0, -1.0, 1.0, 1.0])


def _read_itk(text: str, path) -> np.ndarray:
    """The registration (m, RAS "to parent") of an ITK affine/rigid text transform (LPS, mm,
    "from parent"); the inverse of :func:`write_slicer_transform`."""
    fields = dict(line.split(":", 1) for line in text.splitlines() if ":" in line)
    kind = fields.get("Transform", "").strip()
    try:
        p = [float(v) for v in fields.get("Parameters", "").split()]
        c = [float(v) for v in fields.get("FixedParameters", "0 0 0").split()]
    except ValueError:
        p, c = [], []
    if not kind.startswith(("AffineTransform_", "MatrixOffsetTransformBase_")) or len(p) != 12 \
            or len(c) != 3:
        raise InputError(f"expected an ITK AffineTransform_double_3_3 with 12 parameters and "
                         f"a 3-D centre in {path}, got {kind or 'no Transform'!r} with "
                         f"{len(p)} parameters")
    M = np.eye(4)
    M[:3, :3] = np.reshape(p[:9], (3, 3))
    M[:3, 3] = np.array(p[9:]) + np.array(c) - M[:3, :3] @ c      # y = A (x - c) + c + t
    T = np.linalg.inv(_LPS @ M @ _LPS)
    T[:3, 3] *= 1e-3
    return T


def write_slicer_transform(path, transform) -> Path:
    """Write a registration (4x4, m, moving -> fixed RAS) as an ITK text transform that 3D
    Slicer loads as a linear transform whose "to parent" is ``transform`` (mm).

    ITK files hold the transform "from parent" in LPS: the matrix written is
    ``F inv(T_mm) F`` with ``F = diag(-1, -1, 1)`` (LPS <-> RAS), ``T_mm`` the transform with
    its translation in mm; Slicer inverts it and flips it back to RAS on loading.
    """
    T = np.array(transform, dtype=np.float64)
    T[:3, 3] *= 1e3
    M = _LPS @ np.linalg.inv(T) @ _LPS
    params = " ".join(f"{v:.17g}" for v in [*M[:3, :3].ravel(), *M[:3, 3]])
    text = ("#Insight Transform File V1.0\n#Transform 0\n"
            "Transform: AffineTransform_double_3_3\n"
            f"Parameters: {params}\nFixedParameters: 0 0 0\n")
    _text(path, text)
    return Path(path)


# ------------------------------------------------------------------------------------ assess


@dataclass(frozen=True, kw_only=True)
class AssessOptions(_Inputs):
    """The standard accuracy assessment of a tracker on a machined grid (Hummel et al. 2005):
    rigid-fit residuals, errors of the distances between grid points (all, and the 50/150/300
    mm classes), jitter of repeated samples (pose_id column or repeated markups labels) and
    rotation errors. NOMINAL is a CSV with x_mm, y_mm, z_mm or a regular grid from
    --grid-pitch-mm and --grid-shape. See docs/navigation.md."""

    measured: str = _pos("measured points: any pose file or Slicer markups (.fcsv, .mrk.json)")
    nominal: str | None = _opt(None, "nominal positions CSV (x_mm, y_mm, z_mm)")
    grid_pitch_mm: str | None = _opt(None, "nominal regular grid: pitch (mm), one value or "
                                           "x,y,z")
    grid_shape: str | None = _opt(None, "nominal regular grid: nodes per axis, e.g. 4,4,3 "
                                        "(x fastest)")
    match: str = _opt("order", "pair measured and nominal points by row order, or by nearest "
                               "neighbour after a first fit", choices=("order", "nearest"))
    class_tolerance_mm: float = _opt(0.5, "half-width of the 50/150/300 mm distance classes "
                                          "(mm)")
    output: str | None = _opt(None, "HTML report to write", flag=("-o", "--output"))


def _floats(text, name, n):
    try:
        v = [float(x) for x in str(text).split(",")]
    except ValueError:
        v = []
    if len(v) not in n:
        raise InputError(f"expected {name} as comma-separated numbers, got {text!r}")
    return v


def _nominal(o):
    from ._assess import regular_grid
    from ._inputs import read_points_csv

    grid = o.grid_pitch_mm is not None or o.grid_shape is not None
    if (o.nominal is None) == (not grid):
        raise InputError("expected either --nominal FILE or --grid-pitch-mm with --grid-shape, "
                         "got " + ("both" if o.nominal is not None else "neither"))
    if o.nominal is not None:
        return read_points_csv(o.nominal, length_unit=o.length_unit), str(o.nominal)
    if o.grid_pitch_mm is None or o.grid_shape is None:
        raise InputError("expected --grid-pitch-mm and --grid-shape together, got one of them")
    pitch = _floats(o.grid_pitch_mm, "--grid-pitch-mm", (1, 3))
    shape = _floats(o.grid_shape, "--grid-shape", (1, 2, 3))
    if any(not np.isfinite(s) or s != int(s) or s > 1e5 for s in shape):
        raise InputError(f"expected whole node counts in --grid-shape, got {o.grid_shape!r}")
    return (regular_grid([1e-3 * p for p in pitch], [int(s) for s in shape]),
            f"grid {o.grid_shape} at {o.grid_pitch_mm} mm")


def assess(options: AssessOptions) -> NavigationRun:
    """Assess measured grid points (:class:`AssessOptions`); ``output`` (the HTML report) is
    written by the caller from ``run.result`` (``openemt.report.assessment_document``)."""
    from ._assess import assess_grid

    o = options
    _checked(o.output, o.measured, o.nominal)
    nominal, nominal_name = _nominal(o)
    tol = 1e-3 * _limit(o, "class_tolerance_mm")
    t = o.read(o.measured)
    res = assess_grid(t.poses, nominal, match=o.match, groups=t.groups,
                      has_orientation=t.has_orientation, class_tolerance=tol)
    d = res.to_dict()
    s = {"measured": str(o.measured), "nominal": nominal_name, "output": o.output, **d}
    lines = [f"grid assessment of {res.n} points ({o.match} match, {res.n_rows} rows read):",
             f"  rigid fit residual RMS {d['rigid_rms_mm']:.3f} mm, mean "
             f"{d['rigid_mean_mm']:.3f} mm, max {d['rigid_max_mm']:.3f} mm",
             f"  distance errors ({d['n_distances']} pairs): mean |e| "
             f"{d['distance_error_mean_mm']:.3f} mm, RMS {d['distance_error_rms_mm']:.3f} mm, "
             f"max {d['distance_error_max_mm']:.3f} mm"]
    lines += [f"    {c} mm class ({v['n']} pairs): mean |e| {v['mean_mm']:.3f} mm, RMS "
              f"{v['rms_mm']:.3f} mm" for c, v in d["distance_classes"].items() if v["n"]]
    if d["jitter"]:
        j = d["jitter"]
        lines.append(f"  jitter RMS {j['jitter_trans_rms_mm']:.3f} mm" + (
            f", {j['jitter_rot_rms_deg']:.3f} deg" if "jitter_rot_rms_deg" in j else ""))
    if "rotation_error_rms_deg" in d:
        lines.append(f"  rotation error RMS {d['rotation_error_rms_deg']:.3f} deg, max "
                     f"{d['rotation_error_max_deg']:.3f} deg")
    return _run(t, o.measured, s, lines, res, o.output)


# ------------------------------------------------------------------------------------ points


@dataclass(frozen=True, kw_only=True)
class PointsOptions(_Inputs):
    """Points from a recorded log: every dwell (the tool held still, found as openemt collect
    finds dwells) becomes one point, the mean position of the tool or, with --tip, of its tip;
    written as 3D Slicer markups (.mrk.json, or .fcsv) for openemt register. See
    docs/navigation.md."""

    log: str = _pos("recorded poses with times: a track log (.h5, .csv), solve output or pose "
                    "file")
    output: str | None = _opt(None, "markups file to write (.mrk.json or .fcsv)",
                              flag=("-o", "--output"))
    tip: str | None = _opt(None, "pivot calibration (openemt pivot -o): points of the tip")
    labels: str | None = _opt(None, "comma-separated labels of the points (default F-1, F-2, "
                                    "...)")
    max_speed_mm_s: float = _opt(2.0, "still below this speed (mm/s)")
    max_rotation_deg_s: float = _opt(1.0, "still below this rotation speed (deg/s)")
    min_dwell_s: float = _opt(0.3, "shortest dwell kept (s, after the margins)")
    margin_s: float = _opt(0.1, "trimmed from both ends of each dwell (s)")


def points(options: PointsOptions) -> NavigationRun:
    """Dwell points of a recorded log (:class:`PointsOptions`), written as Slicer markups."""
    from ..align import find_dwells, mean_pose, pose_motion
    from ._markups import write_markups
    from ._pivot import read_tip_transform

    o = options
    _checked(o.output, o.log, o.tip)
    tip = np.eye(4) if o.tip is None else read_tip_transform(o.tip)
    t = o.read(o.log)
    if t.times is None:
        raise InputError(f"expected sample times in {o.log} (a track log, or a CSV with a time "
                         f"column), got none")
    ok = np.all(np.isfinite(t.poses), axis=(1, 2)) & np.isfinite(t.times)
    times, P = t.times[ok], t.poses[ok] @ tip
    if len(times) < 3 or not np.all(np.diff(times) > 0):
        raise InputError(f"expected at least 3 usable poses with increasing times in {o.log}, "
                         f"got {len(times)} usable" + (" with times that do not increase"
                                                       if len(times) >= 3 else ""))
    if times[-1] - times[0] > MAX_LOG_SECONDS:
        raise InputError(f"expected a log of at most {MAX_LOG_SECONDS:g} s in {o.log} (times "
                         f"in seconds), got {times[-1] - times[0]:.6g} s: times in ms, or a "
                         f"glitch in the time column?")
    g, v, w = pose_motion(times, P)
    still = (v < 1e-3 * _limit(o, "max_speed_mm_s")) & (
        w < np.deg2rad(_limit(o, "max_rotation_deg_s")))
    iv = find_dwells(g, still, margin=_limit(o, "margin_s"),
                     min_duration=_limit(o, "min_dwell_s"))
    means = [mean_pose(P[(times >= a) & (times <= b)]) for a, b in iv
             if np.any((times >= a) & (times <= b))]
    if not means:
        raise InputError(f"expected at least one dwell (the tool held still for "
                         f"{o.min_dwell_s:g} s) in {o.log}, got none")
    pts = np.array(means)[:, :3, 3]
    labels = [f"F-{i + 1}" for i in range(len(pts))]
    if o.labels:
        given = [v.strip() for v in o.labels.split(",")]
        if len(given) != len(pts):
            raise InputError(f"expected {len(pts)} labels (one per dwell found) in --labels, "
                             f"got {len(given)}")
        labels = given
    if o.output:
        write_markups(o.output, pts, labels)
    s = {"input": str(o.log), "output": o.output, "n_points": len(pts), "labels": labels,
         "points_mm": 1e3 * pts, "intervals_s": iv, "tip": o.tip}
    lines = [f"{len(pts)} dwells in {o.log}" + (" (tool tip)" if o.tip else " (tool origin)")
             + ":"] + [f"  {lab}: " + ", ".join(f"{c:.2f}" for c in 1e3 * p) + " mm"
                       for lab, p in zip(labels, pts)]
    return _run(t, o.log, s, lines, pts, o.output)


# ------------------------------------------------------------------------------------- align


@dataclass(frozen=True, kw_only=True)
class AlignOptions(_Inputs):
    """Solve A_i X = Y B_i between two pose recordings and write the pose pairs that openemt
    correct fit reads. MEASURED holds the tracked tool of the tracker to correct (an EM sensor
    in the field-generator frame), REFERENCE the rigidly attached reference tool (an optical
    marker in the camera frame, or a robot flange in the base frame); the reference is mapped
    onto the measured tool in the measured tracker's frame. See docs/alignment.md."""

    measured: str = _pos("poses of the tracker to correct (any pose file)")
    reference: str = _pos("poses of the reference tracker or robot (any pose file)")
    output: str | None = _opt(None, "pose-pair CSV to write (measured + ref_ columns, "
                                    "metres/radians)", flag=("-o", "--output"))
    match: str = _opt("order", "pair rows by order or by equal frame number",
                      choices=("order", "frame"))
    keep_outliers: bool = _opt(False, "also write the pairs flagged as outliers")
    robust: bool = _opt(True, "no outlier screening: plain least squares over all pairs")
    folds: int = _opt(5, "folds of the held-out check (0: none; at most 20)")
    seed: int = _opt(0, "seed of the folds")


def _fmt(P, se) -> str:
    from ..geometry import vector_from_pose

    v = vector_from_pose(P)
    t = ", ".join(f"{1e3 * a:.3f}+-{1e3 * s:.3f}" for a, s in zip(v[:3], se[:3]))
    r = ", ".join(f"{np.rad2deg(a):.3f}+-{np.rad2deg(s):.3f}" for a, s in zip(v[3:], se[3:]))
    return f"t [{t}] mm, rotvec [{r}] deg"


def align_poses(options: AlignOptions) -> NavigationRun:
    """Hand-eye alignment of two pose files (:class:`AlignOptions`)."""
    from ..align import fit_axyb, pair_rows, reference_in_measured_frame
    from ..io import write_poses_csv

    o = options
    _checked(o.output, o.measured, o.reference)
    if o.folds and not 2 <= o.folds <= 20:
        raise InputError(f"expected --folds 0 or 2 to 20, got {o.folds}")
    meas, ref = o.read(o.measured), o.read(o.reference)
    i, j, info = pair_rows(len(meas.poses), len(ref.poses), match=o.match,
                           measured_frame=meas.frame, reference_frame=ref.frame)
    A, B = meas.poses[i], ref.poses[j]
    finite = np.all(np.isfinite(A), axis=(1, 2)) & np.all(np.isfinite(B), axis=(1, 2))
    A, B, i = A[finite], B[finite], i[finite]
    res = fit_axyb(A, B, robust=o.robust, folds=o.folds, seed=o.seed)
    keep = np.ones(len(A), bool) if o.keep_outliers else res.inlier
    if o.output:
        write_poses_csv(o.output, A[keep], reference_in_measured_frame(B, res.X, res.Y)[keep],
                        frame=None if meas.frame is None else meas.frame[i][keep])
    s = res.summary()
    summary = {"output": o.output, **info, "n_pairs_nonfinite": int((~finite).sum()), **s,
               "n_written": int(keep.sum()), "outlier_rows_measured": i[~res.inlier].tolist(),
               "dropped": {"measured": meas.dropped, "reference": ref.dropped}}
    lines = [f"aligned {s['n']} pairs ({info['match']}): {s['n_outliers']} outliers"
             + (" (written)" if o.keep_outliers else " (not written)"),
             f"  residual rms {s['residual_trans_rms_mm']:.3f} mm, "
             f"{s['residual_rot_rms_deg']:.3f} deg",
             f"  X (reference tool -> measured tool): {_fmt(res.X, res.X_se)}",
             f"  Y (reference frame -> measured frame): {_fmt(res.Y, res.Y_se)}"]
    if s["held_out"]:
        h = s["held_out"]
        lines.insert(2, f"  held out ({h['n_folds']}-fold) {h['trans_rms_mm']:.3f} mm, "
                        f"{h['rot_rms_deg']:.3f} deg")
    lines += [f"  {n}" for n in (meas.note(o.measured), ref.note(o.reference)) if n]
    warn = ("X or Y poorly determined: rotate the tools about more axes",) \
        if res.condition > 1e6 else ()
    lines.append(f"  {int(keep.sum())} pairs -> {o.output}" if o.output else "")
    return NavigationRun(res, summary, tuple(x for x in lines if x), warn)
