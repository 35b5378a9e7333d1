"""A tracking session, from a tracker description to running parts, assembled in one place.

:class:`TrackingSession` is the library workflow of ``openemt track``: the tracker (a file, a
:class:`~openemt.live.TrackerSpec`, or the default simulated one), the options
(:class:`TrackOptions`, one field per command-line option) in; acquisition (backend, raw
recording, stall watch), demodulation, solve, filter, registration and the outputs
(OpenIGTLink server, log) assembled in :meth:`TrackingSession.__enter__`; a
:class:`TrackResult` out. :func:`tracker_backend` and :func:`tracker_sensors` are its parts
(``collect`` and the benches use them too).
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .._constants import SIMULATED_MAINS_AMPLITUDES_V
from .._errors import InputError
from .._options import option as _opt
from .._result import Result
from ..solve import LIVE_BAND_METHODS
from ._tracker_file import TrackerSpec

__all__ = ["StopSignals", "TrackOptions", "TrackResult", "TrackingSession", "tracker_backend",
           "tracker_sensors"]


@dataclass(frozen=True)
class TrackOptions:
    """Every option of a tracking session, with its default (``openemt track --help`` is
    built from these fields). ``None`` means: the tracker file's setting, else the default
    named in the help."""

    tracker: Path | None = _opt(None, "tracker description file (TOML, "
                                "docs/live.md#tracker-file): ADC, channels, carriers, sensors, "
                                "calibrations, device names, filter, registration (default: "
                                "the simulated one-sensor tracker)")
    source: str | None = _opt(None, "sim: simulated device; replay: a raw HDF5 file; sound: a "
                              "sound card (needs --tracker and the optional package "
                              "sounddevice); serial:PORT[@BAUD] or tcp://HOST:PORT: an ADC "
                              "sending openemt frames (docs/live.md#serial-and-network-"
                              "acquisition; needs the tracker's adc layout, default: the "
                              "simulated tracker's) (default: the tracker file's [adc] "
                              "source, else sim)",
                              metavar="SOURCE")
    file: Path | None = _opt(None, "raw HDF5 recording (with --source replay)",
                             positional=True, optional=True)
    device: str | None = _opt(None, "(sound) audio input device: index or name (openemt "
                              "devices lists them; default: the system default input)")
    preset: str | None = _opt(None, "(without --tracker) simulated tracker (openemt.simulate "
                              "preset) whose dipole model drives the simulation and the solver "
                              "(default concentric)")
    calibration: Path | None = _opt(None, "(without --tracker) calibration file (JSON or ILEMT "
                                    ".mat) for the solver's model and linear correction "
                                    "(default: the preset's true model); a finite-coil board "
                                    "calibration tracks its 5-DOF sensor on the board's "
                                    "carriers (docs/planar.md)")
    registration: Path | None = _opt(None, "registration file from 'openemt register -o' "
                                     "(image from tracker): stream, log and score every "
                                     "sensor and tip in the image frame, devices "
                                     "<name>ToImage (default: the tracker file's "
                                     "[navigation] registration, else none)",
                                     metavar="FILE")
    tip: Path | None = _opt(None, "pivot calibration file from 'openemt pivot -o': stream the "
                            "tool tip too, device <name>TipTo<frame> (one-sensor trackers; "
                            "default: the tracker file's per-sensor tip, else none)",
                            metavar="FILE")
    filter: str | None = _opt(None, "tracking filter per sensor: constant-velocity Kalman "
                              "filter, reset on loss (default: the tracker file's [filter], "
                              "else none)", choices=("none", "kalman"))
    process_noise: float | None = _opt(None, "filter: white-acceleration density, "
                                       "m/s^2/sqrt(Hz) (default 0.01)")
    measurement_noise: float | None = _opt(None, "filter: position noise per axis, m "
                                           "(default 2e-6)")
    rotation_process_noise: float | None = _opt(None, "filter: white angular-acceleration "
                                                "density, rad/s^2/sqrt(Hz) (default 0.1)")
    rotation_measurement_noise: float | None = _opt(None, "filter: orientation noise per "
                                                    "axis, rad (default 2e-5)")
    duration: float | None = _opt(None, "seconds of signal to process (default: until Ctrl-C "
                                  "/ end of file)")
    igtl_port: int = _opt(18944, "OpenIGTLink server port (default 18944, Slicer's default)")
    igtl: bool = _opt(True, "do not start the OpenIGTLink server", flag="--igtl")
    host: str = _opt("127.0.0.1", "interface to serve on (0.0.0.0 for other machines)")
    device_name: str | None = _opt(None, "(without --tracker) OpenIGTLink device name = "
                                   "transform node name in Slicer (default SensorToTracker)")
    header_version: str | None = _opt(None, "OpenIGTLink header version of the messages: "
                                      "'auto' (version 1 until a client sends version 2, as "
                                      "PLUS does), 1 or 2 (default: the tracker file's [igtl] "
                                      "header_version, else the server's)",
                                      choices=("auto", "1", "2"))
    rate: float | None = _opt(None, "most OpenIGTLink updates per second and client, Hz "
                              "(default: the tracker file's [igtl] rate, else every pose)",
                              metavar="HZ")
    fast: bool = _opt(False, "process as fast as possible instead of at the sample rate")
    log: Path | None = _opt(None, "write per-sample poses, status and distortion to .h5 or "
                            ".csv, appended every second while the session runs")
    save_raw: Path | None = _opt(None, "(sim) also write the raw samples to an HDF5 file for "
                                 "replay, appended every second while the session runs")
    stall_warn: float = _opt(2.0, "warn after this many seconds without samples from the "
                             "source (default 2)")
    stall_timeout: float = _opt(10.0, "stop with an error (exit 2) after this many seconds "
                                "without samples from the source, also before the first one "
                                "(default 10)")
    stale_after: float | None = _opt(None, "watchdog: report a sensor STALE on its <From>State "
                                     "message after this many seconds without a valid pose "
                                     "(default: the tracker file's [igtl] stale_after, else "
                                     "0.5)")
    tdata: bool = _opt(False, "send all streams of one sample in one OpenIGTLink TDATA "
                       "(tracking data) message on device 'openemt' instead of one TRANSFORM "
                       "per stream (default: the tracker file's [igtl] tdata, else off)")
    metadata: bool = _opt(True, "send version-1 TRANSFORMs without the per-pose metadata "
                          "(for clients of OpenIGTLink version 1, and cheaper for a viewer on "
                          "the same small machine; default: the tracker file's [igtl] "
                          "metadata, else on)")
    send_distorted: bool = _opt(False, "also send converged poses flagged as distorted "
                                "(default: distorted samples are logged and flagged, not sent)")
    seed: int | None = _opt(None, "simulation seed (default: the tracker file's "
                            "[simulation], else 0)")
    noise: float | None = _opt(None, "(sim) sensor noise in V rms (default: the tracker "
                               "file's [simulation], else 1.5e-5)")
    eddy: float | None = _opt(None, "(sim) conductive-object strength; >0 shows as "
                              "quadrature/distortion (default: the tracker file's "
                              "[simulation], else 0)")
    window: str | None = _opt(None, "demodulation window (default: the tracker file's, else "
                              "hann)", choices=("hann", "rect"))
    distortion_threshold: float | None = _opt(None, "quadrature ratio above which a sample is "
                                              "flagged distorted and not sent (default: the "
                                              "tracker file's, else 1e-3)")
    bands: str | None = _opt(None, "couplings to solve from the carrier bands: fast, slow, "
                             "fuse (the fast band corrected from the slow one through a "
                             "low-pass), eddy-free, auto (fuse where the tracker has bands; "
                             "default: the tracker file's [solve] bands, else auto)",
                             choices=LIVE_BAND_METHODS)
    quiet: bool = _opt(False, "", cli=False)

    def __post_init__(self):
        for name in ("tracker", "file", "calibration", "registration", "tip", "log", "save_raw"):
            v = getattr(self, name)
            if v is not None and not isinstance(v, Path):
                object.__setattr__(self, name, Path(v))        # a str or os.PathLike

    def check(self) -> None:
        """Refuse values no session can use (one line naming the option)."""
        from ._acquire import parse_source

        kind = "sim" if self.source is None else parse_source(self.source)[0]
        if self.duration is not None and not 0 < self.duration < math.inf:
            raise InputError(f"expected a positive, finite --duration in seconds (leave it out "
                             f"to run until Ctrl-C), got {self.duration}")
        for name in ("stall_warn", "stall_timeout", "stale_after"):
            v = getattr(self, name)
            if v is not None and not 0 < v < math.inf:
                raise InputError(f"expected a positive, finite --{name.replace('_', '-')} in "
                                 f"seconds, got {v}")
        for name in ("distortion_threshold", "noise", "eddy"):
            v = getattr(self, name)
            if v is not None and not 0 <= v < math.inf:
                raise InputError(f"expected a finite --{name.replace('_', '-')} >= 0, got {v}")
        if not 0 <= self.igtl_port <= 65535:
            raise InputError(f"expected --igtl-port in 0..65535, got {self.igtl_port}")
        if self.seed is not None and not 0 <= self.seed < 2**63:
            raise InputError(f"expected --seed in 0..2**63-1, got {self.seed}")
        if self.rate is not None:
            from ._tracker_file import check_rate

            check_rate(self.rate, "--rate")
        if self.tracker is not None:
            for opt in ("preset", "calibration", "device_name"):
                if getattr(self, opt) is not None:
                    raise InputError(f"expected no --{opt.replace('_', '-')} with --tracker "
                                     f"(the tracker file names the model, calibrations and "
                                     f"devices), got {getattr(self, opt)}")
        elif kind == "sound":
            raise InputError("expected --tracker FILE with --source sound (which channels are "
                             "references and sensor coils), got none")
        if kind == "replay":
            if self.file is None:
                raise InputError("expected a raw HDF5 FILE with --source replay, got none")
        elif self.file is not None:
            raise InputError(f"expected FILE only with --source replay, got {str(self.file)!r}")
        if self.save_raw is not None and kind != "sim":
            raise InputError(f"expected --save-raw only with --source sim, got --source "
                             f"{self.source}")
        if self.save_raw is not None and self.save_raw.suffix.lower() not in (".h5", ".hdf5"):
            raise InputError(f"expected --save-raw ending in .h5 or .hdf5, got "
                             f"{str(self.save_raw)!r}")
        if self.device is not None and kind != "sound":
            raise InputError(f"expected --device only with --source sound, got --source "
                             f"{self.source}")
        if self.log is not None and self.log.suffix.lower() not in (".h5", ".hdf5", ".csv"):
            raise InputError(f"expected --log ending in .h5, .hdf5 or .csv, got "
                             f"{str(self.log)!r}")


@dataclass(frozen=True)
class TrackResult(Result):
    """What a session did: the pipeline's :class:`~openemt.live.TrackSummary` and the
    session's own keys (source, tracker, streams, outputs, stalls, how it stopped); its
    ``to_dict()`` is ``openemt track --json``."""

    summary: object
    session: dict
    stopped_signal: int | None = None
    _not_in_dict = ("stopped_signal",)

    def _items(self) -> dict:
        return {**self.summary.to_dict(), **self.session}

    @property
    def exit_code(self) -> int:
        """0, or 128 + the signal that stopped the session."""
        return 0 if self.stopped_signal is None else 128 + int(self.stopped_signal)

    def human(self) -> list:
        """The summary's lines for stderr."""
        s, out = self.summary, self.to_dict()
        lines = [f"tracked {s.n_samples} samples ({s.signal_seconds:.2f} s of signal) of "
                 f"{len(out['sensors_tracked'])} sensor(s) in {s.wall_seconds:.2f} s; status "
                 f"{s.status_counts}; distorted {100 * s.distorted_fraction:.1f} %"
                 f" ({out['not_sent_distorted']} converged but not sent)"]
        if s.truth:
            lines.append(f"position error vs truth: rms {s.truth['position_error_mm_rms']:.4f}"
                         f" mm, max {s.truth['position_error_mm_max']:.4f} mm")
        ev = out["events"]
        if ev["lost"] or ev["distorted"] or ev["stale"]:
            lines.append(f"stream states: lost {ev['lost']}, distorted {ev['distorted']}, "
                         f"stale {ev['stale']}, recovered {ev['recovered']} time(s) (sent on "
                         f"<From>State)")
        if s.latency_ms_p50 is not None:
            lines.append(f"latency coupling -> send: p50 {s.latency_ms_p50:.3f} ms, p99 "
                         f"{s.latency_ms_p99:.3f} ms")
        acq = out.get("acquisition") or {}
        if acq.get("latency_ms_p50") is not None:
            lines.append(f"latency sample time -> send: p50 {acq['latency_ms_p50']:.3f} ms, "
                         f"p99 {acq['latency_ms_p99']:.3f} ms")
        k = out.get("link")
        if k is not None:
            drift = ("" if k["drift_ppm"] is None
                     else f"; ADC clock {k['drift_ppm']:+.1f} ppm against the host")
            lines.append(f"link: {k['frames']} frames, {k['crc_errors']} bad CRC, "
                         f"{k['bytes_skipped']} bytes skipped, {k['gaps']} gap(s) "
                         f"({k['samples_lost']} samples lost, not bridged), {k['restarts']} "
                         f"restart(s), {k['reconnects']} reconnection(s){drift}")
        if s.igtl:
            g = s.igtl
            lines.append(f"OpenIGTLink: {g['sent']} sent, {g['clients_max']} client(s) at "
                         f"most, {g['messages_skipped']} skipped for slow clients, "
                         f"{g['clients_dropped']} client(s) dropped")
        if self.stopped_signal is not None:
            lines.append(f"stopped by {out['stopped_by']} after {s.n_samples} samples"
                         + ("; outputs written" if s.n_samples else
                            "; no sample yet, existing outputs left unchanged"))
        return lines


