"""The collection workflow: :class:`CollectOptions` in, :class:`CollectResult` out."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._errors import InputError
from .._options import option as _f
from .._result import Result

__all__ = ["GIVE_UP_S", "SIM_CLOCK_OFFSET_S", "SIM_LATENCY_S", "SIM_RATE_HZ", "CollectOptions",
           "CollectResult", "collect", "spare_poses"]

#: Seconds of tracker signal after which a reference that is frozen, or whose motion does not
#: match the tracker's well enough to give a time offset, ends the collection (refused).
GIVE_UP_S = 60.0
#: Simulated reference defaults: messages per second, latency and clock offset (s).
SIM_RATE_HZ = 250.0
SIM_LATENCY_S = 0.030
SIM_CLOCK_OFFSET_S = 0.250


@dataclass(frozen=True)
class CollectOptions:
    """What ``openemt collect`` is asked to do (one field per command-line option)."""

    output: Path | None = _f(None, "output dataset (.h5)", flag=("-o", "--output"))
    tracker: Path | None = _f(None, "tracker description file (TOML, docs/live.md#tracker-file) "
                                    "(default: the simulated one-sensor tracker)")
    source: str = _f("sim", "simulated device (default; it follows the simulated robot's motion "
                            "of --seed, or the reference's with --follow-reference), replay of a "
                            "raw HDF5 file, or a sound card", choices=("sim", "replay", "sound"))
    file: Path | None = _f(None, "raw HDF5 recording (with --source replay)", positional=True,
                           optional=True)
    device: str | None = _f(None, "(sound) audio input device: index or name")
    sensor: str | None = _f(None, "name of the tracker file's sensor to collect (default: the "
                                  "first)")
    reference: str | None = _f(None, "receive reference poses as an OpenIGTLink client: "
                                     "TRANSFORM messages of DEVICE (mm, time-stamped by the "
                                     "sender)", metavar="igtl://HOST:PORT/DEVICE")
    reference_csv: Path | None = _f(None, "reference poses with time stamps (columns time in s, "
                                          "x/y/z, an orientation; docs/reference-calibration.md"
                                          "#collecting)", metavar="CSV")
    simulate_reference: str | None = _f(None, "(--source sim) a simulated robot or optical "
                                              "tracker on the same motion, served by an "
                                              "OpenIGTLink server on a free local port",
                                        choices=("robot", "optical"))
    follow_reference: bool = _f(False, "(--source sim) the simulated tracker moves with the "
                                       "poses the reference reports, through the simulated X "
                                       "and Y (P = Y B X^-1), so any reference can be tried "
                                       "without EM hardware")
    n_poses: int = _f(100, "stop after this many dwells are collected (default 100)")
    duration: float | None = _f(None, "stop after this many seconds of tracker signal "
                                      "(default: none)")
    reference_noise_mm: float | None = _f(None, "stated translation noise of one reference "
                                                "pose, 3-D RMS (default: the simulated kind's, "
                                                "robot 0.05, optical 0.25; else not stated)",
                                          metavar="MM")
    reference_noise_deg: float | None = _f(None, "stated rotation noise, RMS angle (default: "
                                                 "robot 0.02, optical 0.1)", metavar="DEG")
    reference_timeout: float = _f(2.0, "seconds without a reference pose after which the "
                                       "reference counts as stopped (default 2)")
    max_offset: float | None = _f(None, "search the time offset within +-this many seconds "
                                        "(default: any offset)")
    sim_rate: float = _f(SIM_RATE_HZ, f"(simulated reference) poses per second (default "
                                      f"{SIM_RATE_HZ:g})")
    sim_latency_ms: float = _f(SIM_LATENCY_S * 1e3, f"(simulated reference) latency of its "
                                                    f"poses (default {SIM_LATENCY_S * 1e3:g} ms)")
    sim_clock_offset_ms: float = _f(SIM_CLOCK_OFFSET_S * 1e3,
                                    f"(simulated reference) its clock minus the tracker's "
                                    f"(default {SIM_CLOCK_OFFSET_S * 1e3:g} ms)")
    sim_stop_after: float | None = _f(None, "(simulated reference) stop serving after S "
                                            "seconds (a reference that goes away)",
                                      metavar="S")
    sim_speed: float = _f(1.0, "(--source sim) simulated seconds per wall-clock second for the "
                               "tracker and the simulated reference alike (default 1: real "
                               "time)")
    seed: int = _f(0, "(--source sim) seed of the simulated motion and noise (default 0)")

    def check(self) -> None:
        """Refuse options that cannot work (:class:`InputError`)."""
        if self.output is None:
            raise InputError("expected -o/--output FILE.h5, got none")
        refs = [self.reference, self.reference_csv, self.simulate_reference]
        if sum(r is not None for r in refs) != 1:
            raise InputError("expected exactly one of --reference, --reference-csv and "
                             "--simulate-reference, got "
                             f"{sum(r is not None for r in refs)}")
        if self.n_poses < 1:
            raise InputError(f"expected --n-poses >= 1, got {self.n_poses}")
        for opt, v in (("--duration", self.duration),
                       ("--reference-timeout", self.reference_timeout),
                       ("--max-offset", self.max_offset), ("--sim-rate", self.sim_rate),
                       ("--sim-stop-after", self.sim_stop_after)):
            if v is not None and not 0 < v < math.inf:
                raise InputError(f"expected a positive, finite {opt}, got {v}")
        if not 0 < self.sim_speed <= 100:
            raise InputError(f"expected --sim-speed in (0, 100], got {self.sim_speed}")
        for opt, v in (("--sim-latency-ms", self.sim_latency_ms),
                       ("--sim-clock-offset-ms", self.sim_clock_offset_ms),
                       ("--reference-noise-mm", self.reference_noise_mm),
                       ("--reference-noise-deg", self.reference_noise_deg)):
            if v is not None and not math.isfinite(v):
                raise InputError(f"expected a finite {opt}, got {v}")
        if self.simulate_reference is not None and self.source != "sim":
            raise InputError(f"expected --simulate-reference only with --source sim (the "
                             f"simulated reference follows the simulated motion), got "
                             f"--source {self.source}")
        if self.follow_reference and (self.source != "sim" or self.reference is None):
            raise InputError("expected --follow-reference with --source sim and --reference "
                             "igtl://... (the simulated tracker follows that reference)")
        if self.source == "replay" and self.file is None:
            raise InputError("expected a raw HDF5 FILE with --source replay, got none")
        if self.source != "replay" and self.file is not None:
            raise InputError(f"expected FILE only with --source replay, got {str(self.file)!r}")
        if self.source == "sound" and self.tracker is None:
            raise InputError("expected --tracker FILE with --source sound, got none")
        if Path(self.output).suffix.lower() not in (".h5", ".hdf5"):
            raise InputError(f"expected -o ending in .h5 or .hdf5, got {str(self.output)!r}")


@dataclass(frozen=True)
class CollectResult(Result):
    """What a collection wrote (``to_dict()`` is ``openemt collect --json``)."""

    path: str
    n_poses: int
    n_poses_requested: int
    sensor: str
    source: str
    reference: str
    time_offset_ms: float
    offset_correlation: float
    offset_confidence: float
    dwells: dict
    pairing: dict
    coverage: dict
    tracker_seconds: float
    wall_seconds: float
    seconds_per_signal_second: float
    reference_poses_received: int
    reference_dropped: dict
    ended_by: str
    reference_lost: str | None
    stopped_by: str | None
    warnings: list
    simulated: dict | None = None
    time_offset_error_ms: float | None = None
    view: dict | None = None

    def _items(self) -> dict:
        items = super()._items()
        if items["view"] is None:           # ``collect --view`` only
            del items["view"]
        return items

    @property
    def exit_code(self) -> int:
        """0, or 128 + the signal that stopped the collection."""
        return {"SIGINT": 130, "SIGTERM": 143}.get(self.stopped_by or "", 0)


def spare_poses(n_poses: int) -> int:
    """Holds of the simulated motion after the ``n_poses`` of ``openemt simulate --reference``,
    for holds that a collection drops."""
    return max(5, int(n_poses) // 4)


class _Coverage:
    """Coverage of the kept dwells, each solved once with the tracker's model."""

    def __init__(self, model, hemisphere, box):
        self.model, self.hemisphere, self.box = model, hemisphere, box
        self.P = np.empty((0, 4, 4))

    def poses(self, dws):
        from ..solve import solve_lm

        k = len(self.P)
        if dws is not None and len(dws) > k:
            res = solve_lm(dws.couplings[k:], self.model, hemisphere=self.hemisphere)
            self.P = np.concatenate([self.P, res.poses])
        return self.P

    def __call__(self, dws, n=None):
        from ..align import coverage

        P = self.poses(dws)[:n]
        B = np.empty((0, 4, 4)) if dws is None else dws.reference_poses[:len(P)]
        return coverage(P[:, :3, 3], B, self.box)


