"""The real-time chain: backend -> demodulation -> warm-started LM solve -> optional correction
-> filter -> registration -> tool tip -> OpenIGTLink, log, per-sample status and distortion
flag.

The solver is injected: any callable ``solver(couplings (N, n_so, n_se) real, initial)``
returning an object with ``poses (N, 4, 4)``, ``pose_vectors (N, 6)``, ``status (N,)`` and
``residual (N,)`` (the :class:`openemt.solve.SolveResult` fields). ``initial`` is either
``(N, 6)`` pose vectors (warm start from the last valid pose) or a start name when no valid
pose is known yet: the model's ``cold_start`` (``"kim18"`` for the dipole family; ``"kim18"``
for an injected solver). The default is :func:`openemt.solve.prepare`'s solver of the model.
"""

from __future__ import annotations

import collections
import dataclasses
import itertools
import time
from dataclasses import dataclass, field, replace

import numpy as np

from .._compile_notice import serial_threads
from .._constants import OUTPUT_RATE_HZ
from .._errors import InputError, check_nonnegative
from .._result import Result
from ..signal import Demodulator, distortion_ratio
from ..solve import DEFAULT_BAND_TIME_CONSTANT_S, BandStage, Status, resolve_bands
from ..solve._result import status_count_names
from ..solve._validity import MAX_RELATIVE_RESIDUAL
from ._filter import filter_restarts
from ._igtl_meta import distortion_level, transform_metadata
from ._tracker_file import (
    check_device_names,
    relative_device_name,
    state_device_name,
    status_device_name,
    tip_device_name,
)

__all__ = ["STREAM_EVENTS", "PipelineConfig", "SensorSetup", "TrackLog", "TrackStep",
           "TrackSummary", "TrackingPipeline", "lm_solver", "state_device_name"]

_CONVERGED = int(Status.CONVERGED)
_OUT_OF_VOLUME = int(Status.OUT_OF_VOLUME)

#: The stream states a sensor's ``<device>State`` STRING message reports on change.
STREAM_EVENTS = ("tracking", "lost", "distorted", "stale", "recovered")


#: The witnesses' largest position error (m) above which a chunk's environment terms are
#: re-estimated from them (below it the witnesses see no distortion worth modelling).
WITNESS_REFIT_M = 0.5e-3


def _witness_estimator(models, poses):
    """A :class:`openemt.calibrate.WitnessEstimator` of the witnesses (one induced dipole)
    when they share one model and give it enough equations, else None (the witnesses then
    only enter the distortion level)."""
    if not models or any(m is None or m is not models[0] for m in models):
        return None
    from ..calibrate import WitnessEstimator

    try:
        return WitnessEstimator(models[0], np.stack(poses))
    except InputError:
        return None