def describe_streams(streams, tdata: bool = False) -> str:
    """One line saying what a session streams: every device, what it is and its frame."""
    what = {"tool": "{s}", "tip": "tip of {s}", "relative": "{s}",
            "tip-relative": "tip of {s}"}
    parts = [f"{st.device!r} ({what[st.kind].format(s=st.sensor)} in {st.frame}, "
             f"{st.units})" for st in streams]
    kind = "TDATA 'openemt' with tools" if tdata else "TRANSFORM"
    return f"{kind} " + ", ".join(parts)


class StopSignals:
    """SIGINT and SIGTERM become a stop request while armed (in the main thread; elsewhere,
    or when not ``enabled``, arming does nothing): :attr:`signal` is the number of the
    signal that asked to stop, None before one. A context manager (armed inside)."""

    def __init__(self, enabled: bool = True):
        self.enabled = bool(enabled)
        self.signal = None
        self._previous: dict = {}        # signal -> the handler it had before

    def _on_signal(self, signum, frame):
        self.signal = signum

    def arm(self) -> None:
        import signal
        import threading

        if (not self.enabled or self._previous
                or threading.current_thread() is not threading.main_thread()):
            return
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._previous[sig] = signal.signal(sig, self._on_signal)

    def disarm(self) -> None:
        import signal

        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous = {}

    def __enter__(self):
        self.arm()
        return self

    def __exit__(self, *exc):
        self.disarm()


