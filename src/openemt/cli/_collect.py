"""``openemt collect``: record a reference-pose dataset from a tracker source and a reference
(OpenIGTLink client, CSV with time stamps, or a simulated robot / optical tracker) for
``openemt calibrate --mode reference``."""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import numpy as np

from .._errors import InputError

__all__ = ["register", "run"]

#: Simulated reference defaults: messages per second, latency and clock offset (s).
SIM_RATE_HZ = 250.0
SIM_LATENCY_S = 0.030
SIM_CLOCK_OFFSET_S = 0.250


def register(subparsers) -> None:
    from . import command_help
    from ._common import add_common

    p = subparsers.add_parser(
        "collect", help=command_help("collect"),
        description="Acquire couplings from a tracker source while reference poses arrive "
                    "(an OpenIGTLink server such as PLUS or 3D Slicer, a CSV with time stamps, "
                    "or a simulated robot / optical tracker served over OpenIGTLink); estimate "
                    "the time offset of the two clocks, average both streams over the dwells "
                    "where both are static, and write a dataset for 'openemt calibrate --mode "
                    "reference' (docs/reference-calibration.md#collecting). Stops at --n-poses, "
                    "--duration, the end of the source or reference, or on Ctrl-C, writing what "
                    "it has.")
    p.add_argument("--tracker", type=Path, default=None,
                   help="tracker description file (TOML, docs/live.md#tracker-file) (default: "
                        "the simulated one-sensor tracker)")
    p.add_argument("--source", choices=("sim", "replay", "sound"), default="sim",
                   help="simulated device (default; it follows the simulated robot's motion of "
                        "--seed), replay of a raw HDF5 file, or a sound card")
    p.add_argument("file", nargs="?", type=Path, default=None,
                   help="raw HDF5 recording (with --source replay)")
    p.add_argument("--device", default=None,
                   help="(sound) audio input device: index or name")
    p.add_argument("--sensor", default=None,
                   help="name of the tracker file's sensor to collect (default: the first)")
    ref = p.add_mutually_exclusive_group(required=True)
    ref.add_argument("--reference", default=None, metavar="igtl://HOST:PORT/DEVICE",
                     help="receive reference poses as an OpenIGTLink client: TRANSFORM "
                          "messages of DEVICE (mm, time-stamped by the sender)")
    ref.add_argument("--reference-csv", type=Path, default=None, metavar="CSV",
                     help="reference poses with time stamps (columns time, x/y/z, an "
                          "orientation; docs/reference-calibration.md#collecting)")
    ref.add_argument("--simulate-reference", choices=("robot", "optical"), default=None,
                     help="(--source sim) a simulated robot or optical tracker on the same "
                          "motion, served by an OpenIGTLink server on a free local port")
    p.add_argument("--n-poses", type=int, default=100,
                   help="stop after this many dwells are collected (default 100)")
    p.add_argument("--duration", type=float, default=None,
                   help="stop after this many seconds of tracker signal (default: none)")
    p.add_argument("--reference-noise-mm", type=float, default=None, metavar="MM",
                   help="stated translation noise of one reference pose, 3-D RMS (default: "
                        "the simulated kind's, robot 0.05, optical 0.25; else not stated)")
    p.add_argument("--reference-noise-deg", type=float, default=None, metavar="DEG",
                   help="stated rotation noise, RMS angle (default: robot 0.02, optical 0.1)")
    p.add_argument("--reference-timeout", type=float, default=2.0,
                   help="seconds without a reference pose after which the reference counts as "
                        "stopped (default 2)")
    p.add_argument("--max-offset", type=float, default=None,
                   help="search the time offset within +-this many seconds (default: any "
                        "offset with half the recordings overlapping)")
    p.add_argument("--sim-rate", type=float, default=SIM_RATE_HZ,
                   help=f"(simulated reference) poses per second (default {SIM_RATE_HZ:g})")
    p.add_argument("--sim-latency-ms", type=float, default=SIM_LATENCY_S * 1e3,
                   help=f"(simulated reference) latency of its poses (default "
                        f"{SIM_LATENCY_S * 1e3:g} ms)")
    p.add_argument("--sim-clock-offset-ms", type=float, default=SIM_CLOCK_OFFSET_S * 1e3,
                   help=f"(simulated reference) its clock minus the tracker's (default "
                        f"{SIM_CLOCK_OFFSET_S * 1e3:g} ms)")
    p.add_argument("--sim-stop-after", type=float, default=None, metavar="S",
                   help="(simulated reference) stop serving after S seconds (a reference that "
                        "goes away mid-collection)")
    p.add_argument("--sim-speed", type=float, default=1.0,
                   help="(--source sim) simulated seconds per wall-clock second for the tracker "
                        "and the simulated reference alike (default 1: real time)")
    p.add_argument("--seed", type=int, default=0,
                   help="(--source sim) seed of the simulated motion and noise (default 0)")
    p.add_argument("-o", "--output", required=True, type=Path, help="output dataset (.h5)")
    add_common(p)
    p.set_defaults(func=run)


