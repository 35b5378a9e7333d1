"""Tool poses or points from any pose file openemt writes or reads: the one reader of the
navigation steps (``pivot``, ``spin``, ``register``, ``assess``, ``points``, ``align``).

* ``.h5``: an ``openemt solve`` poses file, an ``openemt track --log`` log (one sensor, or
  ``sensor`` naming one of several) or a dataset with poses (``openemt import ndi|poses``, a
  simulation);
* ``.csv``: an ``openemt track --log`` CSV (``status`` and, for several sensors, ``sensor``
  columns) or any pose CSV (:func:`openemt.io.read_poses_csv`: ``x, y, z`` with an optional
  ``_m``/``_mm`` suffix, rotation vector or quaternion columns, ``pose_id`` groups);
* ``.fcsv`` / ``.mrk.json``: 3D Slicer markups (positions only, :mod:`._markups`).

Every row that cannot be used is kept as a NaN row (so rows keep their file numbers) and
counted by reason in ``ToolPoses.dropped``: ``not_converged`` (a solve or track status other
than converged), ``not_finite`` (missing or non-finite values), ``bad_line`` (a CSV row with
the wrong number of fields), ``undefined`` (markups points whose position is not defined),
``out_of_range`` (a position farther than ``MAX_POSITION`` from the origin: a wrong unit or
garbage, never a tracked pose).
Refused with one line: a file larger than ``MAX_POSE_FILE_BYTES`` or with more than
``MAX_POSE_ROWS`` rows (checked before parsing), rotation blocks that are not rotations (more
than ``ROTATION_TOLERANCE`` from orthonormal, or a reflection), and a file without one usable
row (e.g. a solve output where nothing converged).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._errors import InputError
from ..geometry import pose_from_rt

__all__ = ["MAX_POSE_FILE_BYTES", "MAX_POSE_ROWS", "MAX_POSITION", "ROTATION_TOLERANCE",
           "ToolPoses", "check_rotations", "read_points_csv", "read_tool_poses"]

#: Largest pose text file read (bytes), refused by its size before parsing: a CSV parses at
#: about 9 times its size in peak memory (25 MiB: 220 MiB, 5 s; 2e6 poses fit).
MAX_POSE_FILE_BYTES = 256 << 20
#: Most rows read from one file (an HDF5 file is refused by its shapes before reading).
MAX_POSE_ROWS = 5_000_000
#: Farthest position (m) read as a pose; farther rows are left out as ``out_of_range``.
MAX_POSITION = 1e4
#: Largest ``max |R^T R - I|`` of a rotation block (float32 storage rounds to about 1e-7).
ROTATION_TOLERANCE = 1e-5
_TRACK_FORMAT = "openemt-track"


@dataclass(frozen=True, eq=False)
class ToolPoses:
    """Poses read by :func:`read_tool_poses`.

    Attributes
    ----------
    poses : ndarray, shape (N, 4, 4)
        In metres; NaN rows for samples that failed or could not be read.
    has_orientation : bool
        False for position-only inputs (rotations are then identity).
    groups : ndarray or None
        Label of the repeated sample group per row (``pose_id`` column, or markups labels
        that repeat), None if every row is its own point.
    kind : str
        ``poses-h5`` (solve output), ``track-log``, ``dataset``, ``csv`` or ``markups``.
    dropped : dict of str -> int
        Rows left out (NaN) by reason, see the module docstring.
    times : ndarray, shape (N,) or None
        Sample times (s), where the file has them.
    labels : ndarray of str or None
        Point labels (markups, or a CSV ``pose_id`` column).
    frame : ndarray of int or None
        Tracker frame numbers (pose datasets and CSVs with a ``frame`` column).
    """

    poses: np.ndarray
    has_orientation: bool
    groups: np.ndarray | None
    kind: str
    dropped: dict = field(default_factory=dict)
    times: np.ndarray | None = None
    labels: np.ndarray | None = None
    frame: np.ndarray | None = None

    @property
    def n_usable(self) -> int:
        return int(np.all(np.isfinite(self.poses), axis=(1, 2)).sum())

    def note(self, source) -> str | None:
        """One line saying which rows were left out, None if none."""
        parts = [f"{v} {k.replace('_', ' ')}" for k, v in self.dropped.items() if v]
        if not parts:
            return None
        return (f"left out {sum(self.dropped.values())} of {len(self.poses)} rows of "
                f"{Path(source).name}: {', '.join(parts)}")


def check_rotations(P: np.ndarray, source) -> None:
    """Refuse rotation blocks that are not rotations (finite rows only; see the module)."""
    ok = np.all(np.isfinite(P), axis=(1, 2))
    if not ok.any():
        return
    R = P[ok, :3, :3]
    dev = np.abs(np.einsum("nki,nkj->nij", R, R) - np.eye(3)).max(axis=(1, 2))
    bad = (dev > ROTATION_TOLERANCE) | (np.linalg.det(R) < 0)
    if bad.any():
        rows = np.flatnonzero(ok)[bad]
        raise InputError(f"expected rotation blocks within {ROTATION_TOLERANCE:g} of a rotation "
                         f"in {source}, got {len(rows)} that are not (first row {rows[0]}, "
                         f"max |R^T R - I| {dev[bad].max():.3g}, det "
                         f"{np.linalg.det(R[bad][0]):.3g}): scaled, sheared or reflected poses")


def _is_h5(path) -> bool:
    return str(path).lower().endswith((".h5", ".hdf5"))


def _rows_bounded(n: int, path) -> None:
    if n > MAX_POSE_ROWS:
        raise InputError(f"expected at most {MAX_POSE_ROWS} rows in {path}, got {n}: split the "
                         f"recording")


def _status_rows(P, status, dropped):
    from ..solve import Status

    bad = np.asarray(status) != int(Status.CONVERGED)
    P = np.array(P, dtype=np.float64)
    dropped["not_converged"] = int((bad & np.all(np.isfinite(P), axis=(1, 2))).sum())
    P[bad] = np.nan
    return P


def _pick_sensor(names, sensor, path):
    if sensor is None and len(names) == 1:
        return names[0]
    if sensor not in names:
        raise InputError(f"expected --sensor naming one of {', '.join(map(str, names))} for "
                         f"{path}, got {'none' if sensor is None else repr(sensor)}")
    return sensor


def _read_h5(path: Path, sensor):
    from ..io._h5safe import committed_rows, open_h5
    from ..solve import POSES_SCHEMA

    dropped: dict = {}
    with open_h5(path, "an openemt poses file, track log or pose dataset") as f:
        schema = f.attrs.get("schema", f.attrs.get("format"))
        schema = schema.decode() if isinstance(schema, bytes) else schema
        if schema in (POSES_SCHEMA, _TRACK_FORMAT):
            g = f
            if schema == _TRACK_FORMAT and int(f.attrs.get("version", 1)) >= 2:
                names = [s.decode() if isinstance(s, bytes) else str(s)
                         for s in f.attrs.get("sensors", [])]
                g = f.get(f"sensors/{_pick_sensor(names, sensor, path)}")
            if g is None or not all(k in g and hasattr(g[k], "shape") for k in
                                    ("poses", "status")):
                raise InputError(f"expected datasets poses and status in {path}, got "
                                 f"{sorted(g) if g is not None else 'no sensor group'}")
            n = committed_rows(g, ("poses",))   # a track log commits its rows (killed session)
            _rows_bounded(n, path)
            if g["poses"].shape[1:] != (4, 4) or g["status"].ndim != 1 or \
                    g["status"].shape[0] < n or g["poses"].dtype.kind not in "fiu" or \
                    g["status"].dtype.kind not in "iu":
                raise InputError(f"expected real poses (N, 4, 4) and integer status (N,) in "
                                 f"{path}, got {g['poses'].dtype} {g['poses'].shape} and "
                                 f"{g['status'].dtype} {g['status'].shape}")
            times = g["times"][:n] if "times" in g and g["times"].shape[:1] >= (n,) else None
            P = _status_rows(g["poses"][:n], g["status"][:n], dropped)
            kind = "poses-h5" if schema == POSES_SCHEMA else "track-log"
            return ToolPoses(P, True, None, kind, dropped,
                             None if times is None else np.asarray(times, float))
        shape = getattr(f.get("poses"), "shape", None)
        if shape:
            _rows_bounded(shape[0], path)
    from ..io import read_pose_dataset

    ds = read_pose_dataset(path)
    fr = ds.extra.get("frame")
    times = ds.extra.get("times")
    return ToolPoses(np.array(ds.poses, dtype=np.float64), True, None, "dataset", dropped,
                     None if times is None else np.asarray(times, float),
                     frame=None if fr is None else np.asarray(fr, np.int64))


def _read_csv(path: Path, length_unit, angle_unit, sensor):
    from ..io import read_poses_csv

    t = read_poses_csv(path, length_unit=length_unit, angle_unit=angle_unit)
    keep = np.ones(len(t.poses), bool)
    if t.sensor is not None:
        names = list(dict.fromkeys(t.sensor.tolist()))
        keep = t.sensor == _pick_sensor(names, sensor, path)
    sel = np.flatnonzero(keep)
    P = np.array(t.poses[sel], dtype=np.float64)
    dropped = {"bad_line": len(t.bad_lines)}
    kind = "csv"
    if "status" in t.columns:
        kind = "track-log" if "distorted" in t.columns else "csv"
        st = t.columns["status"][sel]
        P = _status_rows(P, np.where(np.isfinite(st), st, -1), dropped)
    return ToolPoses(P, t.has_orientation,
                     None if t.group is None else t.group[sel], kind, dropped,
                     None if t.time is None else t.time[sel],
                     labels=None if t.group is None else t.group[sel],
                     frame=None if t.frame is None else t.frame[sel])


def read_tool_poses(path, *, length_unit: str = "m", angle_unit: str = "rad",
                    sensor: str | None = None) -> ToolPoses:
    """Read tool poses from any pose file (see the module docstring).

    ``length_unit`` and ``angle_unit`` apply to CSV columns without a unit suffix; ``sensor``
    picks one sensor of a several-sensor track log.
    """
    from ..io._safefile import check_regular
    from ._markups import is_markups_path, read_markups

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"expected a pose file, got missing file {str(path)!r}")
    st = check_regular(path, "a pose file")
    if _is_h5(path):
        t = _read_h5(path, sensor)
    else:
        if st.st_size > MAX_POSE_FILE_BYTES:
            raise InputError(f"expected a pose file of at most {MAX_POSE_FILE_BYTES >> 20} MiB, "
                             f"got {path.name} of {st.st_size >> 20} MiB")
        if is_markups_path(path):
            m = read_markups(path)
            P = pose_from_rt(np.eye(3), m.points)
            repeated = len(np.unique(m.labels)) < len(m.labels)
            t = ToolPoses(P, False, m.labels if repeated else None, "markups",
                          {"undefined": m.n_undefined}, labels=m.labels)
        else:
            t = _read_csv(path, length_unit, angle_unit, sensor)
    finite = np.all(np.isfinite(t.poses), axis=(1, 2))
    counted = t.dropped.get("not_converged", 0) + t.dropped.get("bad_line", 0)
    t.dropped["not_finite"] = int((~finite).sum()) - counted
    far = finite & ~(np.abs(t.poses[:, :3, 3]).max(axis=1, initial=0) <= MAX_POSITION)
    if far.any():
        t.poses[far] = np.nan
        finite &= ~far
    t.dropped["out_of_range"] = int(far.sum())
    if t.has_orientation:
        check_rotations(t.poses, path)
    if not finite.any():
        why = ", ".join(f"{v} {k.replace('_', ' ')}" for k, v in t.dropped.items() if v)
        raise InputError(f"expected at least one usable pose in {path}, got none of "
                         f"{len(t.poses)} rows" + (f" ({why})" if why else ""))
    return t


def read_points_csv(path, *, length_unit: str = "m") -> np.ndarray:
    """Positions (N, 3) in metres from a CSV with ``x, y, z`` columns (suffix ``_m``/``_mm``,
    see :func:`openemt.io.read_poses_csv`); a row that is not finite is refused."""
    from ..io import read_poses_csv

    t = read_poses_csv(path, length_unit=length_unit)
    bad = list(t.bad_lines) + list(t.nonfinite_lines)
    if bad:
        raise InputError(f"expected finite x, y, z on every row of {path}, got missing or "
                         f"non-finite values on lines {', '.join(map(str, sorted(bad)[:10]))}")
    return t.poses[:, :3, 3].copy()


def read_transform_file(path, what: str, fmt: str, key: str, *, kind: str | None = None):
    """``(T, d)``: the 4x4 matrix under ``key`` (not checked further) and the whole dict of a
    JSON file openemt writes with ``"format": fmt`` (and ``"kind": kind``), ``what`` naming it
    in the one-line error for another file."""
    from ..io._jsontext import load_json_file

    path = Path(path)
    d = load_json_file(path, what)
    if not isinstance(d, dict) or d.get("format") != fmt or \
            (kind is not None and d.get("kind") != kind):
        got = d.get("format") if isinstance(d, dict) else type(d).__name__
        expected = f"format {fmt!r}" + ("" if kind is None else f", kind {kind!r}")
        raise InputError(f"expected {what} ({expected}) in {path}, got {got!r}")
    try:
        T = np.asarray(d.get(key), dtype=np.float64)
    except (TypeError, ValueError):
        T = np.zeros(0)
    return T, d
