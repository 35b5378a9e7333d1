"""``openemt track``: live tracking from a simulated device, a raw recording or a sound card to
OpenIGTLink, for the sensors of a tracker description file."""

from __future__ import annotations

import math
import sys
from dataclasses import replace
from pathlib import Path

from .._errors import InputError, check_nonnegative

__all__ = ["register", "run"]


def register(subparsers) -> None:
    from . import command_help
    from ._common import add_common

    p = subparsers.add_parser(
        "track", help=command_help("track"),
        description="Demodulate raw samples (simulated device, an HDF5 recording or a sound "
                    "card), solve every sensor's pose with a warm-started LM solver, optionally "
                    "filter it, and serve each sensor as an OpenIGTLink TRANSFORM device in "
                    "millimetres for 3D Slicer (OpenIGTLinkIF, client connector to the host "
                    "and port below; several clients at once). Stops at --duration, at the end "
                    "of a recording, or on Ctrl-C.")
    p.add_argument("--tracker", type=Path, default=None,
                   help="tracker description file (TOML, docs/live.md#tracker-file): ADC, "
                        "channels, carriers, sensors, calibrations, device names, filter "
                        "(default: the simulated one-sensor tracker)")
    p.add_argument("--source", choices=("sim", "replay", "sound"), default="sim",
                   help="simulated device (default), replay of a raw HDF5 file, or a sound "
                        "card (needs --tracker and the optional package sounddevice)")
    p.add_argument("file", nargs="?", type=Path, default=None,
                   help="raw HDF5 recording (with --source replay)")
    p.add_argument("--device", default=None,
                   help="(sound) audio input device: index or name (openemt devices lists "
                        "them; default: the system default input)")
    p.add_argument("--preset", default=None,
                   help="(without --tracker) simulated tracker (openemt.simulate preset) whose "
                        "dipole model drives the simulation and the solver (default concentric)")
    p.add_argument("--calibration", type=Path, default=None,
                   help="(without --tracker) calibration file (JSON or ILEMT .mat) for the "
                        "solver's model and linear correction (default: the preset's true "
                        "model); a finite-coil board calibration tracks its 5-DOF sensor on the "
                        "board's carriers (docs/planar.md)")
    p.add_argument("--filter", choices=("none", "kalman"), default=None,
                   help="tracking filter per sensor: constant-velocity Kalman filter, reset "
                        "on loss (default: the tracker file's [filter], else none)")
    p.add_argument("--process-noise", type=float, default=None,
                   help="filter: white-acceleration density, m/s^2/sqrt(Hz) (default 0.01)")
    p.add_argument("--measurement-noise", type=float, default=None,
                   help="filter: position noise per axis, m (default 2e-6)")
    p.add_argument("--rotation-process-noise", type=float, default=None,
                   help="filter: white angular-acceleration density, rad/s^2/sqrt(Hz) "
                        "(default 0.1)")
    p.add_argument("--rotation-measurement-noise", type=float, default=None,
                   help="filter: orientation noise per axis, rad (default 2e-5)")
    p.add_argument("--duration", type=float, default=None,
                   help="seconds of signal to process (default: until Ctrl-C / end of file)")
    p.add_argument("--igtl-port", type=int, default=18944,
                   help="OpenIGTLink server port (default 18944, Slicer's default)")
    p.add_argument("--no-igtl", action="store_true", help="do not start the OpenIGTLink server")
    p.add_argument("--host", default="127.0.0.1",
                   help="interface to serve on (0.0.0.0 for other machines)")
    p.add_argument("--device-name", default=None,
                   help="(without --tracker) OpenIGTLink device name = transform node name in "
                        "Slicer (default openemt)")
    p.add_argument("--fast", action="store_true",
                   help="process as fast as possible instead of at the sample rate")
    p.add_argument("--log", type=Path, default=None,
                   help="write per-sample poses, status and distortion to .h5 or .csv, "
                        "appended every second while the session runs")
    p.add_argument("--save-raw", type=Path, default=None,
                   help="(sim) also write the raw samples to an HDF5 file for replay, "
                        "appended every second while the session runs")
    p.add_argument("--stall-warn", type=float, default=2.0,
                   help="warn after this many seconds without samples from the source "
                        "(default 2)")
    p.add_argument("--stall-timeout", type=float, default=10.0,
                   help="stop with an error (exit 2) after this many seconds without samples "
                        "from the source, also before the first one (default 10)")
    p.add_argument("--stale-after", type=float, default=None,
                   help="watchdog: report a sensor STALE on its <device>State message after "
                        "this many seconds without a valid pose (default: the tracker file's "
                        "[igtl] stale_after, else 0.5)")
    p.add_argument("--tdata", action="store_true",
                   help="send all sensors of one sample in one OpenIGTLink TDATA (tracking "
                        "data) message on device 'openemt' instead of one TRANSFORM per sensor "
                        "(default: the tracker file's [igtl] tdata, else off)")
    p.add_argument("--no-metadata", action="store_true",
                   help="send version-1 TRANSFORMs without the Status, RelativeResidual and "
                        "Distortion metadata (cheaper for a viewer on the same small machine; "
                        "default: the tracker file's [igtl] metadata, else on)")
    p.add_argument("--send-distorted", action="store_true",
                   help="also send converged poses flagged as distorted (default: distorted "
                        "samples are logged and flagged, not sent)")
    p.add_argument("--seed", type=int, default=None,
                   help="simulation seed (default: the tracker file's [simulation], else 0)")
    p.add_argument("--noise", type=float, default=None,
                   help="(sim) sensor noise in V rms (default: the tracker file's "
                        "[simulation], else 1.5e-5)")
    p.add_argument("--eddy", type=float, default=None,
                   help="(sim) conductive-object strength; >0 shows as quadrature/distortion "
                        "(default: the tracker file's [simulation], else 0)")
    p.add_argument("--window", choices=("hann", "rect"), default=None,
                   help="demodulation window (default: the tracker file's, else hann)")
    p.add_argument("--distortion-threshold", type=float, default=None,
                   help="quadrature ratio above which a sample is flagged distorted and not "
                        "sent (default: the tracker file's, else 1e-3)")
    add_common(p)
    p.set_defaults(func=run)


