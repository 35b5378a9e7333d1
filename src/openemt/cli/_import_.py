"""``openemt import FORMAT ...``: convert acquisition files into one openemt dataset file."""

from __future__ import annotations

import time
from pathlib import Path

from .._errors import InputError
from . import command_help
from ._common import add_common, emit

__all__ = ["parse_sign_arg", "register", "run", "run_poses"]


def parse_sign_arg(text: str) -> tuple[str, tuple[float, float, float]]:
    """``'REGEX=sx,sy,sz'`` -> ``(REGEX, (sx, sy, sz))`` (split at the last ``=``)."""
    regex, sep, signs = str(text).rpartition("=")
    try:
        values = tuple(float(v) for v in signs.replace(" ", ",").split(",") if v != "")
    except ValueError:
        values = ()
    if not sep or not regex or len(values) != 3 or any(v not in (-1.0, 1.0) for v in values):
        raise InputError(f"expected a sign rule 'REGEX=sx,sy,sz' with signs +1/-1, got {text!r}")
    return regex, values


def register(sub) -> None:
    p = sub.add_parser("import", help=command_help("import"),
                       description=__doc__.splitlines()[0])
    fsub = p.add_subparsers(dest="format", metavar="FORMAT")
    fsub.required = True
    q = fsub.add_parser(
        "ilemt", help="an ILEMT data folder of so<SRC>_se<SEN>_<pattern>.dat files",
        description="Import every so<SRC>_se<SEN>_<pattern>.dat file of an ILEMT folder (sorted "
                    "by name) into one dataset. Sign flips come from the folder's "
                    "local_cal_options.m unless given here.")
    q.add_argument("folder", help="ILEMT data folder")
    q.add_argument("-o", "--output", required=True, help="output dataset file (.h5)")
    q.add_argument("--source-signs", action="append", default=None, metavar="REGEX=sx,sy,sz",
                   help="source sign rule (repeatable; the first regex found in a file name "
                        "applies); replaces options.source_signs of local_cal_options.m")
    q.add_argument("--sensor-signs", action="append", default=None, metavar="REGEX=sx,sy,sz",
                   help="sensor sign rule (repeatable); replaces options.sensor_signs")
    q.add_argument("--no-sign-options", action="store_true",
                   help="ignore local_cal_options.m: no flips except the rules given here")
    q.add_argument("--no-compensate", action="store_true",
                   help="do not apply the stage-error compensation")
    q.add_argument("--patterns", default=None, metavar="P1,P2",
                   help="only these data patterns (e.g. md,ld)")
    add_common(q)
    q.set_defaults(func=run)

    n = fsub.add_parser(
        "ndi", help="NDI Toolbox TSV exports (Aurora, Polaris): poses of one tool",
        description="Import the poses of one tool from NDI Toolbox exports into a pose dataset "
                    "(rows in file order; non-OK states skipped and counted; rows of the wrong "
                    "length reported by line number).")
    n.add_argument("files", nargs="+", help="NDI Toolbox export files (.tsv/.txt)")
    n.add_argument("-o", "--output", required=True, help="output pose dataset (.h5)")
    n.add_argument("--tool", default=None, metavar="PORT_OR_LABEL",
                   help="port number (e.g. 10) or full port label of the tool; needed when a "
                        "file holds several tools")
    n.add_argument("--average-static", action="store_true",
                   help="each file is one static pose: write its mean (one row per file, in "
                        "the order given) and report the jitter")
    add_common(n)
    n.set_defaults(func=run_poses)

    c = fsub.add_parser(
        "poses", help="pose CSV files (any tracker or robot; optional ref_ columns)",
        description="Import pose CSV files (columns x, y, z and qw..qz or rx..rz, optional "
                    "ref_ columns, pose_id, frame, time) into a pose dataset.")
    c.add_argument("files", nargs="+", help="pose CSV files")
    c.add_argument("-o", "--output", required=True, help="output pose dataset (.h5)")
    c.add_argument("--average-static", action="store_true",
                   help="average the samples of each pose_id (or of each file without one)")
    c.add_argument("--length-unit", choices=("m", "mm"), default="m",
                   help="unit of position columns without a _m/_mm suffix")
    c.add_argument("--angle-unit", choices=("rad", "deg"), default="rad",
                   help="unit of rotation-vector columns without a _rad/_deg suffix")
    add_common(c)
    c.set_defaults(func=run_poses)

    t = fsub.add_parser(
        "track-log", help="the couplings of a track --log .h5 file: a recording",
        description="Import the couplings one sensor of a 'track --log' HDF5 file recorded "
                    "into a dataset marked as a recording, which 'openemt solve' solves as a "
                    "time series.")
    t.add_argument("log_file", metavar="LOG", help="track log (.h5)")
    t.add_argument("-o", "--output", required=True, help="output dataset file (.h5)")
    t.add_argument("--sensor", default=None, help="sensor name (needed for a log of several)")
    add_common(t)
    t.set_defaults(func=run_track_log)