def _transform(value, name: str):
    """``value`` as a finite (4, 4) float64 array, or None for None."""
    if value is None:
        return None
    T = np.asarray(value, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise InputError(f"expected a finite (4, 4) `{name}`, got shape {T.shape}")
    return T


def _status_name(code) -> str:
    """The :class:`~openemt.solve.Status` name of ``code`` (a custom solver's own code as
    its number)."""
    try:
        return Status(int(code)).name
    except ValueError:  # pragma: no cover - a custom solver's own code
        return str(int(code))


def _level_summary(counts) -> dict:
    """``max``, ``median``, ``p95`` of the distortion levels counted per level (None before
    any sample) and ``fraction_at_or_above_128`` (at or beyond a threshold)."""
    c = np.asarray(counts)
    n = int(c.sum())
    if not n:
        return {"max": None, "median": None, "p95": None, "fraction_at_or_above_128": 0.0}
    cum = np.cumsum(c)
    return {"max": int(np.flatnonzero(c)[-1]),
            "median": int(np.searchsorted(cum, 0.5 * n)),
            "p95": int(np.searchsorted(cum, 0.95 * n)),
            "fraction_at_or_above_128": float(c[128:].sum() / n)}


def lm_solver(model, *, hemisphere="+x", **kwargs):
    """The default solver callable: :func:`openemt.solve.prepare` of ``model`` (a
    :class:`openemt.solve._prepared.PreparedLM`: the model, options, concentric start model
    and hemisphere are checked and packed here, not on every chunk; the results of
    :func:`openemt.solve.solve_lm`). ``kwargs`` are :class:`openemt.solve.SolveOptions` fields.

    ``hemisphere`` only matters while (re)acquiring with the closed-form start; afterwards
    each sample starts from the previous valid pose.
    """
    from ..solve import prepare

    return prepare(model, hemisphere=hemisphere, **kwargs)


@dataclass(frozen=True, eq=False)
class TrackStep:
    """Outputs of one processed chunk (N samples, possibly 0).

    Attributes
    ----------
    times : ndarray, shape (N,)
        Sample time (s from the first raw sample; frame centres).
    couplings : ndarray, shape (N, n_source, n_sensor), complex
        Demodulated couplings (real = coupling, imaginary = quadrature).
    poses : ndarray, shape (N, 4, 4)
        Sensor poses (m), corrected if a correction is configured.
    pose_vectors : ndarray, shape (N, 6)
        ``[x, y, z, rx, ry, rz]`` of ``poses``.
    status : ndarray, shape (N,), int8
        :class:`openemt.solve.Status` codes of the solve.
    residual : ndarray, shape (N,)
        Solver residual (ILEMT resnorm).
    distortion : ndarray, shape (N,)
        Quadrature ratio ``||Im C|| / ||C||``.
    distorted : ndarray, shape (N,), bool
        ``distortion > distortion_threshold``.
    t_ready : float
        ``time.perf_counter()`` when the demodulated couplings were available.
    relative_residual : ndarray, shape (N,), optional
        ``||C_pred - C_meas||_F / ||C_meas||_F`` of the solve (NaN where the solver reports
        none); sent as the ``RelativeResidual`` metadata.
    tool_poses : ndarray, shape (N, 4, 4), optional
        The sensor's own poses when ``poses`` are its tool tip's (a sensor with a ``tip``).
    distortion_level : ndarray, shape (N,), uint8, optional
        The 0-255 distortion level of each sample (:func:`openemt.live.distortion_level`, from
        the quadrature ratio and the relative residual; the ``DistortionLevel`` metadata).
    acquisition_time : ndarray, shape (N,), optional
        UTC (epoch s) of each sample (its frame centre) on the ADC's sample clock: the
        OpenIGTLink timestamp (docs/live.md#time).
    latency : ndarray, shape (N,), optional
        Seconds from ``acquisition_time`` to the return of the OpenIGTLink send (to the end of
        processing without a server); NaN when the source is not paced in real time.
    """

    times: np.ndarray
    couplings: np.ndarray
    poses: np.ndarray
    pose_vectors: np.ndarray
    status: np.ndarray
    residual: np.ndarray
    distortion: np.ndarray
    distorted: np.ndarray
    t_ready: float = 0.0
    relative_residual: np.ndarray | None = None
    tool_poses: np.ndarray | None = None
    distortion_level: np.ndarray | None = None
    acquisition_time: np.ndarray | None = None
    latency: np.ndarray | None = None

    def __len__(self) -> int:
        return self.times.shape[0]


@dataclass(frozen=True)
class TrackSummary(Result):
    """What a run did (JSON-ready via :meth:`to_dict`: the fields, with ``extra``'s keys at the
    top level)."""

    n_samples: int
    signal_seconds: float
    wall_seconds: float
    status_counts: dict
    distorted_fraction: float
    latency_ms_p50: float | None
    latency_ms_p99: float | None
    igtl: dict | None = None
    truth: dict | None = None
    extra: dict = field(default_factory=dict)

    def _items(self) -> dict:
        d = super()._items()
        d.update(d.pop("extra"))                # extra's keys at the top level, after the fields
        return d


def _takes_metadata(igtl) -> bool:
    """Whether ``igtl.send_poses`` takes ``metadata`` (an :class:`IgtlServer` does; a
    stand-in with the older signature gets TRANSFORMs without it)."""
    if igtl is None:
        return True
    import inspect

    try:
        params = inspect.signature(igtl.send_poses).parameters.values()
    except (TypeError, ValueError):  # pragma: no cover - not introspectable
        return True
    return any(p.name == "metadata" or p.kind is p.VAR_KEYWORD for p in params)


class TrackLog:
    """Accumulates per-sample outputs of every sensor; writes HDF5 (``.h5``/``.hdf5``) or CSV.

    One sensor (the layout of ``openemt track`` without a tracker file, version 1): HDF5
    datasets at the root: ``times`` (s), ``poses`` (N, 4, 4) m, ``pose_vectors`` (N, 6) m/rad,
    ``status`` int8, ``residual``, ``distortion``, ``distorted`` bool, ``couplings`` complex
    (N, n_source, n_sensor); attrs ``format = "openemt-track"``, ``version = 1``. CSV columns:
    ``time_s, x_m, y_m, z_m, rx_rad, ry_rad, rz_rad, status, residual, distortion, distorted``.

    Several sensors (version 2): the same datasets, one group per sensor
    (``/sensors/<name>/times``, ...), and the attribute ``sensors`` listing the names in
    tracker-file order. CSV: the column ``sensor`` (its name) after ``time_s``, one row per
    sensor and sample, sensors of one sample next to each other.
    """

    _KEYS = ("times", "poses", "pose_vectors", "status", "residual", "distortion",
             "distorted", "couplings", "distortion_level", "acquisition_time", "latency")

    def __init__(self, sensor_names=None):
        self.sensor_names = tuple(sensor_names) if sensor_names is not None else ("openemt",)
        self._parts = [{k: [] for k in self._KEYS} for _ in self.sensor_names]

    def set_sensors(self, names) -> None:
        """Name the sensors (before anything is appended)."""
        names = tuple(names)
        if any(any(v) for p in self._parts for v in p.values()) and names != self.sensor_names:
            raise InputError(f"expected sensors {self.sensor_names} for a log that holds "
                             f"samples, got {names}")
        self.sensor_names = names
        self._parts = [{k: [] for k in self._KEYS} for _ in names]

    def append(self, step: TrackStep, sensor: int = 0) -> None:
        if len(step):
            parts = self._parts[sensor]
            for k in self._KEYS:
                v = getattr(step, k)
                parts[k].append(np.full(len(step), np.nan) if v is None else v)

    def arrays(self, sensor: int | str = 0) -> dict:
        """The arrays of one sensor (index or name)."""
        if isinstance(sensor, str):
            sensor = self.sensor_names.index(sensor)
        return {k: (np.concatenate(v) if v else np.empty(0))
                for k, v in self._parts[sensor].items()}

    def write(self, path) -> None:
        """Write the log to ``path`` (``.h5``/``.hdf5`` or ``.csv``; layout in
        :mod:`openemt.live._record`), atomically."""
        from ._record import TrackLogWriter

        w = TrackLogWriter(path, self.sensor_names, flush_seconds=float("inf"),
                           max_buffered_bytes=1 << 62)       # one flush at the end: atomic
        try:
            for i in range(len(self.sensor_names)):
                w.append_arrays(self.arrays(i), i)
            w.close()
        except BaseException:
            w.abort()
            raise


@dataclass(frozen=True)
class SensorSetup:
    """One sensor of a pipeline.

    Attributes
    ----------
    name : str
        Sensor name (log, summary).
    columns : tuple of int, optional
        Columns of the demodulated coupling matrix holding this sensor's coils (None = all).
    model : DipoleModel, optional
        Model for the default solver.
    solver : callable, optional
        See the module docstring (default :func:`lm_solver` of ``model``).
    correction : ndarray (4, 4), optional
        Linear position correction of valid poses.
    hemisphere : str
    device_name : str, optional
        OpenIGTLink device name (default: the server's).
    filter : FilterSpec, optional
        Tracking filter (None or kind "none" = off).
    tip : ndarray (4, 4), optional
        Tool-tip transform (``openemt pivot``): poses are logged and scored as ``pose @ tip``
        and the tip is streamed as its own device (:func:`~openemt.live._tracker_file.
        tip_device_name`) beside the sensor's.
    """

    name: str = "openemt"
    columns: tuple | None = None
    model: object = None
    solver: object = None
    correction: object = None
    hemisphere: str = "+x"
    device_name: str | None = None
    filter: object = None
    tip: object = None


class _SensorState:
    """Run-time state of one sensor: solver, warm start, filter, counters."""

    def set_columns(self, columns) -> None:
        """Set this sensor's coupling columns (None = all); ``index_of_columns`` is a slice
        (a view, no copy) when they are consecutive, else the list."""
        self.columns = None if columns is None else list(columns)
        c = self.columns
        if c is None:
            self.index_of_columns = slice(None)
        elif c == list(range(c[0], c[0] + len(c))):
            self.index_of_columns = slice(c[0], c[0] + len(c))
        else:
            self.index_of_columns = c

    def __init__(self, setup: SensorSetup, index: int):
        solver = setup.solver
        if solver is None:
            if setup.model is None:
                raise InputError(f"expected a `model` or a `solver` for sensor "
                                 f"{setup.name!r}, got neither")
            solver = lm_solver(setup.model, hemisphere=setup.hemisphere)
        self.setup = setup
        self.index = index
        self.solver = solver
        # the start name while acquiring: the model's (the coupling-model protocol)
        self.cold_start = (getattr(setup.model, "cold_start", "kim18") if setup.solver is None
                           else "kim18")
        self.set_columns(setup.columns)
        self.correction = _transform(setup.correction, "correction")
        self.tip = None if setup.tip is None else np.asarray(setup.tip, dtype=np.float64)
        f = setup.filter
        self.filter = f if f is not None and getattr(f, "enabled", False) else None
        self.filter_state = None
        self.band_state = None       # the band fusion's low-pass state (BandStage)
        self.last = None             # last valid pose vector
        self.status_counts = np.zeros(len(Status), dtype=np.int64)   # per Status code
        self.n_distorted = 0
        self._level_counts = np.zeros(256, dtype=np.int64)   # samples per distortion level
        self._levels: list = []      # the levels of recent chunks, counted in batches
        self._n_levels = 0
        self.n_not_sent = 0          # converged but distorted, not sent
        self.err_n, self.err_ss, self.err_max = 0, 0.0, 0.0   # against the truth (simulated)
        self.state = None            # "OK", "DISTORTED", "LOST" or "STALE" (stream state)
        self.last_valid = None       # time.monotonic() of the last valid (sendable) pose
        self.bad_since = None        # time.monotonic() when the state left "OK"
        self.events = dict.fromkeys(STREAM_EVENTS, 0)

    def add_levels(self, level) -> None:
        """Count a chunk's distortion levels (in batches: one count per 1500 samples)."""
        self._levels.append(level)
        self._n_levels += len(level)
        if self._n_levels >= 1500:
            self._count_levels()

    def _count_levels(self) -> None:
        if self._levels:
            self._level_counts += np.bincount(np.concatenate(self._levels), minlength=256)
            self._levels, self._n_levels = [], 0

    @property
    def level_counts(self) -> np.ndarray:
        """Samples per distortion level (0-255) so far."""
        self._count_levels()
        return self._level_counts


@dataclass(frozen=True)
class PipelineConfig:
    """The settings of a :class:`TrackingPipeline` (one record; its fields may also be given
    as keywords of the pipeline, which override the record's).

    Attributes
    ----------
    output_rate, window, phase
        Demodulator settings (:class:`openemt.signal.Demodulator`).
    distortion_threshold : float
        Quadrature ratio above which a sample is flagged as distorted. A distorted sample is
        not sent (unless ``send_distorted``) and is solved from its warm start alone, without
        the extra starts a high residual otherwise triggers (its cost stays that of a clean
        sample); it is logged with its flag and counted in ``not_sent_distorted``.
    send_distorted : bool
        Send converged distorted samples too (they stay flagged).
    reference : str, optional
        Name of the reference sensor: every other sensor (and tip) is also streamed relative
        to it, ``inv(reference) @ sensor``, on device ``<sensor name>To<reference name>``, for
        the samples where both are valid (docs/live.md#reference-relative-output).
    stale_after : float
        Watchdog: a sensor without a valid pose for this many seconds of wall-clock time
        (also when no samples arrive) is reported ``STALE`` on its state device.
    tdata : bool
        Send all streams of one sample in one OpenIGTLink TDATA message on device
        ``tdata_device`` instead of one TRANSFORM per stream
        (:func:`openemt.live._tdata.pack_tdata`).
    tdata_device : str
    igtl_metadata : bool
        Give every TRANSFORM the OpenIGTLink version-2 metadata ``TransformStatus``,
        ``TransformValid``, ``RelativeResidual``, ``QuadratureRatio`` and ``DistortionLevel``
        (:func:`openemt.live._igtl_meta.transform_metadata`; a version-1 client gets the
        TRANSFORMs without it); False sends version-1 TRANSFORMs without metadata (so does a
        stand-in server whose ``send_poses`` takes no ``metadata``).
    igtl_every : int
        Send every ``igtl_every``-th valid pose.
    status_every : int
        Every ``status_every`` samples a STRING per sensor on its status device
        (``<From>Status``, :func:`~openemt.live._tracker_file.status_device_name`) such as
        ``"CONVERGED distorted=0 quadrature=1.2e-05"`` (the latest sample).
    serial_small_batches : bool
        Solve chunks of fewer than 256 samples with numba's parallel regions limited to this
        thread (see ``openemt bench track``'s baseline for why).
    registration : ndarray (4, 4), optional
        Image-from-tracker transform (``openemt register``) applied to every sensor's pose
        (and so its tip): the sensors stream, log and score in the image frame. Relative
        streams are unchanged by it.
    witnesses : tuple of (str, pose vector)
        Fixed witness sensors (the tracker file's ``[[witness]]``): a sensor's name and its
        known pose ``[x, y, z, rx, ry, rz]`` (m, rad) in the tracker frame (as solved, before
        any correction or registration). The largest position error of the witnesses in a
        sample (infinite where one does not converge) enters the distortion level of every
        sensor of that sample (128 at 1 mm, :func:`openemt.live.distortion_level`). Where
        the witnesses share one model and give it enough equations (two tri-axial witnesses
        per induced dipole at least) and a chunk's witness error exceeds
        :data:`WITNESS_REFIT_M`, an induced dipole is re-estimated from their couplings
        (:class:`openemt.calibrate.WitnessEstimator`) and the other sensors of that model
        are refined under it.
    bands : str
        With several carrier bands: the couplings each sensor solves
        (:class:`openemt.solve.BandStage`): ``fast``, ``slow``, ``fuse`` (the fast band
        corrected from the slow one through a low-pass of ``band_time_constant`` seconds,
        its state per sensor), ``eddy-free``; ``auto``: ``fuse``. With ``slow`` and ``fuse``
        the quadrature ratio (the distortion flag) is the slow band's. One band: ignored
        (``auto``, ``fast``) or refused.
    band_time_constant : float
    """

    output_rate: float = OUTPUT_RATE_HZ
    window: str = "hann"
    phase: object = None
    distortion_threshold: float = 1e-3
    send_distorted: bool = False
    reference: str | None = None
    stale_after: float = 0.5
    tdata: bool = False
    tdata_device: str = "openemt"
    igtl_metadata: bool = True
    igtl_every: int = 1
    status_every: int = 150
    serial_small_batches: bool = True
    registration: object = None
    witnesses: tuple = ()
    bands: str = "auto"
    band_time_constant: float = DEFAULT_BAND_TIME_CONSTANT_S


class TrackingPipeline:
    """Raw samples to poses, live, for one or several sensors.

    Every chunk is demodulated once for all sensor channels; each sensor's couplings (its
    columns of the coupling matrix) are then solved, corrected, filtered, registered, logged
    and streamed as its own OpenIGTLink TRANSFORM device (and its tip's, when it has one) in
    the same pass.

    Parameters
    ----------
    backend : Backend
        Source of raw chunks (:mod:`openemt.live`).
    sensors : sequence of SensorSetup, a SensorSetup, or a model
        The sensors (each with its columns, model or solver, correction, device name, filter
        and tip); a bare model is one sensor with the default solver of that model, named
        after the server's device.
    config : PipelineConfig, optional
        The settings; keywords named like its fields override them.
    igtl : IgtlServer, optional
        Receives every ``igtl_every``-th valid, undistorted pose of each stream (device name:
        the sensor's ``device_name``, else the server's) and the state and status STRINGs.
    log : TrackLog or TrackLogWriter, optional
        Gets the sensor names of the pipeline and every chunk of every sensor
        (:class:`~openemt.live.TrackLogWriter` streams them to a file).

    Stream states: after every chunk each sensor's state is that of its last sample (``OK``,
    ``DISTORTED``: converged with a quadrature ratio above the threshold, ``LOST``: not
    converged) or ``STALE`` (no valid pose for ``stale_after`` seconds); a change is sent once
    as a STRING on the sensor's state device (:func:`state_device_name`, ``ProbeState`` for
    ``ProbeToTracker``), e.g. ``"LOST ProbeToTracker: status OUT_OF_VOLUME"`` or
    ``"RECOVERED ProbeToTracker after 0.21 s"``, and counted in the summary (``events``).

    A pose that is not finite after the filter (a filter driven beyond its range) is marked
    ``OUT_OF_VOLUME``, never sent or logged as converged.
    """

    def __init__(self, backend, sensors, config: PipelineConfig | None = None, *, igtl=None,
                 log=None, **settings):
        cfg = config if config is not None else PipelineConfig()
        if settings:
            cfg = replace(cfg, **settings)
        self.config = cfg
        if isinstance(sensors, SensorSetup):
            sensors = [sensors]
        elif not isinstance(sensors, (list, tuple)):
            if sensors is None:
                raise InputError("expected `sensors` (SensorSetup records) or a model, got "
                                 "None")
            name = igtl.device_name if igtl is not None else "openemt"
            sensors = [SensorSetup(name=name, model=sensors)]
        sensors = list(sensors)
        if not sensors:
            raise InputError("expected at least one sensor, got none")
        names = [s.name for s in sensors]
        if len(set(names)) != len(names):
            raise InputError(f"expected distinct sensor names, got {names}")
        self.backend = backend
        self.sensors = [_SensorState(s, i) for i, s in enumerate(sensors)]
        from ..geometry import pose_from_vector

        self._witness, wposes = [], []
        for wname, pose in cfg.witnesses:
            if wname not in names:
                raise InputError(f"expected witnesses among the sensors {names}, got "
                                 f"{wname!r}")
            wposes.append(pose_from_vector(np.asarray(pose, dtype=np.float64)))
            self._witness.append((names.index(wname), wposes[-1][:3, 3]))
        self._estimator = _witness_estimator(
            [self.sensors[k].setup.model for k, _ in self._witness], wposes)
        # sensors of one model (e.g. one calibration file) share a solver and are solved in
        # one batched call while all of them are tracking
        self._groups: list = []
        shared: dict = {}
        for st in self.sensors:
            if st.setup.solver is None:
                key = (id(st.setup.model), st.setup.hemisphere)
                if key in shared:
                    st.solver = shared[key][0].solver
                    shared[key].append(st)
                    continue
                shared[key] = [st]
                self._groups.append(shared[key])
            else:
                self._groups.append([st])
        n_se = backend.layout.n_sensor
        for st in self.sensors:
            cols = st.columns
            if cols is not None and (not cols or min(cols) < 0 or max(cols) >= n_se):
                raise InputError(f"expected columns of sensor {st.setup.name!r} in "
                                 f"0..{n_se - 1} (the layout's sensor channels), got {cols}")
            if cols is not None and cols == list(range(n_se)):
                st.set_columns(None)
        # each sensor's columns, for its quadrature ratio (one compiled pass for all sensors)
        self._column_mask = np.zeros((len(self.sensors), n_se), bool)
        for st in self.sensors:
            self._column_mask[st.index, st.index_of_columns] = True
        self.demod = Demodulator(backend.layout, output_rate=cfg.output_rate,
                                 window=cfg.window, phase=cfg.phase)
        self.distortion_threshold = check_nonnegative(cfg.distortion_threshold,
                                                      "`distortion_threshold`")
        lay = backend.layout
        method = resolve_bands(cfg.bands, lay.n_bands, ordered=True,
                               rate=self.demod.output_rate,
                               where="--bands or the tracker file's [solve] bands")
        if method == "sheet":
            raise InputError("expected a band method for a live stream in fast, slow, fuse, "
                             "eddy-free (--bands or the tracker file's [solve] bands), got "
                             "sheet: its per-sample fit (tens of milliseconds a sample) is "
                             "solve's, on a dataset")
        self.bands = None if method is None else BandStage(
            method, lay.band_frequencies, time_constant=cfg.band_time_constant,
            rate=self.demod.output_rate, quadrature_threshold=self.distortion_threshold)
        self.igtl = igtl
        self.send_distorted = bool(cfg.send_distorted)
        self.interrupted = None
        self.log = log
        if log is not None:
            log.set_sensors(names)
        self.igtl_every = max(1, int(cfg.igtl_every))
        self.status_every = max(1, int(cfg.status_every))
        self.stale_after = float(cfg.stale_after)
        if not self.stale_after > 0:
            raise InputError(f"expected a positive `stale_after` in seconds, got "
                             f"{cfg.stale_after!r}")
        self.tdata = bool(cfg.tdata)
        self.tdata_device = cfg.tdata_device
        self.igtl_metadata = bool(cfg.igtl_metadata) and _takes_metadata(igtl)
        self.registration = _transform(cfg.registration, "registration")
        self.reference = None
        reference = cfg.reference
        if reference is not None:
            if reference not in names:
                raise InputError(f"expected `reference` to name a sensor in {names}, got "
                                 f"{reference!r}")
            self.reference = self.sensors[names.index(reference)]
        # every stream after the sensors' own: (sensor state, device, tip?, relative?)
        self._extra: list = [(st, tip_device_name(self._device(st)), True, False)
                             for st in self.sensors if st.tip is not None]
        if self.reference is not None:
            for st in self.sensors:
                if st is self.reference:
                    continue
                self._extra.append((st, relative_device_name(st.setup.name, reference),
                                    False, True))
                if st.tip is not None:
                    self._extra.append((st, relative_device_name(st.setup.name + "Tip",
                                                                 reference), True, True))
        self._relative = [(st, d) for st, d, _, rel in self._extra if rel]
        if igtl is not None:       # every device that goes on the wire
            devices = self.devices + [f(self._device(st)) for f in (state_device_name,
                                                                    status_device_name)
                                      for st in self.sensors]
        else:                      # the names the pipeline makes (a log needs no device)
            devices = [d for _, d, _, _ in self._extra]
        check_device_names(devices + ([self.tdata_device] if self.tdata else []),
                           "OpenIGTLink device names (sensors, tips, relative streams "
                           "<sensor>To<reference>, their state and status devices, "
                           "`tdata_device`)")
        self.events: collections.deque = collections.deque(maxlen=1000)
        # confining numba's threads only matters for solvers that may start parallel regions
        self.serial_small_batches = bool(cfg.serial_small_batches) and not all(
            getattr(st.solver, "serial", False) for st in self.sensors)
        self._n_out = 0
        self._latency = collections.deque(maxlen=200_000)   # bounded for endless runs
        # acquisition time and end-to-end latency (docs/live.md#time)
        self._e2e = collections.deque(maxlen=20_000)        # one array per chunk
        self._epoch_times = getattr(backend, "epoch_times", None)
        self._discontinuous = bool(getattr(backend, "discontinuous", False))
        self._clocked = bool(getattr(backend, "realtime", True))
        self.demod_restarts = 0
        self._truth_known = backend.truth_poses(np.zeros(1)) is not None
        self._truth_pending: list = []     # (times, [(positions, converged) per sensor])
        self._n_truth_pending = 0

    @property
    def sensor_names(self) -> list:
        return [st.setup.name for st in self.sensors]

    @staticmethod
    def _remember(st: _SensorState, vecs, status) -> None:
        if len(status) and status[-1] == _CONVERGED:      # the usual case
            st.last = vecs[-1].copy()
            return
        ok = status == _CONVERGED
        if ok.any():
            st.last = vecs[np.flatnonzero(ok)[-1]].copy()
        elif len(status):
            st.last = None            # lost: re-acquire with the closed form

    @staticmethod
    def _unpack(res):
        rel = getattr(res, "relative_residual", None)     # NaN where a solver gives none
        status = np.asarray(res.status, dtype=np.int8)
        return (np.asarray(res.poses, dtype=np.float64),
                np.asarray(res.pose_vectors, dtype=np.float64), status,
                np.asarray(res.residual, dtype=np.float64),
                np.full(status.shape, np.nan) if rel is None
                else np.asarray(rel, dtype=np.float64))

    def _call(self, solver, C, initial, quick):
        """``solver(C, initial)``; samples marked in ``quick`` (distorted, not sent) are solved
        without the solver's extra starts when it offers that (``explore_optional``)."""
        if quick is None or not getattr(solver, "explore_optional", False) or not quick.any():
            return self._unpack(solver(C, initial))
        if quick.all():
            return self._unpack(solver(C, initial, explore=False))
        keep = ~quick
        pick = (lambda m: initial) if isinstance(initial, str) else (lambda m: initial[m])
        a = self._unpack(solver(C[keep], pick(keep)))
        b = self._unpack(solver(C[quick], pick(quick), explore=False))
        out = []
        for x, y in zip(a, b):
            z = np.empty((C.shape[0],) + x.shape[1:], x.dtype)
            z[keep], z[quick] = x, y
            out.append(z)
        return tuple(out)

    def _solve(self, st: _SensorState, C, quick=None):
        n = C.shape[0]
        initial = st.cold_start if st.last is None else np.repeat(st.last[None], n, axis=0)
        out = self._call(st.solver, C, initial, quick)
        self._remember(st, out[1], out[2])
        return out

    def _solve_all(self, Cs, quick=None) -> list:
        """Solve every sensor's couplings ``Cs[k]`` (N, n_so, n_se_k); sensors of a group that
        are all tracking go through their shared solver in one call. ``quick[k]`` marks the
        samples to solve without extra starts (see :meth:`_call`)."""
        out = [None] * len(self.sensors)
        for group in self._groups:
            if len(group) > 1 and all(st.last is not None for st in group):
                n = Cs[group[0].index].shape[0]
                C = np.concatenate([Cs[st.index] for st in group])
                initial = np.repeat(np.stack([st.last for st in group]), n, axis=0)
                q = None if quick is None else np.concatenate([quick[st.index] for st in group])
                P, V, S, R, RR = self._call(group[0].solver, C, initial, q)
                k = len(group)                  # one view per sensor: (k, n, ...) blocks
                P, V = P.reshape(k, n, 4, 4), V.reshape(k, n, 6)
                S, R, RR = S.reshape(k, n), R.reshape(k, n), RR.reshape(k, n)
                # the usual case: every sensor's last sample converged (one test for all)
                tracked = n > 0 and not (S[:, -1] != _CONVERGED).any()
                lasts = V[:, -1].copy() if tracked else None
                for j, st in enumerate(group):
                    out[st.index] = (P[j], V[j], S[j], R[j], RR[j])
                    if tracked:
                        st.last = lasts[j]
                    else:
                        self._remember(st, V[j], S[j])
            else:
                for st in group:
                    out[st.index] = self._solve(st, Cs[st.index],
                                                None if quick is None else quick[st.index])
        return out

    @staticmethod
    def _correct(st: _SensorState, poses, vecs, status):
        if st.correction is None:
            return poses, vecs
        from ..correct import apply_linear_correction
        from ..geometry import vector_from_pose

        ok = status == _CONVERGED
        if not np.any(ok):
            return poses, vecs
        poses = poses.copy()
        poses[ok, :3, 3] = apply_linear_correction(st.correction, poses[ok, :3, 3])
        return poses, vector_from_pose(poses)

    @staticmethod
    def _filter(st: _SensorState, times, poses, vecs, status):
        f = st.filter
        if f is None:
            return poses, vecs
        from ._filter import kalman_filter_poses, new_filter_state

        if st.filter_state is None:
            st.filter_state = new_filter_state()
        ok = status == _CONVERGED
        fp, fv, _ = kalman_filter_poses(
            vecs, times, ok, process_noise=f.process_noise,
            measurement_noise=f.measurement_noise,
            rotation_process_noise=f.rotation_process_noise,
            rotation_measurement_noise=f.rotation_measurement_noise, max_gap=f.max_gap,
            state=st.filter_state)
        return fp, fv

    def step(self):
        """Read and process one backend chunk; None at the end of the data.

        Returns the chunk's :class:`TrackStep` (one sensor) or a tuple of them, one per sensor
        (several sensors)."""
        chunk = self.backend.read()
        if chunk is None:
            return None
        if self._discontinuous and len(chunk):
            restart = self.backend.pop_restart()
            if restart is not None:       # lost frames or a restarted device: a new window
                self.demod.reset(restart)
                self.demod_restarts += 1
        d = self.demod.process(chunk)
        t_ready = time.perf_counter()
        n = len(d)
        steps = []
        if n == 0:
            e = np.empty(0)
            for _ in self.sensors:
                steps.append(TrackStep(d.times, d.couplings, np.empty((0, 4, 4)),
                                       np.empty((0, 6)), np.empty(0, np.int8), e, e,
                                       np.empty(0, bool), t_ready,
                                       distortion_level=np.empty(0, np.uint8)))
            now = time.monotonic()
            for st, step in zip(self.sensors, steps):   # the watchdog runs without samples too
                self._watch(st, step, step.distorted, now, None)
            return steps[0] if len(steps) == 1 else tuple(steps)
        send_status = (self._n_out + n) // self.status_every > self._n_out // self.status_every
        stamps = (self.backend.t0_epoch + d.times if self._epoch_times is None
                  else self._epoch_times(d.times))
        latency = np.empty(n)
        parts = [d.couplings if st.columns is None else d.couplings[:, :, st.index_of_columns]
                 for st in self.sensors]
        quad = d.couplings
        if self.bands is None:
            Cs = [c.real for c in parts]
        else:                                   # the couplings to solve from the bands
            Cs = []
            for st in self.sensors:
                b = d.bands if st.columns is None else d.bands[..., st.index_of_columns]
                C, st.band_state = self.bands(b, st.band_state)
                Cs.append(C)
            quad = d.bands[:, self.bands.quadrature_band]
        # quadrature ratio ||Im C|| / ||C|| per sensor over its columns, (k, n) in one pass
        ratios = distortion_ratio(quad, self._column_mask)
        flags = ratios > self.distortion_threshold
        # distorted samples are not sent: their solve skips the extra starts (bounded cost)
        quick = None if self.send_distorted else flags
        if self.serial_small_batches and n * len(self.sensors) < 256:
            with serial_threads():
                solved = self._solve_all(Cs, quick)
        else:
            solved = self._solve_all(Cs, quick)
        witness_m = None
        if self._witness:                       # the witnesses' error at their known poses
            errs = [np.where(solved[k][2] == _CONVERGED,
                             np.linalg.norm(solved[k][0][:, :3, 3] - p, axis=1), np.inf)
                    for k, p in self._witness]
            witness_m = np.max(errs, axis=0)
            if self._estimator is not None and n and np.max(witness_m) > WITNESS_REFIT_M:
                solved = self._witness_refit(Cs, solved)
        oks, valids = [], []
        for st, couplings, (poses, vecs, status, resid, rel), ratio, flag in zip(
                self.sensors, parts, solved, ratios, flags):
            poses, vecs = self._correct(st, poses, vecs, status)
            if st.filter is not None:
                poses, vecs = self._filter(st, d.times, poses, vecs, status)
                # a filter driven beyond its range gives no pose: never a converged NaN
                bad = ~np.isfinite(vecs).all(axis=1) & (status == _CONVERGED)
                if bad.any():
                    status = status.copy()
                    status[bad] = _OUT_OF_VOLUME
            tool = None
            if self.registration is not None or st.tip is not None:
                from ..geometry import vector_from_pose

                if self.registration is not None:      # into the image frame
                    poses = self.registration @ poses
                if st.tip is not None:                 # the tool tip, streamed beside it
                    tool, poses = poses, poses @ st.tip
                vecs = vector_from_pose(poses)
            ok = status == _CONVERGED
            oks.append(ok)
            # valid = sent: converged, and not distorted unless distorted samples are sent
            valids.append(ok & ~flag if not self.send_distorted and flag.any() else ok)
            # against the quadrature threshold and the solver's validity threshold (as the
            # stream's metadata) and the witnesses' position error where there are witnesses
            level = distortion_level(ratio, rel, self.distortion_threshold,
                                     MAX_RELATIVE_RESIDUAL, witness_m=witness_m)
            st.add_levels(level)
            steps.append(TrackStep(d.times, couplings, poses, vecs, status, resid, ratio, flag,
                                   t_ready, rel, tool, level, stamps, latency))
        if self.igtl is not None:
            self._send(steps, valids, stamps, t_ready)
            if send_status:
                for st, step in zip(self.sensors, steps):
                    self._send_status(self._device(st), int(step.status[-1]),
                                      bool(step.distorted[-1]), float(step.distortion[-1]),
                                      stamps[-1])
        if self._clocked:                      # sample time -> sent, per sample
            np.subtract(time.time(), stamps, out=latency)
            self._e2e.append(latency)
        else:
            latency.fill(np.nan)
        now = time.monotonic()
        for st, step, valid in zip(self.sensors, steps, valids):
            self._watch(st, step, valid, now, stamps[-1])
        for st, step, ok in zip(self.sensors, steps, oks):   # after every sensor's poses are sent
            self._account(st, step, ok)
        if self._truth_known:              # compared with the truth in batches (cheaper)
            self._truth_pending.append((d.times, [(s.poses[:, :3, 3], ok)
                                                  for s, ok in zip(steps, oks)]))
            self._n_truth_pending += n
            if self._n_truth_pending >= 1500:
                self._flush_truth()
        self._latency.extend([time.perf_counter() - t_ready] * n)
        self._n_out += n
        return steps[0] if len(steps) == 1 else tuple(steps)

    def _witness_refit(self, Cs, solved) -> list:
        """The environment terms re-estimated from the witnesses' couplings of this chunk
        (their mean: the witnesses are still) and the converged poses of every other sensor
        of the witnesses' model refined under them (:func:`openemt.solve.refine_poses`)."""
        from ..geometry import pose_from_vector
        from ..solve import refine_poses

        est = self._estimator
        env = est.update(np.stack([Cs[k].mean(axis=0) for k, _ in self._witness]))
        skip = {k for k, _ in self._witness}
        out = list(solved)
        for st in self.sensors:
            k = st.index
            if k in skip or st.setup.model is not est.model:
                continue
            poses, vecs, status, resid, rel = solved[k]
            ok = status == _CONVERGED
            if not ok.any():
                continue
            poses, vecs = poses.copy(), vecs.copy()
            resid, rel = np.array(resid, dtype=np.float64), np.array(rel, dtype=np.float64)
            vecs[ok], resid[ok] = refine_poses(env, Cs[k][ok], vecs[ok])
            poses[ok] = pose_from_vector(vecs[ok])
            C = Cs[k][ok]
            rel[ok] = np.linalg.norm(C - env.coupling(poses[ok]), axis=(1, 2)) / \
                np.linalg.norm(C, axis=(1, 2))
            out[k] = (poses, vecs, status, resid, rel)
        return out

    def _device(self, st: _SensorState) -> str:
        return st.setup.device_name or (self.igtl.device_name if self.igtl is not None
                                        else st.setup.name)

    @property
    def devices(self) -> list:
        """The device of every stream, in the order they are sent: the sensors', the tips',
        then the relative streams'."""
        return [self._device(st) for st in self.sensors] + [d for _, d, _, _ in self._extra]

    def _streams(self, steps, picks):
        """The streams of one chunk: per sensor (its own pose), per tool tip, then per sensor
        (and tip) relative to the reference, ``(device, poses, pick, distorted, relative
        residual, distortion)``; a relative stream's pose is ``inv(reference) @ sensor`` where
        both are picked (elsewhere the sensor's own, never sent), flagged distorted where
        either is, with the larger relative residual and quadrature ratio of the two."""
        def own(step):
            return step.poses if step.tool_poses is None else step.tool_poses

        out = [(self._device(st), own(step), pick, step.distorted, step.relative_residual,
                step.distortion, step.distortion_level)
               for st, step, pick in zip(self.sensors, steps, picks)]
        if not self._extra:
            return out
        if self.reference is not None:
            r = self.reference.index
            ref, rpick = steps[r], picks[r]
        for st, device, tip, relative in self._extra:
            step = steps[st.index]
            poses = step.poses if tip else own(step)
            if not relative:
                out.append((device, poses, picks[st.index], step.distorted,
                            step.relative_residual, step.distortion, step.distortion_level))
                continue
            from ..geometry import invert

            pick = picks[st.index] & rpick
            poses = poses.copy()
            if pick.any():
                poses[pick] = invert(own(ref)[pick]) @ poses[pick]
            out.append((device, poses, pick, step.distorted | ref.distorted,
                        np.fmax(step.relative_residual, ref.relative_residual),
                        np.maximum(step.distortion, ref.distortion),
                        np.maximum(step.distortion_level, ref.distortion_level)))
        return out

    def _send(self, steps, valids, stamps, t_ready) -> None:
        """Send the chunk's valid poses of every stream: one TRANSFORM per stream and sample
        (with metadata), or one TDATA per sample."""
        n = len(stamps)
        picks = valids
        if self.igtl_every != 1:
            every = (self._n_out + np.arange(n)) % self.igtl_every == 0
            picks = [v & every for v in valids]
        if not getattr(self.igtl, "connected", True):   # cheap exit: count what nobody got
            if self.tdata:
                count = int(np.logical_or.reduce(picks).sum())
            else:
                rp = picks[self.reference.index] if self.reference is not None else None
                count = sum(int(p.sum()) for p in picks) + sum(
                    int((picks[st.index] & rp).sum() if rel else picks[st.index].sum())
                    for st, _, _, rel in self._extra)
            self.igtl.send_packed(b"", count)
            return
        streams = self._streams(steps, picks)
        if self.tdata:
            from ._igtl_wire import MM_SCALE
            from ._tdata import pack_tdata

            M = np.stack([s[1] for s in streams], axis=1)          # (n, streams, 4, 4)
            valid = np.stack([s[2] for s in streams], axis=1)
            # unsent slots: finite; m -> mm (Slicer)
            M = np.where(valid[:, :, None, None], M, np.eye(4)) * MM_SCALE
            data, count = pack_tdata(M, valid, [s[0] for s in streams], stamps,
                                     self.tdata_device)
            if count:
                self.igtl.send_packed(data, count, t_ready)
            return
        # every stream's poses in one call (one packing pass, one write per client): the
        # samples of the first stream, then those of the next, ...
        if all(s[2].all() for s in streams):
            sel = [slice(None)] * len(streams)
        else:
            sel = [s[2] for s in streams]

        def joined(j):                          # field j of every stream's picked samples
            if len(streams) == 1:
                return streams[0][j][sel[0]]
            return np.concatenate([s[j][k] for s, k in zip(streams, sel)])

        poses = joined(1)
        if not len(poses):
            return
        devices = streams[0][0] if len(streams) == 1 else [
            d for s, k in zip(streams, sel)
            for d in [s[0]] * (n if isinstance(k, slice) else int(k.sum()))]
        kw = {}
        if self.igtl_metadata:
            kw["metadata"] = transform_metadata(
                joined(3), joined(4), joined(5), distortion_threshold=self.distortion_threshold,
                level=joined(6))
        self.igtl.send_poses(poses, stamps[sel[0]] if len(sel) == 1 else
                             np.concatenate([stamps[k] for k in sel]), t_ready=t_ready,
                             device_name=devices, **kw)

    def _watch(self, st: _SensorState, step: TrackStep, valid, now: float, stamp) -> None:
        """Update the stream state of ``st`` after a chunk (see the class docstring) and
        report a change."""
        if st.last_valid is None:               # the watchdog starts with the first chunk
            st.last_valid = now
        n = len(step)
        new = st.state
        any_valid = bool(n) and bool(valid.any())
        if any_valid:
            st.last_valid = now
        if n:
            ok = step.status[-1] == _CONVERGED
            new = ("DISTORTED" if step.distorted[-1] else "OK") if ok else "LOST"
            if st.state == "STALE" and not any_valid:
                new = "STALE"                   # stale until a valid pose arrives
        if new != "STALE" and not any_valid and now - st.last_valid >= self.stale_after:
            new = "STALE"
        if new == st.state:
            return
        old, st.state = st.state, new
        device = self._device(st)
        if new == "OK":
            event = "tracking" if old is None else "recovered"
            detail = "" if old is None else f" after {now - st.bad_since:.2f} s"
            st.bad_since = None
        else:
            event = new.lower()
            if st.bad_since is None:
                st.bad_since = now
            if new == "LOST":
                detail = f": status {_status_name(step.status[-1])}"
            elif new == "DISTORTED":
                detail = (f": quadrature {float(step.distortion[-1]):.2e} > "
                          f"{self.distortion_threshold:.2e}")
            else:
                detail = f": no valid pose for {now - st.last_valid:.2f} s"
        st.events[event] += 1
        text = f"{event.upper()} {device}{detail}"
        self.events.append({"sensor": st.setup.name, "event": event, "text": text,
                            "n_samples": self._n_out + n})
        if self.igtl is not None:
            import pyigtl

            # kept as the device's current state: a viewer that connects later gets it first
            self.igtl.send_message(pyigtl.StringMessage(
                text, timestamp=time.time() if stamp is None else float(stamp),
                device_name=state_device_name(device)), retain=state_device_name(device))

    def _send_status(self, device, code, distorted, ratio, timestamp):
        import pyigtl

        self.igtl.send_message(pyigtl.StringMessage(
            f"{_status_name(code)} distorted={int(distorted)} quadrature={ratio:.2e}", timestamp=timestamp,
            device_name=status_device_name(device)))

    def _account(self, st: _SensorState, step: TrackStep, ok):
        n_ok = int(np.count_nonzero(ok))
        if n_ok == len(step):                  # the usual case, without a bincount
            st.status_counts[_CONVERGED] += n_ok
        else:
            st.status_counts += np.bincount(step.status.astype(np.int64),
                                            minlength=len(Status))
        n_dist = int(np.count_nonzero(step.distorted))
        st.n_distorted += n_dist
        if n_dist and not self.send_distorted:
            st.n_not_sent += int(np.count_nonzero(ok & step.distorted))
        if self.log is not None:
            self.log.append(step, st.index)

    def _flush_truth(self):
        """Compare every sensor's converged positions since the last call with the backend's
        truth: one truth evaluation for all sensors (a simulator computes every sensor's pose
        at once), every 1500 samples rather than on every chunk."""
        pending, self._truth_pending, self._n_truth_pending = self._truth_pending, [], 0
        if not pending or not self._truth_known:
            return
        truth = self.backend.truth_poses(np.concatenate([t for t, _ in pending]))
        if truth is None:
            self._truth_known = False
            return
        truth = np.asarray(truth)
        for st in self.sensors:
            ok = np.concatenate([chunk[st.index][1] for _, chunk in pending])
            if not ok.any():
                continue
            xyz = np.concatenate([chunk[st.index][0] for _, chunk in pending])[ok]
            T = (truth[:, st.index] if truth.ndim == 4 else truth)[ok]   # (N, n_sensors, 4, 4)
            if self.registration is not None:
                T = self.registration @ T
            if st.tip is not None:
                T = T @ st.tip
            err = np.linalg.norm(xyz - T[:, :3, 3], axis=1)
            st.err_n += err.size
            st.err_ss += float(np.sum(err ** 2))
            st.err_max = max(st.err_max, float(err.max()))

    def run(self, duration: float | None = None, *, max_steps: int | None = None,
            stop=None, monitor=None) -> TrackSummary:
        """Process chunks until the data end, ``duration`` seconds of signal, ``max_steps``
        chunks, ``stop()`` returning True, or Ctrl-C (a clean stop, not an error; the
        exception is kept in :attr:`interrupted`). ``monitor(pipeline)`` is called after
        every chunk (e.g. a status line, see :meth:`progress`)."""
        t_wall = time.perf_counter()
        steps = 0
        fs_out = self.demod.output_rate
        self.interrupted = None
        try:
            while True:
                if duration is not None and self._n_out >= duration * fs_out:
                    break
                if max_steps is not None and steps >= max_steps:
                    break
                if stop is not None and stop():
                    break
                if self.step() is None:
                    break
                steps += 1
                if monitor is not None:
                    monitor(self)
        except KeyboardInterrupt as exc:
            self.interrupted = exc
        return self.summary(time.perf_counter() - t_wall)

    def progress(self, recent: int = 1500) -> dict:
        """A cheap snapshot for a status line: samples so far, status counts (all sensors, by
        lower-case name), distorted and not-sent samples, and the median latency (ms) of the
        last ``recent`` samples."""
        counts = sum(st.status_counts for st in self.sensors)
        lat = self._latency
        k = min(len(lat), int(recent))
        p50 = (1e3 * float(np.median(np.fromiter(itertools.islice(reversed(lat), k), float)))
               if k else None)
        return {"n_samples": self._n_out, "signal_seconds": self._n_out / self.demod.output_rate,
                "status_counts": status_count_names(counts),
                "distorted": sum(st.n_distorted for st in self.sensors),
                "not_sent_distorted": sum(st.n_not_sent for st in self.sensors),
                "latency_ms_p50": p50, "link": self._link_stats()}

    def _link_stats(self):
        f = getattr(self.backend, "link_stats", None)
        return None if f is None else f()

    def acquisition(self) -> dict:
        """Time and link figures (docs/live.md#time): the end-to-end latency (acquisition time
        of a sample to its send) percentiles in ms (None when the source is not paced in real
        time), the demodulator restarts at gaps, and a framed link's counters and clock fit
        (``link``, None for other sources)."""
        e2e = np.concatenate(self._e2e) * 1e3 if self._e2e else np.empty(0)
        return {"latency_ms_p50": float(np.percentile(e2e, 50)) if e2e.size else None,
                "latency_ms_p99": float(np.percentile(e2e, 99)) if e2e.size else None,
                "latency_ms_max": float(e2e.max()) if e2e.size else None,
                "demodulator_restarts": self.demod_restarts, "link": self._link_stats()}

    def _sensor_summary(self, st: _SensorState) -> dict:
        counts = status_count_names(st.status_counts)
        self._flush_truth()
        n = self._n_out
        out = {"status_counts": counts,
               "distorted_fraction": (st.n_distorted / n) if n else 0.0,
               "distortion_level": _level_summary(st.level_counts),
               "not_sent_distorted": st.n_not_sent,
               "device_name": self._device(st) if self.igtl is not None else None,
               "truth": None, "filter": None, "state": st.state, "events": dict(st.events)}
        if st.err_n:
            out["truth"] = {"position_error_mm_rms": 1e3 * float(np.sqrt(st.err_ss / st.err_n)),
                            "position_error_mm_max": 1e3 * st.err_max}
        if st.filter is not None:
            out["filter"] = {**dataclasses.asdict(st.filter),      # a FilterSpec's fields
                             "restarts_after_loss": 0 if st.filter_state is None
                             else filter_restarts(st.filter_state)}
        return out

    def summary(self, wall_seconds: float = float("nan")) -> TrackSummary:
        """Summary of everything processed so far. With several sensors ``status_counts`` and
        ``distorted_fraction`` add up all sensors, ``truth`` is the worst sensor's, and
        ``extra["sensors"]`` holds each sensor's own."""
        per = {st.setup.name: self._sensor_summary(st) for st in self.sensors}
        lat = np.asarray(self._latency) * 1e3
        counts: dict = {}
        for v in per.values():
            for k, c in v["status_counts"].items():
                counts[k] = counts.get(k, 0) + c
        truths = [v["truth"] for v in per.values() if v["truth"]]
        truth = max(truths, key=lambda t: t["position_error_mm_rms"]) if truths else None
        igtl = None
        if self.igtl is not None:
            igtl = dict(self.igtl.stats(), port=self.igtl.port,
                        device_name=self.igtl.device_name)
            sl = self.igtl.latencies() * 1e3
            if sl.size:
                igtl["send_latency_ms_p50"] = float(np.percentile(sl, 50))
                igtl["send_latency_ms_p99"] = float(np.percentile(sl, 99))
        n = self._n_out
        k = len(self.sensors)
        extra = {"not_sent_distorted": sum(st.n_not_sent for st in self.sensors),
                 "send_distorted": self.send_distorted,
                 "events": {e: sum(st.events[e] for st in self.sensors) for e in STREAM_EVENTS},
                 "stale_after": self.stale_after,
                 "reference": None if self.reference is None else self.reference.setup.name,
                 "relative_devices": [d for _, d in self._relative] or None,
                 "tdata": self.tdata, "metadata": self.igtl_metadata and not self.tdata,
                 "distortion_level": _level_summary(sum(st.level_counts
                                                        for st in self.sensors)),
                 "acquisition": self.acquisition()}
        if self.bands is not None:                 # what the carrier bands gave the solver
            extra["bands"] = {"method": self.bands.method,
                              "frequencies_hz": self.bands.frequencies.tolist(),
                              **({"time_constant_s": self.bands.time_constant}
                                 if self.bands.method == "fuse" else {})}
        if k > 1:
            extra["sensors"] = per
        elif per[self.sensors[0].setup.name]["filter"] is not None:
            extra["filter"] = per[self.sensors[0].setup.name]["filter"]
        return TrackSummary(
            n_samples=n, signal_seconds=n / self.demod.output_rate, wall_seconds=wall_seconds,
            status_counts=counts,
            distorted_fraction=(sum(st.n_distorted for st in self.sensors) / (n * k))
            if n else 0.0,
            latency_ms_p50=float(np.percentile(lat, 50)) if lat.size else None,
            latency_ms_p99=float(np.percentile(lat, 99)) if lat.size else None,
            igtl=igtl, truth=truth, extra=extra)