def _default_spec(args):
    """The tracker without a tracker file: the shipped simulated one-sensor tracker with the
    preset's carriers, model (or --calibration) and --device-name."""
    from ..live import SensorSpec, example_tracker, read_tracker
    from ..live._board import board_default_spec
    from ..simulate import get_preset

    device = args.device_name or "openemt"
    if args.calibration is not None:          # a board calibration: docs/planar.md
        board = board_default_spec(args.calibration, device, preset=args.preset)
        if board is not None:
            return board
    spec = read_tracker(example_tracker("simulated"))
    name = args.preset or "concentric"
    preset = get_preset(name)
    if (preset.n_source, preset.n_sensor) != (3, 3):
        raise InputError(f"expected a tri-axial source and sensor preset for track, got "
                         f"{name!r} with {preset.n_source}x{preset.n_sensor} coils")
    sensor = SensorSpec(name=device, channels=(0, 1, 2), calibration=args.calibration,
                        device_name=device)
    sim = dict(spec.simulation, preset=name)
    sim.pop("noise_rms", None)
    return replace(spec, frequencies=tuple(preset.frequencies), sensors=(sensor,),
                   simulation=sim, path=None)


class _Session:
    """The command's side of a running session: SIGTERM/Ctrl-C become a stop request once
    tracking runs (the chunk in hand is finished and the outputs are closed), and a status
    line on stderr (carriage-return updated every second on a terminal; a plain line every
    5 s otherwise; none with --quiet)."""

    def __init__(self, args):
        self.quiet = bool(args.quiet)
        self.tty = sys.stderr.isatty()
        self.period = 1.0 if self.tty else 5.0
        self.signal = None               # the signal number that asked to stop
        self._previous: dict = {}
        self._t0 = self._last = None
        self._n0 = 0
        self._width = 0

    # -- signals: a flag instead of an exception in the middle of a chunk or a flush
    def _on_signal(self, signum, frame):
        self.signal = signum

    def arm(self) -> None:
        import signal
        import threading

        if self._previous or threading.current_thread() is not threading.main_thread():
            return
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._previous[sig] = signal.signal(sig, self._on_signal)

    def disarm(self) -> None:
        import signal

        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous = {}

    def stop(self) -> bool:
        return self.signal is not None

    def say(self, text: str) -> None:
        if self.quiet:
            return
        self.end_line()
        print(text, file=sys.stderr, flush=True)

    # -- the status line
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


def _announce_compile(args, sensors) -> None:
    """Say so before the solver kernels compile (first run after installation)."""
    from .._compile_notice import LIVE_KERNELS, PLANAR_KERNELS, SOLVER_KERNELS, announce_compile

    kernels = SOLVER_KERNELS + LIVE_KERNELS
    if any(s.solver is not None for s in sensors):       # a board sensor
        kernels += PLANAR_KERNELS
    announce_compile(args, "solver kernels", kernels=kernels)