class _Console(StopSignals):
    """The session's side of the terminal: SIGTERM/Ctrl-C become a stop request once tracking
    runs (the chunk in hand is finished and the outputs are closed), and a status line on
    stderr (carriage-return updated every second on a terminal; a plain line every 5 s
    otherwise; none when quiet)."""

    def __init__(self, quiet: bool):
        super().__init__()
        self.quiet = bool(quiet)
        self.tty = sys.stderr.isatty()
        self.period = 1.0 if self.tty else 5.0
        self._t0 = self._last = None
        self._n0 = 0
        self._width = 0

    def stop(self) -> bool:
        return self.signal is not None

    def say(self, text: str) -> None:
        if self.quiet:
            return
        self.end_line()
        print(text, file=sys.stderr, flush=True)

    def __call__(self, pipe) -> None:
        import time

        if not self._previous:
            self.arm()                   # the first chunk is done: start-up is over
        if self.quiet:
            return
        now = time.monotonic()
        if self._t0 is None:
            self._t0 = self._last = now
            return
        if now - self._last < self.period:
            return
        p = pipe.progress()
        rate = (p["n_samples"] - self._n0) / (now - self._last)
        self._last, self._n0 = now, p["n_samples"]
        counts = ", ".join(f"{k} {v}" for k, v in p["status_counts"].items() if v) or "none"
        lat = "" if p["latency_ms_p50"] is None else f", latency {p['latency_ms_p50']:.2f} ms"
        line = (f"tracking {p['signal_seconds']:.1f} s: {rate:.0f} samples/s, {counts}, "
                f"distorted {p['distorted']} (not sent {p['not_sent_distorted']}){lat}")
        if pipe.igtl is not None:
            line += f", {pipe.igtl.n_clients} client(s)"
        k = p.get("link")
        if k is not None:
            line += (f", link: {k['gaps']} gap(s) ({k['samples_lost']} samples lost), "
                     f"{k['crc_errors']} bad CRC, {k['restarts']} restart(s)")
        if self.tty:
            pad = max(0, self._width - len(line))
            self._width = len(line)
            sys.stderr.write("\r" + line + " " * pad)
            sys.stderr.flush()
        else:
            print(line, file=sys.stderr, flush=True)

    def end_line(self) -> None:
        if self.tty and self._width:
            sys.stderr.write("\n")
            sys.stderr.flush()
            self._width = 0