def run_track_log(args) -> int:
    """``import track-log``: a track log's couplings as a dataset marked as a recording."""
    from ..io import write_dataset
    from ..live import read_track_log, track_log_dataset

    log = Path(args.log_file)
    ds = track_log_dataset(read_track_log(log), args.sensor, log.name)
    out = Path(args.output)
    write_dataset(ds, out)
    rec = ds.meta["recording"]
    summary = {"path": str(out), "format": "track-log", "n_samples": ds.n_samples,
               "n_source": ds.n_source, "n_sensor": ds.n_sensor,
               "sensor": ds.meta["sensor"]["name"], "complete": ds.meta["complete"],
               "sample_rate_hz": rec["sample_rate_hz"]}
    emit(args, summary, [f"imported {ds.n_samples} samples of sensor "
                         f"{summary['sensor']} (a recording) -> {out}"])
    return 0


def run(args) -> int:
    from ..io import import_ilemt_folder, write_dataset

    if args.format != "ilemt":  # pragma: no cover - the other formats run run_poses
        raise InputError(f"expected import format 'ilemt', got {args.format!r}")
    t0 = time.perf_counter()
    so = [parse_sign_arg(s) for s in args.source_signs] if args.source_signs else None
    se = [parse_sign_arg(s) for s in args.sensor_signs] if args.sensor_signs else None
    if args.no_sign_options:
        so = so or []
        se = se or []
    patterns = None
    if args.patterns:
        patterns = [p.strip() for p in args.patterns.split(",") if p.strip()]
    out = Path(args.output)
    ds = import_ilemt_folder(args.folder, source_signs=so, sensor_signs=se,
                             compensate_stage=not args.no_compensate, patterns=patterns)
    write_dataset(ds, out)
    rows = {name: int((ds.file_index == i).sum()) for i, name in enumerate(ds.files)}
    prov = ds.meta.get("provenance", {})
    summary = {
        "path": str(out),
        "n_samples": ds.n_samples,
        "n_source": ds.n_source,
        "n_sensor": ds.n_sensor,
        "files": rows,
        "source": ds.meta.get("source", {}).get("name"),
        "sensor": ds.meta.get("sensor", {}).get("name"),
        "source_signs": prov.get("source_signs"),
        "sensor_signs": prov.get("sensor_signs"),
        "signs_from": prov.get("signs_from"),
        "compensate_stage": not args.no_compensate,
        "seconds": round(time.perf_counter() - t0, 4),
    }
    human = [f"imported {ds.n_samples} rows from {len(rows)} files -> {out}"]
    human += [f"  {name}: {n}" for name, n in rows.items()]
    emit(args, summary, human)
    return 0


def run_poses(args) -> int:
    """``import ndi`` and ``import poses``: a pose dataset and a summary of what was skipped."""
    from ..io import import_ndi, import_poses_csv, write_dataset

    t0 = time.perf_counter()
    if args.format == "ndi":
        ds, summary = import_ndi(args.files, tool=args.tool, average=args.average_static)
    else:
        ds, summary = import_poses_csv(args.files, average=args.average_static,
                                       length_unit=args.length_unit,
                                       angle_unit=args.angle_unit)
    out = Path(args.output)
    write_dataset(ds, out)
    summary = {"path": str(out), "format": args.format, **summary,
               "seconds": round(time.perf_counter() - t0, 4)}
    human = [f"imported {ds.n_samples} poses from {len(args.files)} files -> {out}"]
    for f in summary["files"]:
        line = f"  {f['file']}: {f['n_valid']} of {f['n_rows']} rows"
        if f.get("label"):
            line += f" of {f['label']}"
        if f.get("skipped"):
            line += ", skipped " + ", ".join(f"{k}: {v}" for k, v in f["skipped"].items())
        if f.get("n_nonfinite_rows"):
            line += f", {f['n_nonfinite_rows']} with missing values (lines " \
                    f"{', '.join(map(str, f['nonfinite_lines']))})"
        if f["n_bad_rows"]:
            line += f", {f['n_bad_rows']} rows of the wrong length (lines " \
                    f"{', '.join(map(str, f['bad_lines']))})"
        if "jitter_trans_sd_mm" in f:
            line += (f", jitter {f['jitter_trans_sd_mm']:.3f} mm / "
                     f"{f['jitter_rot_sd_deg']:.3f} deg")
        human.append(line)
    emit(args, summary, human)
    return 0