def _setup(o: CollectOptions):
    from ..live import example_tracker, read_tracker, tracker_sensors

    spec = read_tracker(o.tracker if o.tracker is not None else example_tracker("simulated"))
    sensors = tracker_sensors(spec)
    k = 0
    if o.sensor is not None:
        names = [s.name for s in spec.sensors]
        if o.sensor not in names:
            raise InputError(f"expected --sensor to be one of {names}, got {o.sensor!r}")
        k = names.index(o.sensor)
    setup = sensors[k]
    if setup.model is None:
        raise InputError(f"expected a dipole tracker for collect, got the board sensor "
                         f"{setup.name!r}")
    return spec, setup


def collect(options: CollectOptions, *, progress=None, handle_signals: bool = False,
            observer=None) -> CollectResult:
    """Collect a reference-pose dataset (docs/reference-calibration.md#collecting).

    Reads the tracker source and the reference until ``n_poses`` dwells are kept (or the
    duration, the end of either stream, or a signal), then writes exactly the first
    ``n_poses`` (or all there are) to ``options.output``. Refused with :class:`InputError`
    (nothing written): bad options, no dwell, and a reference that does not match the tracker
    (:func:`~openemt.collect.check_pairing`; a time offset that cannot be established).

    Parameters
    ----------
    progress : text stream, optional
        Where progress lines go (none when None).
    handle_signals : bool
        SIGINT / SIGTERM stop the collection, which writes what it has (main thread only).
    observer : optional
        A read-only observer (the live view's :class:`openemt.view.LiveFeed`): ``start``
        with the layout, ``raw`` with every chunk read, ``collect`` with the state after every
        analysis and at the end (:func:`_observed`); references only, nothing flows back.
    """
    from ..calibrate import MIN_REFERENCE_POSES
    from ..live import tracker_backend
    from ..simulate import REFERENCE_KINDS, working_volume
    from ._collector import Collector
    from ._pairing import check_pairing
    from ._refcsv import read_reference_csv
    from ._reference import (
        ReferenceClient,
        SimulatedReferenceServer,
        parse_reference_url,
        simulated_motion,
    )

    o = options
    o.check()
    wall_start = time.perf_counter()
    warnings: list = []

    def say(text):
        if progress is not None:
            print(text, file=progress, flush=True)

    def warn(text):
        warnings.append(text)
        say("warning: " + text)

    spec, setup = _setup(o)
    url = parse_reference_url(o.reference) if o.reference is not None else None
    csv = read_reference_csv(o.reference_csv) if o.reference_csv is not None else None
    kind = o.simulate_reference or "robot"
    stated = REFERENCE_KINDS[kind] if (o.source == "sim" or o.simulate_reference) else None
    noise_t = (o.reference_noise_mm * 1e-3 if o.reference_noise_mm is not None
               else None if stated is None else stated.noise_trans)
    noise_r = (np.deg2rad(o.reference_noise_deg) if o.reference_noise_deg is not None
               else None if stated is None else stated.noise_rot)
    preset = spec.simulation.get("preset", "concentric")
    motion = None
    if o.source == "sim":
        motion = simulated_motion(kind, o.n_poses, spare=spare_poses(o.n_poses), preset=preset,
                                  seed=o.seed, noise_trans=noise_t, noise_rot=noise_r)
    box = motion.box if motion is not None else np.array(working_volume(preset)[:2])
    hemisphere = setup.hemisphere
    if motion is not None and o.tracker is None:
        hemisphere = motion.hemisphere
    if o.n_poses < MIN_REFERENCE_POSES:
        warn(f"--n-poses {o.n_poses} is below the {MIN_REFERENCE_POSES} training poses that "
             f"'openemt calibrate --mode reference' needs")

    from .._compile_notice import announce_compile, dipole_kernels

    # the solver's kernels and its cold start (the solve below), less the check of complex
    # couplings: the pipeline solves real ones
    if progress is not None:
        announce_compile(progress, "solver kernels",
                         kernels=dipole_kernels(cold_start_table=True, complex_couplings=False))
    cover = _Coverage(setup.model, hemisphere, box)
    P = np.eye(4)[None].copy()
    P[0, :3, 3] = [0.25, 0.02, 0.01]          # compile before the streams start
    cover.poses(None)
    from ..solve import solve_lm

    solve_lm(setup.model.coupling(P), setup.model, hemisphere=hemisphere)

    backend = server = client = follower = None
    stopped = lost = None
    end = "n_poses"
    from ..live import StopSignals

    with StopSignals(handle_signals) as stop:
        try:
            if o.follow_reference:
                from ._follow import Follower

                follower = Follower(motion.X, motion.Y, motion.poses[0], speed=o.sim_speed)
                client = ReferenceClient(*url)
                follower.client = client
                backend = tracker_backend(spec, "sim", realtime=False, seed=o.seed,
                                          trajectory=follower.sensor_poses)
            elif motion is not None:
                backend = tracker_backend(spec, "sim", realtime=False, seed=o.seed,
                                          trajectory=motion.sensor_poses)
            else:
                try:
                    backend = tracker_backend(spec, o.source, file=o.file, device=o.device,
                                              realtime=o.source == "replay" and csv is None,
                                              match_layout=o.tracker is not None)
                except ImportError as exc:
                    raise InputError(str(exc)) from None
            t0 = backend.t0_epoch
            if o.simulate_reference is not None:
                server = SimulatedReferenceServer(
                    motion, t0=t0, rate=o.sim_rate, latency=o.sim_latency_ms * 1e-3,
                    clock_offset=o.sim_clock_offset_ms * 1e-3, speed=o.sim_speed,
                    seed=o.seed, stop_after=o.sim_stop_after)
                say(f"simulated {kind} reference: OpenIGTLink TRANSFORM on {server.url} "
                    f"({o.sim_rate:g} Hz, latency {o.sim_latency_ms:g} ms, clock offset "
                    f"{o.sim_clock_offset_ms:g} ms)")
                url = ("127.0.0.1", server.port, server.device)
            if url is not None and client is None:
                client = ReferenceClient(*url)
            coll = Collector(backend.layout, setup.columns, output_rate=spec.output_rate,
                             window=spec.window, t0=t0, max_offset=o.max_offset,
                             reference_complete=csv is not None)
            if csv is not None:
                coll.add_reference(*csv)
            if observer is not None:
                observer.start(backend.layout)
            paced = o.source == "sim" and client is not None
            say(f"collecting {o.n_poses} poses of sensor {setup.name!r} from --source "
                f"{o.source}; Ctrl-C to stop and write what is collected")
            wall0 = time.time()
            analysed = shown = time.monotonic()
            period = 1.0 if progress is not None and progress.isatty() else 5.0
            while True:
                if stop.signal is not None:
                    stopped, end = stop.signal, "signal"
                    break
                chunk = backend.read()
                if chunk is None:
                    end = "end of source"
                    break
                coll.add_chunk(chunk)
                if observer is not None and len(chunk):
                    observer.raw(chunk)             # a reference: never written again
                tau = (coll.tracker_time or t0) - t0
                if paced:                       # the simulated world runs at --sim-speed
                    delay = t0 + tau / o.sim_speed - time.time()
                    if delay > 0:
                        time.sleep(delay)
                if client is not None and follower is None:
                    coll.add_reference(*client.take())
                if client is not None:
                    lost = _lost(client, wall0, o.reference_timeout)
                    if lost is not None:
                        end = "reference lost"
                        break
                if o.duration is not None and tau >= o.duration:
                    end = "duration"
                    break
                if time.monotonic() - analysed >= 1.0:
                    analysed = time.monotonic()
                    if follower is not None:
                        coll.add_reference(*follower.take())
                    coll.update()
                    if observer is not None:
                        _observed(observer, coll, cover, o, box, setup.name, tau,
                                  MIN_REFERENCE_POSES)
                    if coll.n_dwells >= o.n_poses:
                        break
                    if tau >= GIVE_UP_S and (coll.reference_frozen() or not coll.locked):
                        end = "reference does not match"       # refused below
                        break
                    if time.monotonic() - shown >= period:
                        shown = time.monotonic()
                        say(_status(tau, coll, o.n_poses, cover, MIN_REFERENCE_POSES))
                    if csv is not None and coll.offset is not None and coll.locked and \
                            coll.tracker_time + coll.offset.offset > csv[0][-1] + 1.0:
                        end = "end of reference CSV"
                        break
            if follower is not None:
                follower.pull()
            if client is not None:
                coll.add_reference(*(follower or client).take())
        finally:
            for part in (server, client, backend):    # the server first: no reset
                if part is not None:
                    part.close()
    if lost is not None:
        warn(f"the reference {o.reference or server.url} stopped: {lost}; writing the poses "
             f"collected so far")
    coll.update(final=True)
    dropped = dict(csv.drops.to_dict() if csv is not None else
                   client.drops.to_dict() if client is not None else {})
    if coll.n_reference_out_of_order:
        dropped["time_not_increasing"] = (dropped.get("time_not_increasing", 0)
                                          + coll.n_reference_out_of_order)
    dws = coll.result()
    tracker_seconds = (coll.tracker_time or t0) - t0
    _refuse_mismatch(coll, dws, dropped)
    n = min(len(dws), o.n_poses)
    A = cover.poses(dws)[:n]
    pairing = check_pairing(A, dws.reference_poses[:n],
                            rotations=getattr(setup.model, "n_sensor", 3) >= 3)
    if n < MIN_REFERENCE_POSES:
        warn(f"{n} poses collected, below the {MIN_REFERENCE_POSES} training poses that "
             f"'openemt calibrate --mode reference' needs")
    if observer is not None:
        _observed(observer, coll, cover, o, box, setup.name, tracker_seconds,
                  MIN_REFERENCE_POSES, n=n, ended_by=end)
    ds = _dataset(o, dws, n, setup, motion, server, kind, noise_t, noise_r, hemisphere,
                  spec, end, lost, t0, tracker_seconds, pairing, dropped)
    from ..io import write_dataset

    write_dataset(ds, o.output)
    wall = time.perf_counter() - wall_start
    e = coll.offset
    names = {2: "SIGINT", 15: "SIGTERM"}
    return CollectResult(
        path=str(o.output), n_poses=n, n_poses_requested=o.n_poses, sensor=setup.name,
        source=o.source,
        reference=o.reference or (str(o.reference_csv) if csv is not None else server.url),
        time_offset_ms=e.offset * 1e3, offset_correlation=e.correlation,
        offset_confidence=e.confidence, dwells=ds.meta["reference"]["dwells"],
        pairing=pairing, coverage=cover(dws, n), tracker_seconds=tracker_seconds,
        wall_seconds=wall,
        seconds_per_signal_second=wall / tracker_seconds if tracker_seconds > 0 else math.inf,
        reference_poses_received=coll.n_reference, reference_dropped=dropped, ended_by=end,
        reference_lost=lost,
        stopped_by=None if stopped is None else names.get(int(stopped), str(stopped)),
        warnings=warnings, simulated=ds.meta.get("truth") if server is not None else None,
        time_offset_error_ms=((e.offset - server.time_offset) * 1e3 if server is not None
                              else None))