def _board_calibration(cal) -> bool:
    """Whether a sensor's calibration ``cal`` (None: the preset's dipole model) is a board's,
    whose model has a solver of its own: its cold start is not the dipole family's closed
    form (``cold_start == "kim18"``)."""
    return cal is not None and getattr(cal.model, "cold_start", None) != "kim18"


def announce_compile_for(out, spec: TrackerSpec, calibrations=None) -> None:
    """Say so (on stderr unless ``out.quiet``) before the compiled kernels that tracking with
    ``spec`` runs compile (the first run after installation), before its sensors' solvers are
    prepared: the dipole solver's and its cold start's for a dipole sensor, a board's
    (:func:`~openemt._compile_notice.model_kernels`) for a board sensor, and the live path's;
    not the check of complex couplings (it solves real ones), nor the filter's kernel when no
    sensor has a filter. ``calibrations``: ``spec.calibrations()`` when already read."""
    from .._compile_notice import (
        FILTER_KERNELS,
        LIVE_KERNELS,
        announce_compile,
        dipole_kernels,
        model_kernels,
    )

    kernels: tuple = ()
    for cal in spec.calibrations() if calibrations is None else calibrations:
        kernels += (model_kernels(cal.model) if _board_calibration(cal)
                    else dipole_kernels(cold_start_table=True, complex_couplings=False))
    kernels = tuple(dict.fromkeys(kernels + LIVE_KERNELS))
    if not any(getattr(s.filter or spec.filter, "enabled", False) for s in spec.sensors):
        kernels = tuple(k for k in kernels if k not in FILTER_KERNELS)
    announce_compile(out, "solver kernels", kernels=kernels)


