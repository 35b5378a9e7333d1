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
                   help="write per-sample poses, status and distortion to .h5 or .csv")
    p.add_argument("--save-raw", type=Path, default=None,
                   help="(sim) also write the raw samples to an HDF5 file for replay; needs "
                        "--duration")
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
                   help="quadrature ratio above which a sample is flagged distorted (default: "
                        "the tracker file's, else 1e-3)")
    add_common(p)
    p.set_defaults(func=run)


class _Recorder:
    """Backend wrapper that keeps every chunk read (for --save-raw)."""

    def __init__(self, backend):
        self.backend = backend
        self.layout = backend.layout
        self.t0_epoch = backend.t0_epoch
        self.chunks = []

    def read(self):
        x = self.backend.read()
        if x is not None:
            self.chunks.append(x)
        return x

    def truth_poses(self, times):
        return self.backend.truth_poses(times)

    def close(self):
        self.backend.close()


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


def run(args) -> int:
    import numpy as np

    from ..live import IgtlServer, TrackingPipeline, TrackLog, read_tracker
    from ..live._session import tracker_backend, tracker_sensors
    from ..signal import RawSignal, write_raw
    from ._common import emit

    if args.duration is not None and not 0 < args.duration < math.inf:
        raise InputError(f"expected a positive, finite --duration in seconds (leave it out to run "
                         f"until Ctrl-C), got {args.duration}")
    if args.distortion_threshold is not None:
        check_nonnegative(args.distortion_threshold, "--distortion-threshold")
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
    if args.save_raw is not None:
        if args.source != "sim":
            raise InputError(f"expected --save-raw only with --source sim, got --source "
                             f"{args.source}")
        if args.duration is None:
            raise InputError("expected --duration with --save-raw, got none")
    if args.device is not None and args.source != "sound":
        raise InputError(f"expected --device only with --source sound, got --source "
                         f"{args.source}")
    if args.log is not None and args.log.suffix.lower() not in (".h5", ".hdf5", ".csv"):
        raise InputError(f"expected --log ending in .h5, .hdf5 or .csv, got {str(args.log)!r}")
    device = args.device
    if isinstance(device, str) and device.isdigit():
        device = int(device)
    sensors = tracker_sensors(spec)
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
        source = _Recorder(backend)
    log = TrackLog() if args.log is not None else None
    server = None
    window = args.window or spec.window
    threshold = (spec.distortion_threshold if args.distortion_threshold is None
                 else args.distortion_threshold)
    try:
        if not args.no_igtl:
            server = IgtlServer(args.igtl_port, host=args.host,
                                device_name=spec.sensors[0].device_name)
            if not args.quiet:
                names = ", ".join(repr(s.device_name) for s in spec.sensors)
                print(f"OpenIGTLink: serving TRANSFORM {names} (mm) on "
                      f"{args.host}:{server.port}; Ctrl-C to stop", file=sys.stderr)
        pipe = TrackingPipeline(source, sensors=sensors, window=window,
                                output_rate=spec.output_rate,
                                distortion_threshold=threshold, igtl=server, log=log)
        summary = pipe.run(args.duration)
    finally:
        if server is not None:
            server.close()
        backend.close()
    out = summary.to_dict()
    out["source"] = args.source
    out["tracker"] = None if args.tracker is None else str(args.tracker)
    out["sensors_tracked"] = [s.name for s in spec.sensors]
    out["device_name"] = None if server is None else spec.sensors[0].device_name
    out["device_names"] = None if server is None else [s.device_name for s in spec.sensors]
    if getattr(backend, "n_overflow", None) is not None:
        out["audio_blocks_dropped"] = backend.n_overflow
    if log is not None:
        log.write(args.log)
        out["log"] = str(args.log)
    if args.save_raw is not None:
        lay = backend.layout
        fs = lay.sample_rate
        samples = (np.concatenate(source.chunks) if source.chunks
                   else np.empty((0, lay.n_channels)))
        tt = np.arange(0.0, samples.shape[0] / fs, 1.0 / spec.output_rate)
        write_raw(RawSignal(samples=samples, layout=lay, truth_times=tt,
                            truth_couplings=backend.true_couplings(tt),
                            truth_poses=backend.truth_poses(tt)), args.save_raw)
        out["raw"] = str(args.save_raw)
    human = [(f"tracked {summary.n_samples} samples ({summary.signal_seconds:.2f} s of signal) "
              f"of {len(spec.sensors)} sensor(s) in {summary.wall_seconds:.2f} s; status "
              f"{summary.status_counts}; distorted {100 * summary.distorted_fraction:.1f} %")]
    if summary.truth:
        human.append(f"position error vs truth: rms {summary.truth['position_error_mm_rms']:.4f}"
                     f" mm, max {summary.truth['position_error_mm_max']:.4f} mm")
    if summary.latency_ms_p50 is not None:
        human.append(f"latency coupling -> send: p50 {summary.latency_ms_p50:.3f} ms, p99 "
                     f"{summary.latency_ms_p99:.3f} ms")
    if summary.igtl:
        g = summary.igtl
        human.append(f"OpenIGTLink: {g['sent']} sent, {g['clients_max']} client(s) at most, "
                     f"{g['messages_skipped']} skipped for slow clients, "
                     f"{g['clients_dropped']} client(s) dropped")
    emit(args, out, human)
    return 0