def _observed(observer, coll, cover, o, box, sensor, tau, min_poses, *, n=None,
              ended_by=None) -> None:
    """Hand ``observer`` the collection's state: the dwells kept (the first ``n`` at the end,
    those written), their tracker poses (solved once each, as the coverage line does) and
    reference poses, the counts and the working volume."""
    dws = coll.result()
    P = cover.poses(dws)[:n]
    B = np.empty((0, 4, 4)) if dws is None else dws.reference_poses[:len(P)]
    e = coll.offset
    observer.collect({"n_dwells": 0 if dws is None else len(dws), "n_target": o.n_poses,
                      "n_min": min_poses, "poses": P, "reference_poses": B, "box": box,
                      "tracker_seconds": tau, "locked": coll.locked, "sensor": sensor,
                      "time_offset_ms": None if e is None else e.offset * 1e3,
                      "ended_by": ended_by})


def _lost(client, wall0, timeout) -> str | None:
    now = time.time()
    if client.error is not None or client.closed:
        return client.error or f"the server closed the connection after {client.n_messages} poses"
    if client.gate.jumped is not None:
        return (f"its clock jumped by {client.gate.jumped:.6g} s after {client.n_messages} "
                f"poses")
    if client.last_receipt is None:
        if now - wall0 > client.connect_timeout + timeout:
            return f"no pose of device {client.device!r} in {now - wall0:.1f} s"
    elif now - client.last_receipt > timeout:
        return f"no pose for {now - client.last_receipt:.1f} s after {client.n_messages} poses"
    return None


