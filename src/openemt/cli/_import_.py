"""``openemt import FORMAT ...``: convert acquisition files into one openemt dataset file."""

from __future__ import annotations

import time
from pathlib import Path

from .._errors import InputError
from . import command_help
from ._common import add_common, emit

__all__ = ["parse_sign_arg", "register", "run"]


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


def run(args) -> int:
    from ..io import import_ilemt_folder, write_dataset

    if args.format != "ilemt":  # pragma: no cover - argparse restricts the choices
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
