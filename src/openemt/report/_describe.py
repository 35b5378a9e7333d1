"""A summary of any file openemt writes (``openemt info``): datasets, poses, calibrations,
corrections, raw recordings, live logs, pose (pair) CSV files and NDI exports, recognised by
their content (:func:`describe`)."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._errors import InputError
from .._result import Result

__all__ = ["FileInfo", "calibration_info", "dataset_info", "describe"]


@dataclass(frozen=True)
class FileInfo(Result):
    """What :func:`describe` found: ``kind`` (dataset, poses, calibration, correction, raw,
    track-log, pose-pairs, pose-csv, couplings-csv, ndi-export), the kind's ``details`` and the
    ``path``. ``to_dict()`` is ``openemt info --json``: the kind, its details, the path."""

    path: str
    kind: str
    details: dict

    def _items(self) -> dict:
        return {"kind": self.kind, **self.details, "path": self.path}

    def lines(self) -> list[str]:
        """The human summary (stderr of ``openemt info``)."""
        return _human(Path(self.path), {"kind": self.kind, **self.details})


def describe(path) -> FileInfo:
    """The :class:`FileInfo` of ``path``, any file openemt writes; one InputError line for a
    file it does not recognise, FileNotFoundError for a missing one."""
    details = _details(path)
    return FileInfo(str(path), details.pop("kind"), details)


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
        "pose_dataset": ds.meta.get("kind") == "poses",
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
    """JSON-able summary of a Calibration of any model (the model's own part from its
    ``describe()``)."""
    return {
        "kind": "calibration",
        "mode": cal.mode,
        **cal.model.describe(),
        "source_fixture": cal.source_fixture,
        "stage_fixture": cal.stage_fixture,
        "sensor_fixture": cal.sensor_fixture,
        "linear_correction": cal.linear_correction is not None,
        "free": list(cal.free),
        "frozen": list(cal.frozen),
        "standard_errors": sorted(cal.standard_errors),
        "stats": cal.stats,
    }


_HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"


def _hdf5_signature(path: Path) -> bool:
    """HDF5's signature at offset 0 or after a user block (512, 1024, ... bytes)."""
    with open(path, "rb") as f:
        for offset in (0, 512, 1024, 2048, 4096):
            f.seek(offset)
            if f.read(8) == _HDF5_MAGIC:
                return True
    return False


def _kind(path: Path) -> str:
    """'hdf5', 'json', 'mat', 'csv' or 'tsv' from the suffix, else from the first bytes."""
    suffix = path.suffix.lower()
    known = {".json": "json", ".mat": "mat", ".h5": "hdf5", ".hdf5": "hdf5", ".hdf": "hdf5",
             ".csv": "csv", ".tsv": "tsv"}
    if suffix in known:
        return known[suffix]
    if path.is_file():
        if _hdf5_signature(path):
            return "hdf5"
        with open(path, "rb") as f:
            head = f.read(4096)
        if head.lstrip()[:1] == b"{":
            return "json"
        if b"\t" in head.split(b"\n")[0]:
            return "tsv"
        if b"," in head:
            return "csv"
    raise InputError(f"expected a file openemt writes (dataset or poses .h5, raw recording, "
                     f"track log, calibration or correction .json, ILEMT .mat, pose or log "
                     f".csv, NDI .tsv), got {str(path)!r}")


def _attr(f, name):
    v = f.attrs.get(name)
    return v.decode() if isinstance(v, bytes) else v


def _hdf5_kind(path: Path) -> str:
    """Which openemt HDF5 file: 'dataset', 'poses', 'raw' or 'track-log' (from its attributes,
    after the damaged-file probe of openemt.io)."""
    from ..io._h5safe import open_h5

    with open_h5(path, "a readable openemt HDF5 file") as f:   # probed, structure checked
        schema, fmt = _attr(f, "schema"), _attr(f, "format")
    if schema == "openemt.dataset":       # the common case, without loading the solvers
        return "dataset"
    from ..signal import RAW_FORMAT
    from ..solve import POSES_SCHEMA

    kinds = {("schema", "openemt.dataset"): "dataset", ("schema", POSES_SCHEMA): "poses",
             ("format", RAW_FORMAT): "raw", ("format", "openemt-track"): "track-log"}
    kind = kinds.get(("schema", schema)) or kinds.get(("format", fmt))
    if kind is None:
        raise InputError(f"expected an openemt HDF5 file (schema 'openemt.dataset' or "
                         f"{POSES_SCHEMA!r}, format {RAW_FORMAT!r} or 'openemt-track'), got "
                         f"{path.name} with schema {schema!r} and format {fmt!r}")
    return kind


def _range_mm(xyz) -> list | None:
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    ok = np.all(np.isfinite(xyz), axis=1)
    if not ok.any():
        return None
    return [(1e3 * xyz[ok].min(axis=0)).tolist(), (1e3 * xyz[ok].max(axis=0)).tolist()]