def run(args) -> int:
    import signal

    # on a terminal, a first line before the heavy imports (a second or two; elsewhere bad
    # input stays one `error:` line)
    if not args.quiet and sys.stderr.isatty():
        print(f"openemt track: starting (--source {args.source}; loading the solver and the "
              f"source)", file=sys.stderr, flush=True)
    from ..live import IgtlServer, StallWatch, TrackingPipeline, read_tracker
    from ..live._record import RawRecorder, TrackLogWriter
    from ..live._session import tracker_backend, tracker_sensors
    from ..live._tracker_file import relative_device_name
    from ._common import emit

    if args.duration is not None and not 0 < args.duration < math.inf:
        raise InputError(f"expected a positive, finite --duration in seconds (leave it out to run "
                         f"until Ctrl-C), got {args.duration}")
    for opt, v in (("--stall-warn", args.stall_warn), ("--stall-timeout", args.stall_timeout)):
        if not 0 < v < math.inf:
            raise InputError(f"expected a positive, finite {opt} in seconds, got {v}")
    if args.distortion_threshold is not None:
        check_nonnegative(args.distortion_threshold, "--distortion-threshold")
    if args.stale_after is not None and not 0 < args.stale_after < math.inf:
        raise InputError(f"expected a positive, finite --stale-after in seconds, got "
                         f"{args.stale_after}")
    if args.tracker is not None:
        for opt, v in (("--preset", args.preset), ("--calibration", args.calibration),
                       ("--device-name", args.device_name)):
            if v is not None:
                raise InputError(f"expected no {opt} with --tracker (the tracker file names "
                                 f"the model, calibrations and devices), got {v}")
        spec = read_tracker(args.tracker)
    elif args.source == "sound":
        raise InputError("expected --tracker FILE with --source sound (which channels are "
                         "references and sensor coils), got none")
    else:
        spec = _default_spec(args)
    spec = spec.with_filter(kind=args.filter, process_noise=args.process_noise,
                            measurement_noise=args.measurement_noise,
                            rotation_process_noise=args.rotation_process_noise,
                            rotation_measurement_noise=args.rotation_measurement_noise)
    if args.source == "replay":
        if args.file is None:
            raise InputError("expected a raw HDF5 FILE with --source replay, got none")
    elif args.file is not None:
        raise InputError(f"expected FILE only with --source replay, got {str(args.file)!r}")
    if args.save_raw is not None and args.source != "sim":
        raise InputError(f"expected --save-raw only with --source sim, got --source "
                         f"{args.source}")
    if args.save_raw is not None and args.save_raw.suffix.lower() not in (".h5", ".hdf5"):
        raise InputError(f"expected --save-raw ending in .h5 or .hdf5, got "
                         f"{str(args.save_raw)!r}")
    if args.device is not None and args.source != "sound":
        raise InputError(f"expected --device only with --source sound, got --source "
                         f"{args.source}")
    if args.log is not None and args.log.suffix.lower() not in (".h5", ".hdf5", ".csv"):
        raise InputError(f"expected --log ending in .h5, .hdf5 or .csv, got {str(args.log)!r}")
    # every output was checked before anything started (folders, file kinds, one file per
    # option: openemt.cli.check_outputs)
    device = args.device
    if isinstance(device, str) and device.isdigit():
        device = int(device)
    sensors = tracker_sensors(spec)
    session = _Session(args)
    log = raw = backend = server = None
    try:
        log = (TrackLogWriter(args.log, [s.name for s in sensors]) if args.log is not None
               else None)
        try:
            backend = tracker_backend(spec, args.source, file=args.file, device=device,
                                      realtime=not args.fast, duration=args.duration,
                                      seed=args.seed, noise_rms=args.noise,
                                      eddy_strength=args.eddy,
                                      match_layout=args.tracker is not None)
        except ImportError as exc:                  # the optional sound-card package
            raise InputError(str(exc)) from None
        source = backend
        if args.save_raw is not None:
            raw = source = RawRecorder(backend, args.save_raw, truth_rate=spec.output_rate)
            if log is not None:
                log.flush_first = raw.stream     # the raw behind every logged pose, committed first
        source = StallWatch(source, warn_after=args.stall_warn, timeout=args.stall_timeout,
                            on_warn=session.say)
        window = args.window or spec.window
        threshold = (spec.distortion_threshold if args.distortion_threshold is None
                     else args.distortion_threshold)
        tdata = bool(args.tdata or spec.tdata)
        if not args.no_igtl:
            server = IgtlServer(args.igtl_port, host=args.host,
                                device_name=spec.sensors[0].device_name)
            if not args.quiet:
                names = [s.device_name for s in spec.sensors]
                if spec.reference is not None:
                    names += [relative_device_name(s.name) for s in spec.sensors
                              if s.name != spec.reference]
                what = (f"TDATA 'openemt' (tools {', '.join(map(repr, names))})" if tdata
                        else f"TRANSFORM {', '.join(map(repr, names))}")
                print(f"OpenIGTLink: serving {what} (mm) on "
                      f"{args.host}:{server.port}; Ctrl-C to stop", file=sys.stderr)
        pipe = TrackingPipeline(source, sensors=sensors, window=window,
                                output_rate=spec.output_rate,
                                distortion_threshold=threshold, igtl=server, log=log,
                                send_distorted=args.send_distorted, reference=spec.reference,
                                stale_after=(spec.stale_after if args.stale_after is None
                                             else args.stale_after), tdata=tdata,
                                igtl_metadata=spec.metadata and not args.no_metadata)
        _announce_compile(args, sensors)
        if not args.quiet:
            print(f"tracking {len(spec.sensors)} sensor(s) from --source {args.source}"
                  f"{'' if args.duration is None else f' for {args.duration:g} s'}; "
                  f"Ctrl-C to stop", file=sys.stderr, flush=True)
        summary = pipe.run(args.duration, stop=session.stop, monitor=session)
        session.end_line()
        stopped = session.signal
        if stopped is None and pipe.interrupted is not None:   # during start-up
            from . import Terminated

            stopped = (signal.SIGTERM if isinstance(pipe.interrupted, Terminated)
                       else signal.SIGINT)
        # a session stopped before its first sample never replaces an existing file
        for w in (log, raw and raw.stream):
            if w is not None:
                w.close(keep_empty=stopped is None)
    except BaseException:
        session.end_line()
        session.disarm()
        for w in (log, raw and raw.stream):
            if w is not None:
                w.abort()
        raise
    finally:
        if server is not None:
            server.close()
        if backend is not None:
            backend.close()
    session.disarm()
    out = summary.to_dict()
    out["source"] = args.source
    out["tracker"] = None if args.tracker is None else str(args.tracker)
    out["sensors_tracked"] = [s.name for s in spec.sensors]
    out["device_name"] = None if server is None else spec.sensors[0].device_name
    out["device_names"] = None if server is None else [s.device_name for s in spec.sensors]
    out["stalls"] = source.n_stalls
    out["longest_silence_s"] = source.longest_silence
    out["stopped_by"] = (None if stopped is None
                         else "SIGTERM" if stopped == signal.SIGTERM else "SIGINT")
    if getattr(backend, "n_overflow", None) is not None:
        out["audio_blocks_dropped"] = backend.n_overflow
    if log is not None:
        out["log"] = str(args.log) if log.published else None
        out["log_rows"] = log.rows
    if raw is not None:
        out["raw"] = str(args.save_raw) if raw.published else None
        out["raw_rows"] = raw.rows
    human = [(f"tracked {summary.n_samples} samples ({summary.signal_seconds:.2f} s of signal) "
              f"of {len(spec.sensors)} sensor(s) in {summary.wall_seconds:.2f} s; status "
              f"{summary.status_counts}; distorted {100 * summary.distorted_fraction:.1f} %"
              f" ({out['not_sent_distorted']} converged but not sent)")]
    if summary.truth:
        human.append(f"position error vs truth: rms {summary.truth['position_error_mm_rms']:.4f}"
                     f" mm, max {summary.truth['position_error_mm_max']:.4f} mm")
    ev = out["events"]
    if ev["lost"] or ev["distorted"] or ev["stale"]:
        human.append(f"stream states: lost {ev['lost']}, distorted {ev['distorted']}, stale "
                     f"{ev['stale']}, recovered {ev['recovered']} time(s) (sent on "
                     f"<device>State)")
    if summary.latency_ms_p50 is not None:
        human.append(f"latency coupling -> send: p50 {summary.latency_ms_p50:.3f} ms, p99 "
                     f"{summary.latency_ms_p99:.3f} ms")
    if summary.igtl:
        g = summary.igtl
        human.append(f"OpenIGTLink: {g['sent']} sent, {g['clients_max']} client(s) at most, "
                     f"{g['messages_skipped']} skipped for slow clients, "
                     f"{g['clients_dropped']} client(s) dropped")
    if stopped is not None:
        human.append(f"stopped by {out['stopped_by']} after {summary.n_samples} samples"
                     + ("; outputs written" if summary.n_samples else
                        "; no sample yet, existing outputs left unchanged"))
    emit(args, out, human)
    if stopped is not None:
        return 128 + int(stopped)
    return 0