def _status(tau, coll, n_poses, cover, min_poses) -> str:
    if coll.offset is None:
        return f"collect {tau:.1f} s: waiting for both streams"
    dws = coll.result()
    cov = cover(dws)
    div = "ok" if cov["rotation_diversity_ok"] else "NOT yet (rotate about another axis)"
    spread = cov["orientation_spread_deg"]
    few = (f" (below the {min_poses} that calibrate --mode reference needs)"
           if len(dws) < min_poses else "")
    sync = ("" if coll.locked else " not yet sure,")
    return (f"collect {tau:.1f} s: {len(dws)}/{n_poses} poses{few}, time offset{sync} "
            f"{coll.offset.offset * 1e3:.1f} ms (r={coll.offset.correlation:.2f}), coverage "
            f"{cov['volume_coverage_pct']:.0f} % of the working volume, orientation spread "
            f"{0.0 if spread is None else spread:.1f} deg, rotation diversity {div}")


def _refuse_mismatch(coll, dws, dropped) -> None:
    """InputError (nothing written) when the two streams cannot be paired."""
    from ._collector import MIN_CONFIDENCE, MIN_CORRELATION, MIN_OVERLAP_S

    drops = f" (reference poses dropped: {dropped})" if dropped else ""
    if coll.n_reference == 0:
        raise InputError(f"expected reference poses, got no reference pose{drops}; nothing "
                         f"written")
    if coll.reference_frozen():
        raise InputError(f"expected a reference that moves with the tracker, got a frozen one "
                         f"(static over {coll.reference_span():.1f} s while the tracker moved)"
                         f"{drops}; nothing written")
    e = coll.offset
    if e is None:
        raise InputError(f"expected at least a second of both streams, got less{drops}; nothing "
                         f"written")
    if not coll.locked:
        raise InputError(
            f"expected the tracker's and the reference's motion to match (a time-offset "
            f"correlation of at least {MIN_CORRELATION:g} with a confidence of at least "
            f"{MIN_CONFIDENCE:g} over at least {MIN_OVERLAP_S:g} s of overlap), got correlation "
            f"{e.correlation:.2f}, confidence {e.confidence:.2f} over {e.overlap_s:.1f} s: a "
            f"reference of another motion, in another unit, or too short{drops}; nothing "
            f"written")
    if not len(dws):
        raise InputError(f"expected at least one dwell where the tracker and the reference were "
                         f"both static, got none ({dws.tracker_dwells} static intervals in the "
                         f"tracker stream, {dws.reference_dwells} in the reference stream); "
                         f"nothing written")


