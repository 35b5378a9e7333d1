"""What a live session writes while it runs: the per-sample log (``track --log``) and the raw
recording (``track --save-raw``), appended in chunks (:mod:`openemt.io._stream`), and their
readers, which accept the file of a killed session (marked incomplete).

Log layout (``.h5``/``.hdf5``): one sensor (version 1): datasets at the root ``times`` (s),
``poses`` (N, 4, 4) m, ``pose_vectors`` (N, 6) m/rad, ``status`` int8, ``residual``,
``distortion``, ``distorted`` bool, ``couplings`` complex (N, n_source, n_sensor),
``distortion_level`` uint8 (0-255, :func:`openemt.live.distortion_level`); attrs
``format = "openemt-track"``, ``version = 1``, ``complete``, ``rows``; from a serial or TCP
source also ``source`` and ``link`` (the link counters as JSON text; docs/live.md, "Lost,
damaged and restarted streams"). Several sensors
(version 2): the same datasets in one group per sensor (``/sensors/<name>/...``, each with its
``rows``) and the attribute ``sensors`` (names in tracker-file order).

Both carry the time of each sample (docs/live.md#time): ``acquisition_time`` (UTC, epoch s, on
the ADC's sample clock) and ``latency`` (s from it to the OpenIGTLink send; NaN when the
source was not paced in real time).

CSV: columns ``time_s, x_m, y_m, z_m, rx_rad, ry_rad, rz_rad, status, residual, distortion,
distorted, distortion_level, acquisition_time_s, latency_s`` (logs written without the last
three are still read); several sensors: a ``sensor`` column (the name) after ``time_s``, one row per
sensor and sample, the sensors of one sample on consecutive rows.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._errors import InputError
from ..io._stream import CsvStream, H5Stream
from ._backends import BackendWrapper

__all__ = ["RawRecorder", "TrackLogData", "TrackLogWriter", "read_track_log",
           "track_log_dataset"]

TRACK_FORMAT = "openemt-track"
LOG_KEYS = ("times", "poses", "pose_vectors", "status", "residual", "distortion",
            "distorted", "couplings", "distortion_level", "acquisition_time", "latency")
#: the time columns (docs/live.md#time): NaN where a writer gave none
_TIME_KEYS = ("acquisition_time", "latency")
#: the columns of logs written before the distortion level and the times (still read)
_CSV_COLS_V1 = "x_m,y_m,z_m,rx_rad,ry_rad,rz_rad,status,residual,distortion,distorted"
_CSV_COLS = _CSV_COLS_V1 + ",distortion_level,acquisition_time_s,latency_s"
_CSV_FMT = ["%.6f"] + ["%.9g"] * 6 + ["%d", "%.6g", "%.6g", "%d", "%d", "%.6f", "%.6g"]


def _log_kind(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix in (".h5", ".hdf5"):
        return "h5"
    if suffix == ".csv":
        return "csv"
    raise InputError(f"expected a log file ending in .h5, .hdf5 or .csv, got {str(path)!r}")


class TrackLogWriter:
    """Streams the per-sample outputs of every sensor to ``path`` as the session runs.

    Has the interface of :class:`~openemt.live.TrackLog` that the pipeline uses
    (``set_sensors``, ``append``); the file appears at ``path`` once it holds a row (see
    :mod:`openemt.io._stream`). Call :meth:`close` at the end (or :meth:`abort`).
    """

    def __init__(self, path, sensor_names=None, *, flush_seconds: float = 1.0,
                 max_buffered_bytes: int = 64 << 20):
        self.path = Path(path)
        self.kind = _log_kind(self.path)
        self.flush_seconds = float(flush_seconds)
        self.max_buffered_bytes = int(max_buffered_bytes)
        self.sensor_names: tuple = ()
        self._stream = None
        self._flush_first = None
        self._appended = False
        self._pending: list = []
        self.set_sensors(sensor_names if sensor_names is not None else ("openemt",))

    @property
    def flush_first(self):
        """A stream committed before every flush of the log (``openemt track`` sets the raw
        recording's, so that a killed session's raw file holds every logged pose's samples)."""
        return self._flush_first

    @flush_first.setter
    def flush_first(self, stream) -> None:
        self._flush_first = stream
        if self._stream is not None:
            self._stream.flush_first = stream

    @property
    def published(self) -> bool:
        """True once the file is at ``path`` (it held a row, or the session ended cleanly)."""
        return self._stream is not None and self._stream.published

    @property
    def rows(self) -> int:
        """Samples (per sensor) flushed to the file so far."""
        if self._stream is None:
            return 0
        if self.kind == "csv":
            return self._stream.rows // max(1, len(self.sensor_names))
        return self._stream.rows_total // max(1, len(self.sensor_names))

    def set_sensors(self, names) -> None:
        """Name the sensors (before anything is appended); opens the file."""
        names = tuple(names)
        if self._stream is not None:
            if names == self.sensor_names:
                return
            if self._appended:
                raise InputError(f"expected sensors {self.sensor_names} for a log that holds "
                                 f"samples, got {names}")
            self._stream.abort()
        self.sensor_names = names
        self._pending = [None] * len(names)
        multi = len(names) > 1
        if self.kind == "h5":
            attrs = {"format": TRACK_FORMAT, "version": 2 if multi else 1}
            if multi:
                attrs["sensors"] = list(names)
            self._stream = _H5Log(self.path, attrs, flush_seconds=self.flush_seconds,
                                  max_buffered_bytes=self.max_buffered_bytes)
            self._stream.flush_first = self._flush_first
        else:
            head = f"time_s,sensor,{_CSV_COLS}" if multi else f"time_s,{_CSV_COLS}"
            self._stream = CsvStream(self.path, head, flush_seconds=self.flush_seconds,
                                     max_buffered_bytes=self.max_buffered_bytes)
            self._stream.flush_first = self._flush_first

    def append(self, step, sensor: int = 0) -> None:
        """Add one chunk of one sensor (a :class:`~openemt.live.TrackStep`)."""
        self.append_arrays({k: getattr(step, k) for k in LOG_KEYS}, sensor)

    def append_arrays(self, arrays: dict, sensor: int = 0) -> None:
        """Add rows of one sensor given as arrays (the keys of :data:`LOG_KEYS`)."""
        k = len(self.sensor_names)
        if k == 1:
            self._add([arrays])
        else:
            self._pending[sensor] = arrays
            if all(p is not None for p in self._pending):   # every sensor of this chunk
                parts, self._pending = self._pending, [None] * k
                self._add(parts)
        self._stream.maybe_flush()

    def _add(self, parts) -> None:
        n = len(parts[0]["times"])
        if not n:
            return
        self._appended = True
        for a in parts:
            for key in _TIME_KEYS:
                if a.get(key) is None:
                    a[key] = np.full(n, np.nan)
            if a.get("distortion_level") is None:     # rows given without one: the worst
                a["distortion_level"] = _levels_of(a).astype(np.uint8)
        if self.kind == "h5":
            multi = len(parts) > 1
            for name, a in zip(self.sensor_names, parts):
                self._stream.append(f"sensors/{name}" if multi else "/",
                                    {key: a[key] for key in LOG_KEYS})
            return
        tables = [np.column_stack([a["times"], np.asarray(a["pose_vectors"]).reshape(-1, 6),
                                   a["status"], a["residual"], a["distortion"],
                                   np.asarray(a["distorted"]).astype(int),
                                   _levels_of(a), a["acquisition_time"], a["latency"]])
                  for a in parts]
        buf = io.StringIO()
        if len(tables) == 1:
            np.savetxt(buf, tables[0], delimiter=",", fmt=_CSV_FMT)
        else:
            line = ",".join(_CSV_FMT)
            m = min(len(t) for t in tables)
            for r in range(m):
                for name, t in zip(self.sensor_names, tables):
                    head, rest = (line % tuple(t[r])).split(",", 1)
                    buf.write(f"{head},{name},{rest}\n")
        self._stream.append(buf.getvalue(), n * len(tables))

    def flush(self) -> None:
        self._stream.flush()

    def set_attrs(self, attrs: dict) -> None:
        """File attributes of an HDF5 log (a CSV log has no place for them)."""
        if self.kind == "h5" and self._stream is not None:
            self._stream.group_attrs("/", attrs)

    def close(self, *, keep_empty: bool = True) -> None:
        """Write what is buffered, mark the file complete and close it (see
        :meth:`openemt.io._stream.H5Stream.close` for ``keep_empty``)."""
        self._stream.close(keep_empty=keep_empty)

    def abort(self) -> None:
        """Close without the buffered rows; the flushed ones stay readable."""
        if self._stream is not None:
            self._stream.abort()


def _levels_of(a) -> np.ndarray:
    """The ``distortion_level`` column of rows ``a`` (255 where rows come without one)."""
    lv = a.get("distortion_level")
    n = len(a["times"])
    return np.full(n, 255) if lv is None or len(lv) != n else np.asarray(lv).astype(int)


class _H5Log(H5Stream):
    """An H5Stream whose ``rows_total`` counts rows over all groups."""

    @property
    def rows_total(self) -> int:
        return sum(self._group_rows.values())


@dataclass(frozen=True)
class TrackLogData:
    """A log read back (:func:`read_track_log`).

    Attributes
    ----------
    sensors : tuple of str
        Sensor names in file order.
    arrays : dict
        Sensor name -> ``{key: array}`` (:data:`LOG_KEYS`; a CSV log has no ``poses`` or
        ``couplings``).
    complete : bool or None
        False for the file of a session that was killed (or ended by an error) before it
        closed the file; None when the format cannot tell (CSV).
    """

    sensors: tuple
    arrays: dict = field(default_factory=dict)
    complete: bool | None = True

    @property
    def rows(self) -> int:
        """Samples per sensor."""
        return min((len(a["times"]) for a in self.arrays.values()), default=0)


#: Datasets every sensor of a log has; a log without them is refused, not read as empty.
REQUIRED_LOG_KEYS = ("times", "status")


def _read_group(g, keys) -> dict:
    lacking = [k for k in REQUIRED_LOG_KEYS if k not in g]
    if lacking:
        raise InputError(f"expected datasets {' and '.join(REQUIRED_LOG_KEYS)} per sensor in "
                         f"a track log, got none named {', '.join(lacking)} in "
                         f"{g.file.filename!r}{'' if g.name == '/' else ' ' + g.name}")
    from ..io._h5safe import committed_rows

    n = committed_rows(g, [k for k in keys if k in g])
    return {k: (np.asarray(g[k][:n]) if k in g else np.empty(0)) for k in keys}


def read_track_log(path) -> TrackLogData:
    """Read a ``track --log`` file (.h5/.hdf5 or .csv), also one whose session was killed:
    only the rows the file committed are read, ``complete`` tells whether it ended cleanly.

    Raises
    ------
    InputError
        The file is not an openemt track log (one line naming it).
    """
    path = Path(path)
    kind = _log_kind(path)
    if not path.is_file():
        raise InputError(f"expected an existing track log file, got {str(path)!r}")
    if kind == "csv":
        return _read_csv_log(path)
    from ..io._h5safe import open_h5

    try:
        with open_h5(path, "an openemt track log") as f:
            fmt = f.attrs.get("format")
            fmt = fmt.decode() if isinstance(fmt, bytes) else fmt
            if fmt != TRACK_FORMAT:
                raise InputError(f"expected an HDF5 file with format {TRACK_FORMAT!r}, got "
                                 f"{fmt!r} in {str(path)!r}")
            complete = bool(f.attrs.get("complete", True))
            if int(f.attrs.get("version", 1)) >= 2:
                names = tuple(str(s.decode() if isinstance(s, bytes) else s)
                              for s in f.attrs["sensors"])
                missing = [n for n in names if f"sensors/{n}" not in f]
                if missing and complete:   # a killed session may not have made them yet
                    raise InputError(f"expected a group /sensors/<name> per sensor in the "
                                     f"track log {str(path)!r}, got none for {missing}")
                arrays = {n: (_read_group(f[f"sensors/{n}"], LOG_KEYS)
                              if f"sensors/{n}" in f else
                              {k: np.empty(0) for k in LOG_KEYS}) for n in names}
                m = min((len(a["times"]) for a in arrays.values()), default=0)
                arrays = {n: {k: v[:m] for k, v in a.items()} for n, a in arrays.items()}
            else:
                names = ("openemt",)
                arrays = {"openemt": _read_group(f, LOG_KEYS)}
    except InputError:
        raise
    except (OSError, KeyError, TypeError, ValueError) as exc:
        msg = " ".join(str(exc).split())
        raise InputError(f"expected a readable openemt track log, got {str(path)!r} "
                         f"({msg})") from None
    return TrackLogData(sensors=names, arrays=arrays, complete=complete)


def track_log_dataset(log: TrackLogData, sensor: str | None = None, name: str = ""):
    """The couplings one sensor of a track log (:func:`read_track_log`, an .h5 log) recorded,
    as a :class:`~openemt.io.Dataset` marked as a recording (``meta["recording"]``, the sample
    rate from the median time step), so that ``openemt solve`` solves its rows as a time
    series; the sample times go to ``extra["times"]`` (s)."""
    from ..io import Dataset, recording_meta

    if sensor is None:
        if len(log.sensors) != 1:
            raise InputError(f"expected --sensor naming one of {', '.join(log.sensors)} for a "
                             f"log of {len(log.sensors)} sensors, got none")
        sensor = log.sensors[0]
    if sensor not in log.arrays:
        raise InputError(f"expected a sensor of the log ({', '.join(log.sensors)}), got "
                         f"{sensor!r}")
    a = log.arrays[sensor]
    C = np.asarray(a.get("couplings", np.empty(0)))
    if C.ndim != 3 or not len(C):
        raise InputError(f"expected a track log with couplings (an .h5 log with rows), got "
                         f"{'no rows' if C.ndim == 3 else 'no couplings (a CSV log?)'} for "
                         f"sensor {sensor!r}")
    n = len(C)
    times = np.asarray(a["times"][:n], dtype=np.float64)
    steps = np.diff(times)
    rate = 1.0 / float(np.median(steps)) if steps.size and np.median(steps) > 0 else None
    return Dataset(couplings=C, stage=np.zeros((n, 6)), source_fixture="", sensor_fixture="",
                   pattern="recording", file_index=np.zeros(n, np.int64),
                   files=(name or "track log",), extra={"times": times},
                   meta={"format": TRACK_FORMAT, "sensor": {"name": sensor},
                         "complete": log.complete,
                         "recording": recording_meta(rate, "openemt track --log")})


def _read_csv_log(path: Path) -> TrackLogData:
    text = path.read_text(encoding="utf-8", errors="strict")
    lines = text.split("\n")
    head = lines[0].strip().split(",") if lines else []
    multi = head[:2] == ["time_s", "sensor"]
    lead = ["time_s", "sensor"] if multi else ["time_s"]
    cols = next((c.split(",") for c in (_CSV_COLS, _CSV_COLS_V1)
                 if head == lead + c.split(",")), None)
    if cols is None:
        raise InputError(f"expected a track log CSV header 'time_s,{_CSV_COLS}', got "
                         f"{lines[0][:80]!r} in {str(path)!r}")
    body = lines[1:]
    complete = None
    if body and body[-1] == "":
        body = body[:-1]
    elif body:                    # a torn last line: the session was killed while writing
        body, complete = body[:-1], False
    rows: dict = {}
    order: list = []
    width = len(cols) + 1 + multi
    for i, line in enumerate(body, 2):
        f = line.split(",")
        if len(f) != width:
            raise InputError(f"expected {width} columns on line {i} of {str(path)!r}, got "
                             f"{len(f)}")
        name = f.pop(1) if multi else "openemt"
        if name not in rows:
            rows[name] = []
            order.append(name)
        try:
            rows[name].append([float(x) for x in f])
        except ValueError:
            raise InputError(f"expected numbers on line {i} of {str(path)!r}, got "
                             f"{line[:80]!r}") from None
    arrays = {}
    m = min((len(r) for r in rows.values()), default=0)
    for name in order or ["openemt"]:
        t = np.asarray(rows.get(name, [])[:m], dtype=np.float64).reshape(-1, width - multi)
        arrays[name] = {"times": t[:, 0], "pose_vectors": t[:, 1:7],
                        "status": t[:, 7].astype(np.int8), "residual": t[:, 8],
                        "distortion": t[:, 9], "distorted": t[:, 10].astype(bool),
                        "distortion_level": (t[:, 11].astype(np.uint8) if t.shape[1] > 11
                                             else np.empty(0, np.uint8)),
                        **({"acquisition_time": t[:, 12], "latency": t[:, 13]}
                           if t.shape[1] > 13 else {})}
    return TrackLogData(sensors=tuple(order or ["openemt"]), arrays=arrays, complete=complete)


class RawRecorder(BackendWrapper):
    """A backend wrapper that streams every raw chunk read (and, for simulations, the truth
    at the output rate) to an HDF5 raw file (:func:`openemt.signal.write_raw` schema, plus
    ``rows``/``complete``) while the session runs."""

    def __init__(self, backend, path, *, truth_rate: float, flush_seconds: float = 1.0):
        from ..signal._rawsim import raw_attrs

        super().__init__(backend)
        self.truth_rate = float(truth_rate)
        self._n = 0
        self._k = 0
        self._truth = callable(getattr(backend, "true_couplings", None))
        self.stream = H5Stream(path, raw_attrs(backend.layout, 0.0),
                               chunk_rows={"/": 16384, "truth": 1500},
                               flush_seconds=flush_seconds)

    def read(self):
        x = self.backend.read()
        if x is None or not len(x):
            return x
        self.stream.append("/", {"samples": x})
        self._n += len(x)
        if self._truth:
            fs = self.backend.layout.sample_rate
            k1 = math.ceil((self._n / fs) / (1.0 / self.truth_rate))
            if k1 > self._k:
                tt = np.arange(self._k, k1) / self.truth_rate
                self.stream.append("truth", {
                    "times": tt, "couplings": self.backend.true_couplings(tt),
                    "poses": np.asarray(self.backend.truth_poses(tt))})
                self._k = k1
        self.stream.maybe_flush()
        return x

    @property
    def rows(self) -> int:
        """Raw samples flushed to the file so far."""
        return self.stream.group_rows("/")

    @property
    def published(self) -> bool:
        return self.stream.published