def default_tracker(options: TrackOptions) -> TrackerSpec:
    """The tracker without a tracker file: the shipped simulated one-sensor tracker with the
    preset's carriers and model (or ``calibration``; a board calibration gets the board
    tracker, docs/planar.md) and the device name (default ``SensorToTracker``)."""
    from ..simulate import get_preset
    from ._board import board_default_spec
    from ._tracker_file import (
        SensorSpec,
        device_from,
        example_tracker,
        read_tracker,
        sensor_device_name,
    )

    given = options.device_name
    name = "Sensor" if given is None else device_from(given)
    if options.calibration is not None:          # a board calibration: docs/planar.md
        from .._compile_notice import announce_compile

        board = board_default_spec(
            options.calibration, name, given, preset=options.preset,
            compiling=lambda kernels: announce_compile(options, "finite-coil kernels",
                                                       kernels=kernels))
        if board is not None:
            return board
    spec = read_tracker(example_tracker("simulated"))
    preset_name = options.preset or "concentric"
    preset = get_preset(preset_name)
    if (preset.n_source, preset.n_sensor) != (3, 3):
        raise InputError(f"expected a tri-axial source and sensor preset for track, got "
                         f"{preset_name!r} with {preset.n_source}x{preset.n_sensor} coils")
    sensor = SensorSpec(name=name, channels=(0, 1, 2), calibration=options.calibration,
                        device_name=given or sensor_device_name(name),
                        device_given=given is not None)
    sim = dict(spec.simulation, preset=preset_name)
    sim.pop("noise_rms", None)
    return replace(spec, frequencies=tuple(preset.frequencies), sensors=(sensor,),
                   simulation=sim, path=None)


def resolve_tracker(tracker, options: TrackOptions) -> TrackerSpec:
    """The tracker of a session: ``tracker`` (a path or a :class:`TrackerSpec`; None: the
    default one) with the options that override the file (filter, registration) applied."""
    from ._tracker_file import read_tracker

    if tracker is None:
        spec = default_tracker(options)
    elif isinstance(tracker, TrackerSpec):
        spec = tracker
    else:
        spec = read_tracker(tracker)
    spec = spec.with_filter(kind=options.filter, process_noise=options.process_noise,
                            measurement_noise=options.measurement_noise,
                            rotation_process_noise=options.rotation_process_noise,
                            rotation_measurement_noise=options.rotation_measurement_noise)
    if options.tip is not None:
        spec = spec.with_tip(options.tip)
    if options.registration is not None:
        spec = spec.with_registration(options.registration)
    return spec