def _check(args) -> None:
    if args.n_poses < 1:
        raise InputError(f"expected --n-poses >= 1, got {args.n_poses}")
    for opt, v in (("--duration", args.duration), ("--reference-timeout",
                                                   args.reference_timeout),
                   ("--max-offset", args.max_offset), ("--sim-rate", args.sim_rate),
                   ("--sim-stop-after", args.sim_stop_after)):
        if v is not None and not 0 < v < math.inf:
            raise InputError(f"expected a positive, finite {opt}, got {v}")
    if not 0 < args.sim_speed <= 100:
        raise InputError(f"expected --sim-speed in (0, 100], got {args.sim_speed}")
    for opt, v in (("--sim-latency-ms", args.sim_latency_ms),
                   ("--sim-clock-offset-ms", args.sim_clock_offset_ms),
                   ("--reference-noise-mm", args.reference_noise_mm),
                   ("--reference-noise-deg", args.reference_noise_deg)):
        if v is not None and not math.isfinite(v):
            raise InputError(f"expected a finite {opt}, got {v}")
    if args.simulate_reference is not None and args.source != "sim":
        raise InputError(f"expected --simulate-reference only with --source sim (the simulated "
                         f"reference follows the simulated motion), got --source {args.source}")
    if args.source == "replay" and args.file is None:
        raise InputError("expected a raw HDF5 FILE with --source replay, got none")
    if args.source != "replay" and args.file is not None:
        raise InputError(f"expected FILE only with --source replay, got {str(args.file)!r}")
    if args.source == "sound" and args.tracker is None:
        raise InputError("expected --tracker FILE with --source sound, got none")
    if args.output.suffix.lower() not in (".h5", ".hdf5"):
        raise InputError(f"expected -o ending in .h5 or .hdf5, got {str(args.output)!r}")


def _sensor(spec, sensors, name):
    if name is None:
        return 0
    names = [s.name for s in spec.sensors]
    if name not in names:
        raise InputError(f"expected --sensor to be one of {names}, got {name!r}")
    return names.index(name)


