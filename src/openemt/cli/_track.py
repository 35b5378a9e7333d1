"""``openemt track``: live tracking from a simulated device or a raw recording to OpenIGTLink."""

from __future__ import annotations

import sys
from pathlib import Path

from .._constants import OUTPUT_RATE_HZ, SIMULATED_MAINS_AMPLITUDES_V
from .._errors import InputError

__all__ = ["register", "run"]


def register(subparsers) -> None:
    from . import command_help
    from ._common import add_common

    p = subparsers.add_parser(
        "track", help=command_help("track"),
        description="Demodulate raw samples (simulated device or an HDF5 recording), solve "
                    "poses with a warm-started LM solver and serve them as OpenIGTLink "
                    "TRANSFORM messages in millimetres for 3D Slicer (OpenIGTLinkIF, client "
                    "connector to the host and port below). Stops at --duration, at the end of "
                    "a recording, or on Ctrl-C.")
    p.add_argument("--source", choices=("sim", "replay"), default="sim",
                   help="simulated device (default) or replay of a raw HDF5 file")
    p.add_argument("file", nargs="?", type=Path, default=None,
                   help="raw HDF5 recording (with --source replay)")
    p.add_argument("--preset", default="concentric",
                   help="simulated tracker (openemt.simulate preset) whose dipole model "
                        "drives the simulation and the solver (default concentric)")
    p.add_argument("--calibration", type=Path, default=None,
                   help="calibration file (JSON or ILEMT .mat) for the solver's model and "
                        "linear correction (default: the preset's true model)")
    p.add_argument("--duration", type=float, default=None,
                   help="seconds of signal to process (default: until Ctrl-C / end of file)")
    p.add_argument("--igtl-port", type=int, default=18944,
                   help="OpenIGTLink server port (default 18944, Slicer's default)")
    p.add_argument("--no-igtl", action="store_true", help="do not start the OpenIGTLink server")
    p.add_argument("--host", default="127.0.0.1",
                   help="interface to serve on (0.0.0.0 for other machines)")
    p.add_argument("--device-name", default="openemt",
                   help="OpenIGTLink device name = transform node name in Slicer")
    p.add_argument("--fast", action="store_true",
                   help="process as fast as possible instead of at the sample rate")
    p.add_argument("--log", type=Path, default=None,
                   help="write per-sample poses, status and distortion to .h5 or .csv")
    p.add_argument("--save-raw", type=Path, default=None,
                   help="(sim) also write the raw samples to an HDF5 file for replay; needs "
                        "--duration")
    p.add_argument("--seed", type=int, default=0, help="simulation seed")
    p.add_argument("--noise", type=float, default=None,
                   help="(sim) sensor noise in V rms (default as RawSignalConfig)")
    p.add_argument("--eddy", type=float, default=0.0,
                   help="(sim) conductive-object strength; >0 shows as quadrature/distortion")
    p.add_argument("--window", choices=("hann", "rect"), default="hann",
                   help="demodulation window (default hann)")
    p.add_argument("--distortion-threshold", type=float, default=1e-3,
                   help="quadrature ratio above which a sample is flagged distorted")
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


def _model_and_correction(args):
    correction = None
    if args.calibration is not None:
        from ..io import read_calibration

        cal = read_calibration(args.calibration)
        model = cal.model
        correction = getattr(cal, "linear_correction", None)
        return model, correction
    from ..simulate import get_preset

    return get_preset(args.preset).dipole, None


def run(args) -> int:
    import numpy as np

    from ..live import IgtlServer, ReplayBackend, SimulatedBackend, TrackingPipeline, TrackLog
    from ..signal import RawSignal, RawSignalConfig, write_raw
    from ._common import emit

    if args.duration is not None and not args.duration > 0:
        raise InputError(f"expected a positive --duration, got {args.duration}")
    if args.source == "replay":
        if args.file is None:
            raise InputError("expected a raw HDF5 FILE with --source replay, got none")
        if args.save_raw is not None:
            raise InputError("expected --save-raw only with --source sim, got --source replay")
        backend = ReplayBackend(args.file, realtime=not args.fast)
    else:
        if args.file is not None:
            raise InputError(f"expected no FILE with --source sim, got {str(args.file)!r}")
        if args.save_raw is not None and args.duration is None:
            raise InputError("expected --duration with --save-raw, got none")
        from ..signal import ChannelLayout
        from ..simulate import get_preset

        preset = get_preset(args.preset)
        if (preset.n_source, preset.n_sensor) != (3, 3):
            raise InputError(f"expected a tri-axial source and sensor preset for track, got "
                             f"{args.preset!r} with {preset.n_source}x{preset.n_sensor} coils")
        kw = {"eddy_strength": args.eddy}
        if args.noise is not None:
            kw["noise_rms"] = args.noise
        layout = ChannelLayout(frequencies=tuple(preset.frequencies))
        cfg = RawSignalConfig(layout=layout, mains_amplitudes=SIMULATED_MAINS_AMPLITUDES_V, **kw)
        backend = SimulatedBackend(preset.dipole, config=cfg, seed=args.seed,
                                   realtime=not args.fast, duration=args.duration)
    model, correction = _model_and_correction(args)
    source = backend
    if args.save_raw is not None:
        source = _Recorder(backend)
    log = TrackLog() if args.log is not None else None
    if args.log is not None and args.log.suffix.lower() not in (".h5", ".hdf5", ".csv"):
        raise InputError(f"expected --log ending in .h5, .hdf5 or .csv, got {str(args.log)!r}")
    server = None
    if not args.no_igtl:
        server = IgtlServer(args.igtl_port, host=args.host, device_name=args.device_name)
        if not args.quiet:
            print(f"OpenIGTLink: serving TRANSFORM {args.device_name!r} (mm) on "
                  f"{args.host}:{server.port}; Ctrl-C to stop", file=sys.stderr)
    try:
        pipe = TrackingPipeline(source, model, correction=correction, window=args.window,
                                distortion_threshold=args.distortion_threshold, igtl=server,
                                log=log)
        summary = pipe.run(args.duration)
    finally:
        if server is not None:
            server.close()
        backend.close()
    out = summary.to_dict()
    out["source"] = args.source
    out["device_name"] = None if server is None else args.device_name
    if log is not None:
        log.write(args.log)
        out["log"] = str(args.log)
    if args.save_raw is not None:
        fs = backend.layout.sample_rate
        samples = np.concatenate(source.chunks) if source.chunks else np.empty((0, 6))
        tt = np.arange(0.0, samples.shape[0] / fs, 1.0 / OUTPUT_RATE_HZ)
        write_raw(RawSignal(samples=samples, layout=backend.layout, truth_times=tt,
                            truth_couplings=backend.true_couplings(tt),
                            truth_poses=backend.truth_poses(tt)), args.save_raw)
        out["raw"] = str(args.save_raw)
    human = [(f"tracked {summary.n_samples} samples ({summary.signal_seconds:.2f} s of signal) "
              f"in {summary.wall_seconds:.2f} s; status {summary.status_counts}; distorted "
              f"{100 * summary.distorted_fraction:.1f} %")]
    if summary.truth:
        human.append(f"position error vs truth: rms {summary.truth['position_error_mm_rms']:.4f}"
                     f" mm, max {summary.truth['position_error_mm_max']:.4f} mm")
    if summary.latency_ms_p50 is not None:
        human.append(f"latency coupling -> send: p50 {summary.latency_ms_p50:.3f} ms, p99 "
                     f"{summary.latency_ms_p99:.3f} ms")
    emit(args, out, human)
    return 0