class TrackingSession:
    """A live tracking session: every stage assembled here, once.

    ``with TrackingSession.from_tracker(path, options) as session: result = session.run()``.
    Entering opens the outputs (log, raw recording, OpenIGTLink server), the source (with
    its stall watch) and the pipeline (demodulation, solve, filter, registration);
    :meth:`run` tracks until the duration, the end of the data or a stop request (SIGINT /
    SIGTERM once tracking runs) and commits the files; leaving closes the server and the
    source, and on an error aborts the files (none is left half-written).

    ``sensors`` replaces the tracker's sensor setups (e.g. another solver), ``backend`` the
    source of ``options.source`` (any :class:`~openemt.live.Backend`, e.g. samples held in
    memory) and ``chunk`` the backend's samples per read; ``say`` receives the start-up lines
    (default: stderr unless ``options.quiet``). ``observer`` (e.g. the live view's
    :class:`openemt.view.LiveFeed`) is handed every raw chunk and every processed chunk, read
    only (:mod:`openemt.live._observe`).
    """

    def __init__(self, spec: TrackerSpec, options: TrackOptions | None = None, *,
                 sensors=None, backend=None, chunk: int = 640, say=None,
                 max_queue: int | None = None, match_layout: bool = True, observer=None):
        options = TrackOptions() if options is None else options
        if options.source is None:          # the tracker file's [adc] source, else sim
            options = replace(options, source=spec.adc_source or "sim")
        options.check()
        self.spec = spec
        self.options = options
        self.console = _Console(options.quiet)
        self._say = say or self.console.say
        self._sensors = sensors
        self._backend = backend
        self._chunk = int(chunk)
        self._max_queue = max_queue
        self._match_layout = bool(match_layout)
        self._observer = observer
        self.streams = spec.streams()
        self.log = self.raw = self.backend = self.server = self.source = self.pipeline = None
        self._ran = False

    @classmethod
    def from_tracker(cls, tracker=None, options: TrackOptions | None = None, **kw):
        """A session for ``tracker`` (a tracker file, a :class:`TrackerSpec`, or None for the
        default simulated tracker) and ``options``."""
        options = TrackOptions() if options is None else options
        options.check()
        kw.setdefault("match_layout", tracker is not None)
        return cls(resolve_tracker(tracker, options), options, **kw)

    # -- assembly
    def _igtl_server(self):
        from ._igtl import IgtlServer

        o, spec = self.options, self.spec
        kw = {}
        hv = o.header_version if o.header_version is not None else spec.header_version
        if hv is not None:
            from ._tracker_file import check_header_version

            kw["header_version"] = check_header_version(hv, "--header-version")
        rate = o.rate if o.rate is not None else spec.rate
        if rate is not None:
            kw["rate"] = rate
        if self._max_queue is not None:
            kw["max_queue"] = self._max_queue
        return IgtlServer(o.igtl_port, host=o.host, device_name=spec.sensors[0].device_name,
                          **kw)

    def config(self):
        """The pipeline's :class:`~openemt.live.PipelineConfig` of the tracker and options."""
        from ._pipeline import PipelineConfig

        o, spec = self.options, self.spec
        return PipelineConfig(
            output_rate=spec.output_rate, window=o.window or spec.window,
            distortion_threshold=(spec.distortion_threshold if o.distortion_threshold is None
                                  else o.distortion_threshold),
            send_distorted=o.send_distorted, reference=spec.reference,
            stale_after=spec.stale_after if o.stale_after is None else o.stale_after,
            tdata=bool(o.tdata or spec.tdata), igtl_metadata=spec.metadata and o.metadata,
            registration=spec.registration, witnesses=spec.witnesses,
            bands=o.bands or spec.solve_bands, band_time_constant=spec.band_time_constant)

    def __enter__(self) -> TrackingSession:
        from ._backends import StallWatch
        from ._pipeline import TrackingPipeline
        from ._record import RawRecorder, TrackLogWriter

        o, spec = self.options, self.spec
        try:
            # before the sensors' solvers are prepared (a board's solver computes its seed
            # grid's fields) and the backend (a simulated one computes couplings); the
            # calibration files are read once for both
            cals = spec.calibrations()
            announce_compile_for(o, spec, cals)
            sensors = (tracker_sensors(spec, calibrations=cals) if self._sensors is None
                       else self._sensors)
            if o.log is not None:
                self.log = TrackLogWriter(o.log, [s.name for s in sensors])
            try:
                self.backend = self._backend or tracker_backend(
                    spec, o.source, file=o.file, device=o.device, realtime=not o.fast,
                    duration=o.duration, seed=o.seed, noise_rms=o.noise, eddy_strength=o.eddy,
                    match_layout=self._match_layout, chunk=self._chunk)
            except ImportError as exc:                  # the optional sound-card package
                raise InputError(str(exc)) from None
            source = self.backend
            if o.save_raw is not None:
                self.raw = source = RawRecorder(self.backend, o.save_raw,
                                                truth_rate=spec.output_rate)
                if self.log is not None:
                    self.log.flush_first = self.raw.stream   # the raw behind every logged pose
            log = self.log
            if self._observer is not None:             # the live view: read only
                from ._observe import ObservedLog, ObservedSource

                source = ObservedSource(source, self._observer)
                log = ObservedLog(self.log, self._observer)
            self.source = StallWatch(source, warn_after=o.stall_warn, timeout=o.stall_timeout,
                                     on_warn=self.console.say)
            cfg = self.config()
            if o.igtl:
                self.server = self._igtl_server()
                self._say(f"OpenIGTLink: serving {describe_streams(self.streams, cfg.tdata)} "
                          f"on {o.host}:{self.server.port}; Ctrl-C to stop")
            self.pipeline = TrackingPipeline(self.source, sensors, cfg, igtl=self.server,
                                             log=log)
        except BaseException:
            self.__exit__(*sys.exc_info())
            raise
        return self

    def __exit__(self, kind, exc, tb) -> None:
        self.console.end_line()
        self.console.disarm()
        if kind is not None or not self._ran:      # an error, or never run: no file
            for w in (self.log, self.raw and self.raw.stream):
                if w is not None:
                    w.abort()
        if self.server is not None:
            self.server.close()
        if self.backend is not None:
            self.backend.close()

    def run(self, *, stop=None, monitor=None) -> TrackResult:
        """Track until the duration, the end of the data, ``stop()`` or SIGINT / SIGTERM;
        commit the files; the :class:`TrackResult`. ``monitor(pipeline)`` is called after
        every chunk (default: the status line)."""
        import signal

        o, spec, pipe = self.options, self.spec, self.pipeline
        self._say(f"tracking {len(spec.sensors)} sensor(s) from --source {o.source}"
                  f"{'' if o.duration is None else f' for {o.duration:g} s'}; Ctrl-C to stop")
        console = self.console

        def stopping():
            return console.stop() or (stop is not None and stop())

        restart = getattr(self.backend, "restart_clock", None)
        if restart is not None and not o.fast:
            restart()        # a paced simulator starts sampling now, not when it was made

        summary = pipe.run(o.duration, stop=stopping, monitor=monitor or console)
        self._ran = True
        console.end_line()
        stopped = console.signal
        if stopped is None and pipe.interrupted is not None:   # during start-up
            # SIGTERM arrives as the command line's ``Terminated`` (a KeyboardInterrupt)
            stopped = (signal.SIGTERM if type(pipe.interrupted).__name__ == "Terminated"
                       else signal.SIGINT)
        link = self.source.link_stats()
        if self.log is not None and link is not None:
            import json

            self.log.set_attrs({"source": self._source_name(), "link": json.dumps(link)})
        # a session stopped before its first sample never replaces an existing file
        for w in (self.log, self.raw and self.raw.stream):
            if w is not None:
                w.close(keep_empty=stopped is None)
        return self._result(summary, stopped)

    def _source_name(self) -> str:
        """``--source``, or what a given backend says it reads (``serial:PORT``, ...)."""
        return getattr(self.backend, "source", None) or self.options.source

    def _result(self, summary, stopped) -> TrackResult:
        import signal

        o, spec, server = self.options, self.spec, self.server
        out = {"source": self._source_name(),
               "tracker": None if spec.path is None else str(spec.path),
               "sensors_tracked": [s.name for s in spec.sensors],
               "device_name": None if server is None else spec.sensors[0].device_name,
               "device_names": None if server is None else [s.device_name
                                                            for s in spec.sensors],
               "frame": spec.frame,
               "registration": (None if spec.registration_path is None
                                else str(spec.registration_path)),
               "streams": [st.to_dict() for st in self.streams],
               "stalls": self.source.n_stalls,
               "longest_silence_s": self.source.longest_silence,
               "stopped_by": (None if stopped is None
                              else "SIGTERM" if stopped == signal.SIGTERM else "SIGINT")}
        link = self.backend.link_stats() if hasattr(self.backend, "link_stats") else None
        if link is not None:
            out["link"] = link
        if getattr(self.backend, "n_overflow", None) is not None:
            out["audio_blocks_dropped"] = self.backend.n_overflow
        if self.log is not None:
            out["log"] = str(o.log) if self.log.published else None
            out["log_rows"] = self.log.rows
        if self.raw is not None:
            out["raw"] = str(o.save_raw) if self.raw.published else None
            out["raw_rows"] = self.raw.rows
        return TrackResult(summary=summary, session=out, stopped_signal=stopped)