def spare_poses(n_poses: int) -> int:
    """Holds of the simulated motion after the ``n_poses`` of ``openemt simulate --reference``,
    for holds that a collection drops."""
    return max(5, int(n_poses) // 4)


class _Status:
    """The live feedback line on stderr (every second on a terminal, every 5 s otherwise)."""

    def __init__(self, session, n_poses):
        self.session, self.n_poses = session, n_poses
        self.period = 1.0 if sys.stderr.isatty() else 5.0
        self._last = time.monotonic()

    def due(self) -> bool:
        now = time.monotonic()
        if now - self._last < self.period:
            return False
        self._last = now
        return True

    def show(self, signal_s, dws, cov) -> None:
        if dws is None:
            self.session.say(f"collect {signal_s:.1f} s: waiting for both streams")
            return
        div = ("ok" if cov["rotation_diversity_ok"] else "NOT yet (rotate about another axis)")
        spread = cov["orientation_spread_deg"]
        self.session.say(
            f"collect {signal_s:.1f} s: {len(dws)}/{self.n_poses} poses, time offset "
            f"{dws.time_offset * 1e3:.1f} ms (r={dws.offset_correlation:.2f}), coverage "
            f"{cov['volume_coverage_pct']:.0f} % of the working volume, orientation spread "
            f"{0.0 if spread is None else spread:.1f} deg, rotation diversity {div}")


def _warm_up(model, hemisphere) -> None:
    from ..solve import solve_lm

    P = np.eye(4)[None].copy()
    P[0, :3, 3] = [0.25, 0.02, 0.01]                   # any pose in the volume will do
    solve_lm(model.coupling(P), model, hemisphere=hemisphere)


def _coverage(dws, model, hemisphere, box):
    from ..align import coverage
    from ..solve import solve_lm

    if dws is None or not len(dws):
        return coverage(np.empty((0, 3)), np.empty((0, 4, 4)), box)
    res = solve_lm(dws.couplings, model, hemisphere=hemisphere)
    return coverage(res.poses[:, :3, 3], dws.reference_poses, box)


def run(args) -> int:  # noqa: C901 - one acquisition loop with its stop conditions
    import signal

    from ..live import example_tracker, read_tracker
    from ..live._collect import Collector
    from ..live._refclient import (
        ReferenceClient,
        SimulatedReferenceServer,
        parse_reference_url,
        read_reference_csv,
        simulated_motion,
    )
    from ..live._session import tracker_backend, tracker_sensors
    from ..simulate import REFERENCE_KINDS, get_preset
    from ..simulate._reference import _volume
    from ._common import emit
    from ._track import _announce_compile, _Session

    _check(args)
    spec = read_tracker(args.tracker if args.tracker is not None
                        else example_tracker("simulated"))
    sensors = tracker_sensors(spec)
    k = _sensor(spec, sensors, args.sensor)
    setup = sensors[k]
    if setup.model is None:
        raise InputError(f"expected a dipole tracker for collect, got the board sensor "
                         f"{setup.name!r}")
    url = None
    if args.reference is not None:
        url = parse_reference_url(args.reference)
    csv = None
    if args.reference_csv is not None:
        csv = read_reference_csv(args.reference_csv)
    kind = args.simulate_reference or "robot"
    stated = REFERENCE_KINDS[kind] if (args.source == "sim" or args.simulate_reference) \
        else None
    noise_t = (args.reference_noise_mm * 1e-3 if args.reference_noise_mm is not None
               else None if stated is None else stated.noise_trans)
    noise_r = (np.deg2rad(args.reference_noise_deg) if args.reference_noise_deg is not None
               else None if stated is None else stated.noise_rot)
    preset = spec.simulation.get("preset", "concentric")
    motion = None
    if args.source == "sim":
        motion = simulated_motion(kind, args.n_poses, spare=spare_poses(args.n_poses),
                                  preset=preset, seed=args.seed, noise_trans=noise_t,
                                  noise_rot=noise_r)
    box = motion.box if motion is not None else np.array(_volume(get_preset(preset))[:2])
    hemisphere = setup.hemisphere
    if motion is not None and args.tracker is None:
        hemisphere = motion.hemisphere

    # the coverage feedback solves each dwell: compile (first run only) before the streams start
    _announce_compile(args, [setup])
    _warm_up(setup.model, hemisphere)
    session = _Session(args)
    backend = server = client = None
    stopped = lost = None
    end = "n_poses"
    dws = None
    try:
        if motion is not None:
            backend = tracker_backend(spec, "sim", realtime=False, seed=args.seed,
                                      trajectory=motion.sensor_poses)
        else:
            device = args.device
            if isinstance(device, str) and device.isdigit():
                device = int(device)
            try:
                backend = tracker_backend(spec, args.source, file=args.file, device=device,
                                          realtime=args.source == "replay" and csv is None,
                                          match_layout=args.tracker is not None)
            except ImportError as exc:
                raise InputError(str(exc)) from None
        t0 = backend.t0_epoch
        coll = Collector(backend.layout, setup.columns, output_rate=spec.output_rate,
                         window=spec.window, t0=t0)
        if args.simulate_reference is not None:
            server = SimulatedReferenceServer(
                motion, t0=t0, rate=args.sim_rate, latency=args.sim_latency_ms * 1e-3,
                clock_offset=args.sim_clock_offset_ms * 1e-3, speed=args.sim_speed,
                seed=args.seed, stop_after=args.sim_stop_after)
            session.say(f"simulated {kind} reference: OpenIGTLink TRANSFORM on {server.url} "
                        f"({args.sim_rate:g} Hz, latency {args.sim_latency_ms:g} ms, clock "
                        f"offset {args.sim_clock_offset_ms:g} ms)")
            url = ("127.0.0.1", server.port, server.device)
        if url is not None:
            client = ReferenceClient(*url)
        else:
            coll.add_reference(*csv)
        paced = motion is not None and client is not None
        session.say(f"collecting {args.n_poses} poses of sensor {setup.name!r} from --source "
                    f"{args.source}; Ctrl-C to stop and write what is collected")
        status = _Status(session, args.n_poses)
        session.arm()
        wall0 = time.time()
        analysed = time.monotonic()
        while True:
            if session.stop():
                stopped, end = session.signal, "signal"
                break
            chunk = backend.read()
            if chunk is None:
                end = "end of source"
                break
            coll.add_chunk(chunk)
            tau = (coll.tracker_time or t0) - t0
            if paced:                       # the simulated world runs at --sim-speed
                delay = t0 + tau / args.sim_speed - time.time()
                if delay > 0:
                    time.sleep(delay)
            if client is not None:
                coll.add_reference(*client.take())
                now = time.time()
                if client.error is not None or client.closed:
                    lost = client.error or (f"the server closed the connection after "
                                            f"{client.n_messages} poses")
                elif client.last_receipt is None:
                    if now - wall0 > client.connect_timeout + args.reference_timeout:
                        lost = (f"no pose of device {client.device!r} in "
                                f"{now - wall0:.1f} s")
                elif now - client.last_receipt > args.reference_timeout:
                    lost = (f"no pose for {now - client.last_receipt:.1f} s after "
                            f"{client.n_messages} poses")
                if lost is not None:
                    end = "reference lost"
                    break
            if args.duration is not None and tau >= args.duration:
                end = "duration"
                break
            if time.monotonic() - analysed >= 1.0:
                analysed = time.monotonic()
                dws = coll.analyse(max_offset=args.max_offset)
                if status.due():
                    status.show(tau, dws, _coverage(dws, setup.model, hemisphere, box))
                if dws is not None and len(dws) >= args.n_poses:
                    break
                if csv is not None and dws is not None and \
                        coll.tracker_time + dws.time_offset > csv[0][-1] + 1.0:
                    end = "end of reference CSV"
                    break
        session.disarm()
        if client is not None:
            coll.add_reference(*client.take())
    except BaseException:
        session.disarm()
        raise
    finally:
        for part in (server, client, backend):    # the server first: no reset
            if part is not None:
                part.close()
    if lost is not None:
        session.say(f"warning: the reference {args.reference or url} stopped: {lost}; "
                    f"writing the poses collected so far")
    dws = coll.analyse(max_offset=args.max_offset)
    if dws is None or not len(dws):
        got = ("no reference pose" if coll.n_reference == 0 else
               "less than a second of either stream" if dws is None else
               f"none ({dws.tracker_dwells} static intervals in the tracker stream, "
               f"{dws.reference_dwells} in the reference stream)")
        raise InputError(f"expected at least one dwell where the tracker and the reference "
                         f"were both static, got {got}; nothing written")
    n = min(len(dws), args.n_poses)
    ds = _dataset(args, dws, n, setup, motion, server, kind, noise_t, noise_r, hemisphere,
                  spec, end, lost, t0, (coll.tracker_time or t0) - t0)
    from ..io import write_dataset

    write_dataset(ds, args.output)
    cov = _coverage(dws, setup.model, hemisphere, box)
    out = {"path": str(args.output), "n_poses": n, "n_poses_requested": args.n_poses,
           "sensor": setup.name, "source": args.source,
           "reference": args.reference or (str(args.reference_csv) if csv is not None
                                            else server.url),
           "time_offset_ms": dws.time_offset * 1e3,
           "offset_correlation": dws.offset_correlation,
           "dwells": ds.meta["reference"]["dwells"], "coverage": cov,
           "tracker_seconds": (coll.tracker_time or t0) - t0,
           "reference_poses_received": coll.n_reference,
           "ended_by": end, "reference_lost": lost,
           "stopped_by": (None if stopped is None else
                          "SIGTERM" if stopped == signal.SIGTERM else "SIGINT")}
    if server is not None:
        out["simulated"] = ds.meta["truth"]
        out["time_offset_error_ms"] = (dws.time_offset - server.time_offset) * 1e3
    human = [f"collected {n} poses of sensor {setup.name!r} -> {args.output} (time offset "
             f"{dws.time_offset * 1e3:.1f} ms, {dws.tracker_dwells} tracker and "
             f"{dws.reference_dwells} reference dwells; ended by {end})"]
    emit(args, out, human)
    if stopped is not None:
        return 128 + int(stopped)
    return 0


def _dataset(args, dws, n, setup, motion, server, kind, noise_t, noise_r, hemisphere, spec,
             end, lost, t0, seconds):
    from .. import __version__
    from ..io import Dataset

    C = dws.couplings[:n]
    B = dws.reference_poses[:n]
    iv = dws.intervals[:n]
    ref_kind = kind if server is not None else "igtl" if args.reference else "csv"
    dwells = dws.stats()
    dwells["used"] = n
    meta = {
        "generator": "openemt collect",
        "kind": "reference",
        "sensor": setup.name,
        "tracker": None if args.tracker is None else str(args.tracker),
        "reference": {
            "kind": ref_kind,
            "source": args.reference or (str(args.reference_csv) if args.reference_csv
                                         else server.url),
            "noise_trans_m": noise_t,
            "noise_rot_rad": noise_r,
            "hemisphere": hemisphere if isinstance(hemisphere, str) else list(hemisphere),
            "time_offset_s": dws.time_offset,
            "offset_correlation": dws.offset_correlation,
            "dwells": dwells,
            "ended_by": end,
            "reference_lost": lost,
        },
        "units": {"reference_poses": "m", "couplings": "in-phase, as demodulated",
                  "dwell_intervals": "s, tracker clock"},
        "provenance": {"openemt_version": __version__, "simulated": motion is not None},
    }
    extra = {"reference_poses": B, "dwell_intervals": iv,
             "dwell_tracker_samples": dws.n_tracker_samples[:n],
             "dwell_reference_samples": dws.n_reference_samples[:n]}
    poses = None
    if motion is not None:
        poses = motion.sensor_poses(iv.mean(axis=1) - t0)     # the truth at each dwell
        truth = {"X": motion.X.tolist(), "Y": motion.Y.tolist(), "preset":
                 spec.simulation.get("preset", "concentric"),
                 "dwells_true": motion.holds_within(0.0, seconds)}
        if server is not None:
            truth.update(time_offset_s=server.time_offset, latency_s=server.latency,
                         clock_offset_s=server.clock_offset, rate_hz=server.rate)
        meta["truth"] = truth
        meta["preset"] = truth["preset"]      # calibrate's nominal start, as for simulate
    return Dataset(couplings=C, stage=np.zeros((n, 6)), source_fixture="", sensor_fixture="",
                   pattern=ref_kind, file_index=np.zeros(n, dtype=np.int64), files=(ref_kind,),
                   poses=poses, extra=extra, meta=meta)
