"""``openemt info FILE``: summarise a dataset (.h5) or a calibration (.json / ILEMT .mat)."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np

from .._errors import InputError
from . import command_help
from ._common import add_common, emit

__all__ = ["calibration_info", "dataset_info", "register", "run"]


def register(sub) -> None:
    p = sub.add_parser("info", help=command_help("info"),
                       description=__doc__.splitlines()[0])
    p.add_argument("path", help="dataset .h5, calibration .json or ILEMT calibration .mat")
    add_common(p)
    p.set_defaults(func=run)


def dataset_info(ds) -> dict:
    """JSON-able summary of a Dataset."""
    rows = {name: int((ds.file_index == i).sum()) for i, name in enumerate(ds.files)}
    prov = ds.meta.get("provenance", {})
    absC = np.abs(ds.couplings)
    return {
        "kind": "dataset",
        "n_samples": ds.n_samples,
        "n_source": ds.n_source,
        "n_sensor": ds.n_sensor,
        "complex": bool(np.iscomplexobj(ds.couplings)),
        "files": rows,
        "patterns": dict(Counter(ds.pattern.tolist())),
        "source_fixtures": dict(Counter(ds.source_fixture.tolist())),
        "sensor_fixtures": dict(Counter(ds.sensor_fixture.tolist())),
        "has_poses": ds.poses is not None,
        "has_stage_logged": ds.stage_logged is not None,
        "extra": sorted(ds.extra),
        "source": ds.meta.get("source", {}).get("name") if isinstance(ds.meta.get("source"), dict)
        else ds.meta.get("source"),
        "sensor": ds.meta.get("sensor", {}).get("name") if isinstance(ds.meta.get("sensor"), dict)
        else ds.meta.get("sensor"),
        "compensate_stage": prov.get("compensate_stage"),
        "source_signs": prov.get("source_signs"),
        "coupling_abs_max": float(absC.max()) if absC.size else None,
        "stage_range_m": ([ds.stage[:, :3].min(axis=0), ds.stage[:, :3].max(axis=0)]
                          if ds.n_samples else None),
        "openemt_version": prov.get("openemt_version"),
    }


def calibration_info(cal) -> dict:
    """JSON-able summary of a Calibration."""
    if cal.kind == "finite":          # a board calibration
        return cal.info()
    m = cal.model
    return {
        "kind": "calibration",
        "mode": cal.mode,
        "n_source": m.n_source,
        "n_sensor": m.n_sensor,
        "concentric": bool(m.is_concentric),
        "gain": m.gain,
        "source_fixture": cal.source_fixture,
        "stage_fixture": cal.stage_fixture,
        "sensor_fixture": cal.sensor_fixture,
        "linear_correction": cal.linear_correction is not None,
        "free": list(cal.free),
        "frozen": list(cal.frozen),
        "standard_errors": sorted(cal.standard_errors),
        "stats": cal.stats,
        "source_gains": np.linalg.norm(m.M_so, axis=0),
        "sensor_gains": np.linalg.norm(m.M_se, axis=0),
    }


def _kind(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix in (".json", ".mat"):
        return "calibration"
    if suffix in (".h5", ".hdf5", ".hdf"):
        return "dataset"
    if path.is_file():
        with open(path, "rb") as f:
            head = f.read(8)
        if head == b"\x89HDF\r\n\x1a\n":
            return "dataset"
        if head.lstrip()[:1] == b"{":
            return "calibration"
    raise InputError(f"expected a dataset .h5 or a calibration .json/.mat file, got {str(path)!r}")


def run(args) -> int:
    from ..io import read_calibration, read_dataset

    path = Path(args.path)
    if not path.exists():
        raise FileNotFoundError(f"expected a dataset or calibration file, got missing file "
                                f"{str(path)!r}")
    from ..live._record import live_file_info

    live = live_file_info(path) if path.suffix.lower() in (".h5", ".hdf5", ".csv") else None
    if live is not None:               # a track log or raw recording (docs/live.md)
        info = live
        state = {True: "complete", False: "incomplete: the session was killed or failed",
                 None: "CSV: cannot tell whether complete"}[live["complete"]]
        human = [f"{path}: {live['kind']}, {live['rows']} rows ({state})"]
    elif _kind(path) == "dataset":
        info = dataset_info(read_dataset(path))
        human = [(f"{path}: dataset, {info['n_samples']} rows, "
                  f"{info['n_source']} x {info['n_sensor']} couplings"
                  f"{' (complex)' if info['complex'] else ''}")]
        human += [f"  {name}: {n}" for name, n in info["files"].items()]
    else:
        info = calibration_info(read_calibration(path))
        human = [(f"{path}: calibration mode {info['mode']!r}, {info['n_source']} x "
                  f"{info['n_sensor']} coils{' (concentric)' if info['concentric'] else ''}, "
                  f"linear correction: {'yes' if info['linear_correction'] else 'no'}")]
        human += [f"  {k}: {v}" for k, v in info["stats"].items()]
    info["path"] = str(path)
    emit(args, info, human)
    return 0