def tracker_sensors(spec: TrackerSpec, *, filter=None, calibrations=None) -> list:
    """One :class:`~openemt.live.SensorSetup` per sensor of ``spec``: its coupling columns,
    the model and linear correction of its calibration (the simulated preset's model when it
    names none), its OpenIGTLink device name, tip and filter (the file's
    ``[filter.sensors.<name>]``, else ``[filter]``; ``filter`` overrides both).

    A model whose solver starts cold from the closed form (``cold_start == "kim18"``: the
    dipole family) gets the pipeline's warm-started LM with the sensor's hemisphere and the
    calibration's linear correction; any other model (a finite-coil board) gets its own
    solver from :func:`openemt.solve.prepare`. ``calibrations``: ``spec.calibrations()`` when
    already read."""
    from ._pipeline import SensorSetup

    cals = list(spec.calibrations() if calibrations is None else calibrations)
    # sensors calibrated by one file share its model (and so one batched solver call)
    first: dict = {}
    for i, s in enumerate(spec.sensors):
        if s.calibration is not None:
            key = s.calibration.resolve()
            cals[i] = first.setdefault(key, cals[i])
    preset_model = None
    out = []
    boards: dict = {}
    for s, cols, cal in zip(spec.sensors, spec.sensor_columns(), cals):
        common = dict(name=s.name, columns=cols, device_name=s.device_name, tip=s.tip,
                      filter=(s.filter or spec.filter) if filter is None else filter)
        if _board_calibration(cal):
            from ._board import board_solver

            solver = boards.setdefault(id(cal), board_solver(cal.coupling_model))
            out.append(SensorSetup(solver=solver, **common))
            continue
        if cal is None:
            if preset_model is None:
                from ..simulate import get_preset

                preset_model = get_preset(spec.simulation.get("preset", "concentric")).dipole
            model, corr = preset_model, None
        else:
            # the model with what the calibration adds (octupoles, environment terms)
            model = getattr(cal, "coupling_model", cal.model)
            corr = getattr(cal, "linear_correction", None)
        out.append(SensorSetup(model=model, correction=corr, hemisphere=s.hemisphere,
                               **common))
    return out


