"""``openemt simulate``: write a simulated ILEMT-style dataset (and its truth calibration)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._errors import InputError
from . import command_help
from ._common import add_common, add_options, emit, options_from

__all__ = ["parse_distortion", "register", "run"]

_DISTORTION_HELP = (
    "field-distorting object 'KIND,X,Y,Z,RADIUS[,conductivity=S][,mu_r=M]' with KIND "
    "conductive or ferromagnetic, centre X,Y,Z (m, bench frame) and sphere RADIUS (m); "
    "repeatable")


def register(subparsers) -> None:
    from ..simulate import PATTERNS, PRESETS, STAGE_SIGMA

    p = subparsers.add_parser(
        "simulate", help=command_help("simulate"),
        description="Simulate the ILEMT-style calibration apparatus (stage patterns, manual "
                    "fixtures) with a finite-coil tracker preset and optional error sources; "
                    "write the dataset as HDF5.")
    p.add_argument("--preset", default="concentric", choices=PRESETS,
                   help="simulated tracker (default: concentric)")
    p.add_argument("--board", default=None, metavar="BOARD",
                   help="--preset anser: board geometry file (.toml/.json) of the source coils "
                        "(default: the built-in anser board; docs/planar.md)")
    p.add_argument("--pattern", default=None,
                   help=f"stage pattern(s), comma-separated, from {', '.join(PATTERNS)} "
                        "(default: md; grid for anser)")
    p.add_argument("--source-fixtures", default="all",
                   help="'all' or comma-separated source-fixture codes (e.g. YoutZup,XoutZup)")
    p.add_argument("--sensor-fixtures", default="all",
                   help="'all' or comma-separated sensor-fixture codes (e.g. YoutZup,ZinYup)")
    p.add_argument("--combinations", default="paper", choices=("paper", "cross"),
                   help="paper: every source fixture with the home sensor fixture plus the home "
                        "source fixture with every sensor fixture; cross: all pairs")
    p.add_argument("--snr-db", type=float, default=None,
                   help="noise by SNR (dB): per-sample sigma = rms|C| / 10^(snr/20)")
    p.add_argument("--noise-abs", type=float, default=None,
                   help="noise with a fixed sigma (coupling units)")
    p.add_argument("--stage-sigma", type=float, default=STAGE_SIGMA,
                   help=f"stage position error sigma per axis, m (default {STAGE_SIGMA:g}: 0.107 mm 3-D RMS)")
    p.add_argument("--drift", default=None,
                   help="relative source gain drift over the run: one value or one per source "
                        "coil, comma-separated (e.g. 3e-4)")
    p.add_argument("--distortion", action="append", default=None, metavar="SPEC",
                   help=_DISTORTION_HELP)
    p.add_argument("--no-clip-z", action="store_true",
                   help="log Z = -50 mm as commanded instead of the stage limit -46.2 mm")
    p.add_argument("--reference", default=None, choices=("robot", "optical"),
                   help="simulate a reference-pose collection instead: the sensor on a robot "
                        "flange or optical marker (unknown X, Y), couplings at --n-poses "
                        "random poses in the tracker's volume (docs/reference-calibration.md)")
    p.add_argument("--n-poses", type=int, default=300,
                   help="reference collection: number of poses (default 300)")
    p.add_argument("--reference-noise-mm", type=float, default=None, metavar="MM",
                   help="reference collection: pose noise of the reference, 3-D RMS in mm "
                        "(default robot 0.05, optical 0.25)")
    p.add_argument("--reference-noise-deg", type=float, default=None, metavar="DEG",
                   help="reference collection: rotation noise of the reference, RMS angle in "
                        "degrees (default robot 0.02, optical 0.1)")
    p.add_argument("--format", default="h5", choices=("h5", "ndi"),
                   help="h5: an openemt dataset (default); ndi (with --reference optical): the "
                        "NDI Toolbox TSV export of one session, an EM sensor's poses (port 10, "
                        "a smooth field distortion of about 3 mm) beside the optical marker "
                        "fixed to it (port 1), --n-poses rows (docs/alignment.md)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("-o", "--output", required=True, type=Path,
                   help="output dataset (.h5), or export (.tsv) with --format ndi")
    p.add_argument("--truth-calibration", type=Path, default=None, metavar="CAL.json",
                   help="also write the preset's true dipole-equivalent calibration (JSON)")
    from ..navigate import MotionOptions

    add_options(p, MotionOptions)
    add_common(p)
    p.set_defaults(func=run)


def _floats(text: str, name: str) -> np.ndarray:
    try:
        return np.array([float(v) for v in text.split(",")])
    except ValueError:
        raise InputError(f"expected {name} as comma-separated numbers, got {text!r}") from None


def parse_distortion(spec: str) -> dict:
    """``'conductive,0.1,0.25,0,0.03[,conductivity=3.5e7][,mu_r=1000]'`` -> Distortion fields."""
    parts = [s.strip() for s in spec.split(",")]
    positional = [s for s in parts if "=" not in s]
    keyed = [s for s in parts if "=" in s]
    if len(positional) != 5:
        raise InputError(f"expected --distortion 'KIND,X,Y,Z,RADIUS[,key=value]', got {spec!r}")
    nums = _floats(",".join(positional[1:]), "--distortion X,Y,Z,RADIUS")
    out = {"kind": positional[0], "position": tuple(nums[:3]), "radius": float(nums[3])}
    for kv in keyed:
        k, v = (s.strip() for s in kv.split("=", 1))
        if k not in ("conductivity", "mu_r"):
            raise InputError(f"expected --distortion keys conductivity or mu_r, got {k!r}")
        out[k] = float(_floats(v, f"--distortion {k}")[0])
    return out


def _codes(text: str):
    return "all" if text.strip() == "all" else [c.strip() for c in text.split(",") if c.strip()]


def _check_folder(path: Path) -> None:
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise FileNotFoundError(f"expected an existing folder for output {str(path)!r}, got "
                                f"missing folder {str(folder)!r}")


def _preset(args):
    """The preset to simulate: its name, or with ``--board`` the anser preset of that board."""
    if args.board is None:
        return args.preset
    if args.preset != "anser":
        raise InputError(f"expected --board only with --preset anser, got --preset "
                         f"{args.preset}")
    from ..simulate._presets import anser_preset

    return anser_preset(args.board)


def run(args) -> int:
    if args.motion:                                    # a tracked tool's motion
        from ..navigate import MotionOptions, simulate_tool_session

        run_ = simulate_tool_session(options_from(MotionOptions, args, output=str(args.output)))
        emit(args, run_.to_dict(), run_.lines)
        return 0
    from ..io import write_calibration, write_dataset
    from ..simulate import simulate, truth_calibration

    drift = None
    if args.drift is not None:
        d = _floats(args.drift, "--drift")
        drift = float(d[0]) if d.size == 1 else d
    distortion = [parse_distortion(s) for s in args.distortion or []]
    outputs = [args.output] + ([args.truth_calibration] if args.truth_calibration else [])
    for path in outputs:
        _check_folder(path)
    if args.truth_calibration is not None and \
            args.truth_calibration.resolve() == args.output.resolve():
        raise InputError(f"expected different paths for -o and --truth-calibration, got "
                         f"{str(args.output)!r} twice")

    if args.format == "ndi":
        return _write_ndi(args)
    if args.reference is not None:
        from ..simulate import reference_truth_calibration, simulate_reference

        if args.pattern is not None or args.distortion or args.drift is not None:
            raise InputError("expected no --pattern, --distortion or --drift with --reference "
                             "(a reference collection draws its own poses), got some")
        mm, deg = args.reference_noise_mm, args.reference_noise_deg
        ds = simulate_reference(args.preset, args.reference, args.n_poses,
                                noise_trans=None if mm is None else mm * 1e-3,
                                noise_rot=None if deg is None else np.deg2rad(deg),
                                snr_db=args.snr_db, noise_abs=args.noise_abs, seed=args.seed)
        cal = None
        if args.truth_calibration is not None:
            cal = reference_truth_calibration(args.preset, ds.meta["truth"]["X"],
                                              ds.meta["truth"]["Y"])
    else:
        preset = _preset(args)
        ds = _simulate_rig(args, preset, simulate, drift, distortion)
        cal = truth_calibration(preset) if args.truth_calibration is not None else None
    return _write(args, ds, cal, write_dataset, write_calibration)


def _write_ndi(args) -> int:
    """``--format ndi``: one simulated NDI Toolbox session export (openemt.simulate_ndi_session)."""
    from ..io import write_ndi_tsv
    from ..simulate import simulate_ndi_session

    given = [opt for opt, value in (("--truth-calibration", args.truth_calibration),
                                    ("--pattern", args.pattern), ("--drift", args.drift),
                                    ("--distortion", args.distortion),
                                    ("--snr-db", args.snr_db), ("--noise-abs", args.noise_abs),
                                    ("--reference-noise-mm", args.reference_noise_mm),
                                    ("--reference-noise-deg", args.reference_noise_deg))
             if value is not None]
    if args.reference != "optical" or given:
        got = (", ".join(given) if args.reference == "optical" else
               "no --reference" if args.reference is None else f"--reference {args.reference}")
        raise InputError(f"expected --format ndi with --reference optical, --n-poses and "
                         f"--seed only (a pose export of an EM sensor and an optical marker), "
                         f"got {got}")
    tools, truth = simulate_ndi_session(args.n_poses, seed=args.seed)
    write_ndi_tsv(args.output, tools)
    labels = list(tools)
    summary = {"path": str(args.output), "format": "ndi", "n_samples": int(args.n_poses),
               "tools": labels, "seed": args.seed,
               "truth": {"X": truth["X"], "Y": truth["Y"]}}
    human = [(f"simulated an NDI session of {args.n_poses} rows (EM sensor on port 10, optical "
              f"marker on port 1) -> {args.output}")]
    emit(args, summary, human)
    return 0


def _simulate_rig(args, preset, simulate, drift, distortion):
    return simulate(preset, args.pattern, source_fixtures=_codes(args.source_fixtures),
                    sensor_fixtures=_codes(args.sensor_fixtures), combinations=args.combinations,
                    snr_db=args.snr_db, noise_abs=args.noise_abs, stage_sigma=args.stage_sigma,
                    drift=drift, distortion=distortion or None, clip_z=not args.no_clip_z,
                    seed=args.seed)


def _write(args, ds, cal, write_dataset, write_calibration) -> int:
    existed = args.output.exists()
    write_dataset(ds, args.output)
    if cal is not None:
        try:
            write_calibration(cal, args.truth_calibration)
        except BaseException:
            if not existed:  # no partial result: drop the dataset written just before
                args.output.unlink(missing_ok=True)
            raise

    summary = {
        "path": str(args.output),
        "truth_calibration": None if cal is None else str(args.truth_calibration),
        "n_samples": ds.n_samples,
        "n_source": ds.n_source,
        "n_sensor": ds.n_sensor,
        "complex": bool(np.iscomplexobj(ds.couplings)),
        "preset": args.preset,
        "patterns": ds.meta.get("patterns", [args.reference]),
        "files": list(ds.files),
        "seed": args.seed,
        "errors": ds.meta["errors"],
    }
    if "reference" in ds.meta:
        summary["reference"] = ds.meta["reference"]
        summary["truth"] = {k: ds.meta["truth"][k] for k in ("X", "Y")}
    human = [(f"simulated {ds.n_samples} samples ({ds.n_source} x {ds.n_sensor} couplings) of "
             f"preset {args.preset}: {len(ds.files)} blocks -> {args.output}")]
    if cal is not None:
        human.append(f"truth calibration -> {args.truth_calibration}")
    emit(args, summary, human)
    return 0