def poses_info(path: Path) -> dict:
    """JSON-able summary of a poses file (``openemt solve -o``)."""
    import json

    from ..io._h5safe import open_h5
    from ..solve import read_poses, status_count_names

    try:
        res = read_poses(path)
        with open_h5(path, "an openemt poses file") as f:
            meta = json.loads(_attr(f, "meta") or "{}")
    except (KeyError, TypeError) as exc:
        raise InputError(f"expected a complete openemt poses file, got {path.name} without "
                         f"{' '.join(str(exc).split())[:80]}") from None
    if not isinstance(meta, dict):
        meta = {}
    counts = np.bincount(res.status.astype(np.int64), minlength=6)
    rr = res.relative_residual
    return {"kind": "poses", "n_samples": len(res), "solver": res.solver,
            "status_counts": status_count_names(counts),
            "position_range_mm": _range_mm(res.poses[:, :3, 3]),
            "relative_residual_median": (float(np.nanmedian(rr)) if rr is not None and len(rr)
                                         and np.isfinite(rr).any() else None),
            "meta": meta}


def raw_info(path: Path) -> dict:
    """JSON-able summary of a raw recording (``openemt track --save-raw``)."""
    from ..signal import read_raw

    raw = read_raw(path)
    lay = raw.layout
    n = int(raw.samples.shape[0])
    return {"kind": "raw", "n_samples": n, "n_channels": int(raw.samples.shape[1]),
            "sample_rate": lay.sample_rate, "duration_s": n / lay.sample_rate,
            "frequencies": list(lay.frequencies), "sensor_channels": list(lay.sensor_channels),
            "reference_channels": list(lay.reference_channels),
            "has_truth": raw.truth_times is not None, "complete": raw.complete}


def _log_sensor(arrays: dict) -> dict:
    from ..solve import status_count_names

    st = np.asarray(arrays.get("status", np.zeros(0)), dtype=np.int64).ravel()
    t = np.asarray(arrays.get("times", np.zeros(0)), dtype=np.float64).ravel()
    dist = np.asarray(arrays.get("distorted", np.zeros(0))).ravel()
    P = arrays.get("poses")
    if P is None:
        pv = np.asarray(arrays.get("pose_vectors", np.zeros((0, 6))), dtype=np.float64)
        xyz = pv.reshape(-1, 6)[:, :3]
    else:
        xyz = np.asarray(P, dtype=np.float64).reshape(-1, 4, 4)[:, :3, 3]
    return {"n_samples": int(st.size),
            "duration_s": float(t[-1] - t[0]) if t.size > 1 else 0.0,
            "status_counts": status_count_names(np.bincount(st[(st >= 0) & (st < 6)],
                                                            minlength=6)),
            "distorted_fraction": float(np.mean(dist.astype(bool))) if dist.size else None,
            "position_range_mm": _range_mm(xyz)}


def track_log_info(path: Path) -> dict:
    """JSON-able summary of a live log (``openemt track --log``), HDF5 or CSV, also one whose
    session was killed (read by :func:`openemt.live.read_track_log`: the rows it committed)."""
    from ..live import read_track_log

    log = read_track_log(path)
    sensors = {}
    for name in log.sensors:
        arrays = dict(log.arrays[name])
        if np.size(arrays.get("poses", ())) == 0:
            arrays.pop("poses", None)
        sensors[name] = _log_sensor(arrays)
    return {"kind": "track-log", "format": "csv" if path.suffix.lower() == ".csv" else "hdf5",
            "rows": log.rows, "complete": log.complete, "sensors": sensors}


def correction_info(path: Path) -> dict:
    """JSON-able summary of a correction file (``openemt correct fit -o``)."""
    from ..correct import read_correction

    corr = read_correction(path)
    stats = corr.stats or {}
    out = {"kind": "correction", "method": corr.method, "n_pairs": stats.get("n"),
           "params": sorted(corr.params)}
    for key in ("in_sample", "held_out"):
        if isinstance(stats.get(key), dict):
            out[key] = {part: {k: v for k, v in stats[key][part].items()
                               if k in ("trans_rms_mm", "rot_rms_deg")}
                        for part in ("uncorrected", "corrected")
                        if isinstance(stats[key].get(part), dict)}
    out["meta"] = corr.meta
    return out


def pose_csv_info(path: Path) -> dict:
    """JSON-able summary of a pose CSV (``openemt align -o``, ``correct apply -o x.csv``) or
    a couplings CSV (``openemt.io.export_csv``)."""
    with open(path, encoding="utf-8-sig", errors="replace") as fh:
        first = fh.readline()
    if first.startswith("# openemt couplings csv"):
        from ..io import import_csv

        info = dataset_info(import_csv(path))
        info["kind"] = "couplings-csv"
        return info
    if first.strip().split(",")[:1] == ["time_s"]:
        return track_log_info(path)
    from ..io import read_poses_csv

    t = read_poses_csv(path)
    return {"kind": "pose-pairs" if t.reference is not None else "pose-csv",
            "n_samples": len(t), "has_reference": t.reference is not None,
            "has_orientation": bool(t.has_orientation),
            "reference_has_orientation": bool(t.reference_has_orientation),
            "frames": ([int(t.frame.min()), int(t.frame.max())]
                       if t.frame is not None and len(t) else None),
            "position_range_mm": _range_mm(t.poses[:, :3, 3]),
            "bad_lines": list(t.bad_lines), "nonfinite_lines": list(t.nonfinite_lines)}