def tracker_backend(spec: TrackerSpec, source: str, *, file=None, device=None,
                    realtime: bool = True, duration: float | None = None, seed=None,
                    noise_rms: float | None = None, eddy_strength: float | None = None,
                    chunk: int = 640, match_layout: bool = True, trajectory=None):
    """The backend of ``source`` (``"sim"``, ``"replay"``, ``"sound"``, ``"serial:PORT"`` or
    ``"tcp://HOST:PORT"``) for a tracker.

    ``sim`` simulates the tracker's channel layout (every sensor follows ``trajectory``, a
    callable of times giving poses, by default :func:`~openemt.live.default_trajectory`,
    shifted by its ``simulation_offset``; truth model from ``[simulation] preset``);
    ``replay`` reads a raw recording whose channel layout must match the tracker's
    (``match_layout=False``: the recording's own layout is used); ``sound`` opens the audio
    input ``device`` (an index, also as digits, or a name) with ``adc.channels`` channels at
    ``adc.sample_rate``; ``serial:`` and ``tcp://`` read frames of ``adc.channels`` channels
    at ``adc.sample_rate`` (:mod:`openemt.live._framing`).
    """
    from ._acquire import SerialBackend, TcpBackend, parse_source
    from ._backends import ReplayBackend, SimulatedBackend, SoundDeviceBackend

    layout = spec.layout()
    kind, where = parse_source(source)
    if kind == "serial":
        return SerialBackend(where[0], layout, spec.n_channels, baud=where[1], chunk=chunk)
    if kind == "tcp":
        return TcpBackend(where[0], where[1], layout, spec.n_channels, chunk=chunk)
    if source == "sound":                              # a device index may come as text
        device = int(device) if isinstance(device, str) and device.isdigit() else device
        return SoundDeviceBackend(layout, device=device, channels=spec.n_channels,
                                  chunk=chunk)
    if source == "replay":
        b = ReplayBackend(file, realtime=realtime, chunk=chunk)
        if not match_layout:
            return b
        got = b.layout
        if any(getattr(got, k) != getattr(layout, k) for k in (
                "sample_rate", "frequencies", "sensor_channels", "reference_channels")):
            raise InputError(f"expected a recording with the channel layout of "
                             f"{spec._where()} (sensor channels {layout.sensor_channels}, "
                             f"references {layout.reference_channels}, "
                             f"{layout.sample_rate:g} Hz), got {got.sensor_channels}, "
                             f"{got.reference_channels}, {got.sample_rate:g} Hz in {str(file)!r}")
        return b
    if source != "sim":
        raise InputError(f"expected a source in ('sim', 'replay', 'sound'), got {source!r}")
    from ..signal import RawSignalConfig
    from ..simulate import get_preset
    from ._board import board_trajectory, board_truth

    sim = spec.simulation
    model, path = board_truth(spec), board_trajectory   # a board calibration's truth
    if model is None:
        preset = get_preset(sim.get("preset", "concentric"))
        n_coils = {len(s.channels) for s in spec.sensors}
        if n_coils != {preset.n_sensor} or preset.n_source != len(spec.frequencies):
            raise InputError(f"{spec._where()}: expected sensors of {preset.n_sensor} coils "
                             f"and {preset.n_source} carriers for the simulated preset "
                             f"{preset.name!r}, got {sorted(n_coils)} coils and "
                             f"{len(spec.frequencies)} carriers")
        model, path = preset.dipole, None
    kw = {"mains_amplitudes": sim.get("mains_amplitudes", SIMULATED_MAINS_AMPLITUDES_V)}
    for key, over in (("noise_rms", noise_rms), ("eddy_strength", eddy_strength)):
        v = sim.get(key) if over is None else over
        if v is not None:
            kw[key] = v
    cfg = RawSignalConfig(layout=layout, **kw)
    offsets = np.array([s.simulation_offset for s in spec.sensors], dtype=np.float64)
    return SimulatedBackend(model, path if trajectory is None else trajectory, config=cfg,
                            seed=sim.get("seed", 0)
                            if seed is None else seed, realtime=realtime, duration=duration,
                            offsets=offsets, chunk=chunk, metal=sim.get("metal"))