def _dataset(o, dws, n, setup, motion, server, kind, noise_t, noise_r, hemisphere, spec,
             end, lost, t0, seconds, pairing, dropped):
    from .. import __version__
    from ..io import Dataset

    C = dws.couplings[:n]
    B = dws.reference_poses[:n]
    iv = dws.intervals[:n]
    ref_kind = kind if server is not None else "igtl" if o.reference else "csv"
    dwells = dws.stats()
    dwells["used"] = n
    meta = {
        "generator": "openemt collect",
        "kind": "reference",
        "sensor": setup.name,
        "tracker": None if o.tracker is None else str(o.tracker),
        "reference": {
            "kind": ref_kind,
            "source": o.reference or (str(o.reference_csv) if o.reference_csv
                                      else server.url),
            "noise_trans_m": noise_t,
            "noise_rot_rad": noise_r,
            "hemisphere": hemisphere if isinstance(hemisphere, str) else list(hemisphere),
            "time_offset_s": dws.time_offset,
            "offset_correlation": dws.offset_correlation,
            "dwells": dwells,
            "pairing": pairing,
            "dropped": dropped,
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
    if motion is not None and not o.follow_reference:
        poses = motion.sensor_poses(iv.mean(axis=1) - t0)     # the truth at each dwell
        truth = {"X": motion.X.tolist(), "Y": motion.Y.tolist(), "preset":
                 spec.simulation.get("preset", "concentric"),
                 "dwells_true": motion.holds_within(0.0, seconds)}
        if server is not None:
            truth.update(time_offset_s=server.time_offset, latency_s=server.latency,
                         clock_offset_s=server.clock_offset, rate_hz=server.rate)
        meta["truth"] = truth
        meta["preset"] = truth["preset"]      # calibrate's nominal start, as for simulate
    elif motion is not None:
        meta["preset"] = spec.simulation.get("preset", "concentric")
        meta["truth"] = {"X": motion.X.tolist(), "Y": motion.Y.tolist(),
                         "preset": meta["preset"], "followed": o.reference}
    return Dataset(couplings=C, stage=np.zeros((n, 6)), source_fixture="", sensor_fixture="",
                   pattern=ref_kind, file_index=np.zeros(n, dtype=np.int64), files=(ref_kind,),
                   poses=poses, extra=extra, meta=meta)