def ndi_info(path: Path) -> dict:
    """JSON-able summary of an NDI Toolbox export (``openemt simulate --format ndi``)."""
    from ..io import read_ndi_tsv

    rec = read_ndi_tsv(path)
    return {"kind": "ndi-export", **rec.summary()}


def _human(path: Path, info: dict) -> list[str]:
    kind = info["kind"]
    if kind == "dataset" and info.get("pose_dataset"):
        lines = [f"{path}: pose dataset, {info['n_samples']} poses"]
        return lines + [f"  {name}: {n}" for name, n in info["files"].items()]
    if kind == "dataset":
        lines = [(f"{path}: dataset, {info['n_samples']} rows, {info['n_source']} x "
                  f"{info['n_sensor']} couplings{' (complex)' if info['complex'] else ''}")]
        return lines + [f"  {name}: {n}" for name, n in info["files"].items()]
    if kind == "couplings-csv":
        return [(f"{path}: couplings CSV, {info['n_samples']} rows, {info['n_source']} x "
                f"{info['n_sensor']} couplings")]
    if kind == "calibration":
        lines = [(f"{path}: calibration mode {info['mode']!r}, {info['n_source']} x "
                  f"{info['n_sensor']} coils{' (concentric)' if info['concentric'] else ''}, "
                  f"linear correction: {'yes' if info['linear_correction'] else 'no'}")]
        return lines + [f"  {k}: {v}" for k, v in info["stats"].items()]
    if kind == "poses":
        counts = ", ".join(f"{k} {v}" for k, v in info["status_counts"].items() if v)
        meta = ", ".join(f"{k}: {info['meta'][k]}" for k in ("dataset", "calibration",
                                                              "hemisphere")
                         if info["meta"].get(k) is not None)
        return [f"{path}: poses from {info['solver']}, {info['n_samples']} rows",
                f"  status: {counts}"] + ([f"  {meta}"] if meta else [])
    state = {False: "; incomplete: the session was killed or failed, its committed rows are "
                    "read", None: "; cannot tell whether complete (CSV)"}.get(info.get("complete"),
                                                                               "")
    if kind == "raw":
        return [f"{path}: raw recording, {info['n_samples']} samples x {info['n_channels']} "
                f"channels at {info['sample_rate']:g} Hz ({info['duration_s']:.2f} s), carriers "
                + ", ".join(f"{v:g}" for v in info["frequencies"]) + f" Hz{state}"]
    if kind == "track-log":
        lines = [f"{path}: track log ({info['format']}), {len(info['sensors'])} sensor(s), "
                 f"{info['rows']} rows{state}"]
        for name, s in info["sensors"].items():
            counts = ", ".join(f"{k} {v}" for k, v in s["status_counts"].items() if v)
            lines.append(f"  {name}: {s['n_samples']} samples over {s['duration_s']:.2f} s; "
                         f"{counts or 'no samples'}")
        return lines
    if kind == "correction":
        lines = [f"{path}: {info['method']} correction"
                 + (f" fitted on {info['n_pairs']} pose pairs" if info["n_pairs"] else "")]
        for key, parts in info.items():
            if key in ("in_sample", "held_out"):
                lines += [f"  {key} {part}: " + ", ".join(f"{k} {v:.4g}" for k, v in e.items())
                          for part, e in parts.items()]
        return lines
    if kind in ("pose-pairs", "pose-csv"):
        what = "pose pairs (measured and reference)" if kind == "pose-pairs" else "poses"
        return [f"{path}: CSV of {info['n_samples']} {what}"
                + ("" if info["has_orientation"] else ", positions only")]
    if kind == "ndi-export":
        lines = [f"{path}: NDI Toolbox export, {len(info['tools'])} tool(s)"]
        return lines + [f"  {t['label']}: {t['n_valid']} of {t['n_rows']} rows valid"
                        for t in info["tools"]]
    return [f"{path}: {kind}"]


def _details(path) -> dict:
    """JSON-able summary of any file openemt writes; ``kind`` names which one (each kind
    loads only its own reader: a dataset's summary needs no model or solver library)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"expected a file openemt writes (dataset, poses, calibration, "
                                f"correction, recording or log), got missing file "
                                f"{str(path)!r}")
    kind = _kind(path)
    if kind == "hdf5":
        sub = _hdf5_kind(path)
        if sub == "dataset":
            from ..io import read_dataset

            return dataset_info(read_dataset(path))
        return {"poses": poses_info, "raw": raw_info, "track-log": track_log_info}[sub](path)
    if kind == "json":
        from ..io._jsontext import load_json_file

        doc = load_json_file(path, "an openemt calibration or correction JSON file")
        if isinstance(doc, dict) and doc.get("format") == "openemt.correction":
            return correction_info(path)
    if kind in ("json", "mat"):
        from ..io import read_calibration

        return calibration_info(read_calibration(path))
    if kind == "tsv":
        return ndi_info(path)
    return pose_csv_info(path)
