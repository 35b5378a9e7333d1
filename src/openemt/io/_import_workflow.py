"""The ``openemt import`` workflow: acquisition files in, one openemt dataset file written, a
summary of what was read (and skipped) out."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

from .._errors import InputError
from .._options import option
from .._result import Result

__all__ = ["IMPORT_FORMATS", "ImportOptions", "ImportResult", "import_files", "parse_sign_arg"]

#: The formats ``import`` reads: name -> (one-line help, description, options it takes).
IMPORT_FORMATS = {
    "ilemt": ("an ILEMT data folder of so<SRC>_se<SEN>_<pattern>.dat files",
              "Import every so<SRC>_se<SEN>_<pattern>.dat file of an ILEMT folder (sorted by "
              "name) into one dataset. Sign flips come from the folder's local_cal_options.m "
              "unless given here.",
              ("folder", "output", "source_signs", "sensor_signs", "sign_options", "compensate",
               "patterns")),
    "ndi": ("NDI Toolbox TSV exports (Aurora, Polaris): poses of one tool",
            "Import the poses of one tool from NDI Toolbox exports into a pose dataset (rows in "
            "file order; non-OK states skipped and counted; rows of the wrong length reported "
            "by line number).", ("files", "output", "tool", "average_static")),
    "poses": ("pose CSV files (any tracker or robot; optional ref_ columns)",
              "Import pose CSV files (columns x, y, z and qw..qz or rx..rz, optional ref_ "
              "columns, pose_id, frame, time) into a pose dataset.",
              ("files", "output", "average_static", "length_unit", "angle_unit")),
}


@dataclasses.dataclass(frozen=True)
class ImportOptions:
    """What to import (field metadata: the command-line help)."""

    format: str = option("ilemt", "input format", choices=tuple(IMPORT_FORMATS), cli=False)
    folder: str | None = option(None, "ILEMT data folder", positional=True)
    files: tuple[str, ...] | None = option(None, "export files (.tsv/.txt for ndi, .csv for "
                                           "poses)", positional=True)
    output: str = option(None, "output dataset file (.h5)", flag=("-o", "--output"),
                         required=True)
    source_signs: tuple[str, ...] | None = option(
        None, "source sign rule (repeatable; the first regex found in a file name applies); "
        "replaces options.source_signs of local_cal_options.m", action="append",
        metavar="REGEX=sx,sy,sz")
    sensor_signs: tuple[str, ...] | None = option(
        None, "sensor sign rule (repeatable); replaces options.sensor_signs", action="append",
        metavar="REGEX=sx,sy,sz")
    sign_options: bool = option(True, "ignore local_cal_options.m: no flips except the rules "
                                "given here")
    compensate: bool = option(True, "do not apply the stage-error compensation")
    patterns: str | None = option(None, "only these data patterns (e.g. md,ld)", metavar="P1,P2")
    tool: str | None = option(None, "port number (e.g. 10) or full port label of the tool; needed "
                              "when a file holds several tools", metavar="PORT_OR_LABEL")
    average_static: bool = option(False, "ndi: each file is one static pose, written as its mean "
                                  "(one row per file, in the order given) with its jitter; "
                                  "poses: the samples of each pose_id (or of each file without "
                                  "one) averaged")
    length_unit: str = option("m", "unit of position columns without a _m/_mm suffix",
                              choices=("m", "mm"))
    angle_unit: str = option("rad", "unit of rotation-vector columns without a _rad/_deg suffix",
                             choices=("rad", "deg"))


@dataclasses.dataclass(frozen=True)
class ImportResult(Result):
    """What was imported: the dataset written and, per input file, the rows read and skipped."""

    summary: dict

    def to_dict(self) -> dict:
        return dict(self.summary)

    def lines(self) -> list[str]:
        """The human-readable summary, one line per input file."""
        s = self.summary
        if s.get("format") is None:  # an ILEMT folder
            return [f"imported {s['n_samples']} rows from {len(s['files'])} files -> "
                    f"{s['path']}"] + [f"  {name}: {n}" for name, n in s["files"].items()]
        human = [f"imported {s['n_samples']} poses from {len(s['files'])} files -> {s['path']}"]
        for f in s["files"]:
            line = f"  {f['file']}: {f['n_valid']} of {f['n_rows']} rows"
            if f.get("label"):
                line += f" of {f['label']}"
            if f.get("skipped"):
                line += ", skipped " + ", ".join(f"{k}: {v}" for k, v in f["skipped"].items())
            if f.get("n_nonfinite_rows"):
                line += (f", {f['n_nonfinite_rows']} with missing values (lines "
                         f"{', '.join(map(str, f['nonfinite_lines']))})")
            if f["n_bad_rows"]:
                line += (f", {f['n_bad_rows']} rows of the wrong length (lines "
                         f"{', '.join(map(str, f['bad_lines']))})")
            if "jitter_trans_sd_mm" in f:
                line += (f", jitter {f['jitter_trans_sd_mm']:.3f} mm / "
                         f"{f['jitter_rot_sd_deg']:.3f} deg")
            human.append(line)
        return human


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


def import_files(o: ImportOptions, say=None) -> ImportResult:
    """Import what ``o`` names into the dataset ``o.output``."""
    from ._hdf5 import write_dataset
    from ._ilemt import import_ilemt_folder
    from ._ndi import import_ndi
    from ._poses_csv import import_poses_csv

    t0 = time.perf_counter()
    out = Path(o.output)
    if o.format == "ilemt":
        so = [parse_sign_arg(s) for s in o.source_signs] if o.source_signs else None
        se = [parse_sign_arg(s) for s in o.sensor_signs] if o.sensor_signs else None
        if not o.sign_options:
            so, se = so or [], se or []
        patterns = [p.strip() for p in o.patterns.split(",") if p.strip()] if o.patterns \
            else None
        ds = import_ilemt_folder(o.folder, source_signs=so, sensor_signs=se,
                                 compensate_stage=o.compensate, patterns=patterns)
        write_dataset(ds, out)
        prov = ds.meta.get("provenance", {})
        return ImportResult({
            "path": str(out), "n_samples": ds.n_samples, "n_source": ds.n_source,
            "n_sensor": ds.n_sensor,
            "files": {name: int((ds.file_index == i).sum()) for i, name in enumerate(ds.files)},
            "source": ds.meta.get("source", {}).get("name"),
            "sensor": ds.meta.get("sensor", {}).get("name"),
            "source_signs": prov.get("source_signs"), "sensor_signs": prov.get("sensor_signs"),
            "signs_from": prov.get("signs_from"), "compensate_stage": o.compensate,
            "seconds": round(time.perf_counter() - t0, 4)})
    if o.format == "ndi":
        ds, summary = import_ndi(list(o.files), tool=o.tool, average=o.average_static)
    else:
        ds, summary = import_poses_csv(list(o.files), average=o.average_static,
                                       length_unit=o.length_unit, angle_unit=o.angle_unit)
    write_dataset(ds, out)
    return ImportResult({"path": str(out), "format": o.format, **summary,
                         "seconds": round(time.perf_counter() - t0, 4)})
