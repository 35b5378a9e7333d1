"""``openemt bench track``: live latency and position noise against the Cramer-Rao bound.

Keys
----
latency_ms_p50, latency_ms_p99
    Per sample, from the moment its demodulated coupling is available to the end of the
    socket send of its OpenIGTLink TRANSFORM to a real pyigtl client on loopback (in a
    separate process, as a viewer would be). The
    simulated device is paced at the sample rate (1500 samples/s out) and delivers ``--chunk``
    samples per read (default 640 = 10 frames = 6.7 ms, an audio-interface block, as
    ``openemt track`` uses); the samples of a block are solved together and sent one by one.
    Its raw samples are simulated before the run (``SimulatedBackend.simulate_ahead``), as a
    device's samples exist before they are read: simulated during the run, in blocks of
    0.1 s in the reading thread, they were a burst of CPU every 15th block, after which the
    woken viewer process took the core in the middle of the next send (on the 2-core
    development machine that burst, not the pipeline, set the p99).
    Target p99 < 2 ms. ``pipeline_latency_ms_*`` stop at the hand-over to the sender.
    With ``--pin`` the latency runs keep this process on one CPU and the viewer on another
    (``pinned`` names them; null without): a tracker with a core of its own, as a real-time
    set-up would give it. Without it the scheduler may run the viewer, woken by a send, on
    the sender's core; on the 2-core development machine that, not the pipeline, sets the
    4-sensor p99.
    ``one_frame_reads`` repeats the measurement with one frame (64 samples) per read, the
    per-call overheads then add up to about one CPU core at 1500 samples/s.
    Tail latencies depend on the machine's load: ``load_average`` and ``cpu_count`` are
    reported alongside, and ``kept_up_with_real_time`` says whether the pipeline kept pace.
position_noise_um
    3-D rms scatter (``sqrt(trace(cov))``) of the tracked position of a static sensor at
    200 mm, default simulated noise, through the whole chain (raw samples -> demodulation ->
    LM), over ``--noise-seconds``.
crb_position_noise_um
    The Cramer-Rao bound of the same quantity, ``sqrt(trace(CRB_xyz))``, for the coupling-noise
    covariance *measured* on the demodulated couplings of that run
    (:func:`openemt.solve.cramer_rao`). ``noise_to_crb_ratio`` should be within 1 +/- 0.2.
    ``crb_position_noise_um_from_spec`` is the bound from the simulator's noise setting alone
    (white sensor noise through the Hann frame, reference noise neglected).
sensors
    ``--sensors K`` tracks K tri-axial sensors on one source (3K + 3 channels, each sensor
    its own OpenIGTLink device; the latency runs and ``realtime_factor`` use all K). The
    latency of a sample is then counted per sensor message.
realtime_factor
    Seconds of signal processed per second of wall time for the K sensors, as fast as
    possible (raw samples simulated beforehand, in 640-sample chunks; demodulation, K solves,
    no OpenIGTLink client). Target >= 20 for 4 sensors. ``realtime_factor_cpu`` divides by
    the process CPU time instead (less sensitive to other load). ``realtime_baseline``: the
    same with one solver call per sensor (sensors with their own calibration files), and
    ``realtime_speedup_vs_baseline_cpu`` (sensors sharing a calibration are solved in one
    batched call).
igtl_pack_us_per_message
    CPU time to pack a TRANSFORM message in blocks of 10 with the compiled packer, against
    ``igtl_pack_us_per_message_pyigtl`` (pyigtl, one message at a time; same bytes).
filter
    The constant-velocity Kalman filter (docs/live.md#filter, default noises) on the same
    demodulated poses: ``position_noise_um`` without and with it for the static sensor
    (``noise_reduction`` = with / without), and for a stated motion -- a 10 mm, 2 Hz sine
    along y at 200 mm -- the ``added_lag_ms`` (phase lag of the fitted 2 Hz component,
    filtered minus unfiltered) and the rms error to the truth without and with the filter;
    ``step_settle_ms`` is the time after a 1 mm position step until the output stays within
    1 % of it (``step_overshoot``: largest excess, as a fraction of the step).
many_tools
    ``--tools K`` simulated tri-axial sensors (default 4) tracked in real time for
    ``--tools-seconds`` and served to a pyigtl client in another process that counts every
    message it decodes, three ways: one TRANSFORM per sensor and sample with the version-2
    metadata (``transform``, the default stream), the same without metadata
    (``transform_v1``), and one TDATA message per sample holding all K tools (``tdata``;
    the client is given a TDATA message class, pyigtl has none). Per way:
    ``messages_per_s`` (decoded by the client per second of signal), ``frame_rate_hz`` (whole
    samples of all K tools received per second: the slowest tool's TRANSFORM rate, or the
    TDATA rate), ``messages_skipped`` (shed by the server for the client), ``bytes_per_s``,
    ``kept_up_with_real_time`` and ``pack_us_per_sample`` (CPU time to pack the K tools of one
    sample: ``pack_transforms`` K times with and without metadata, ``pack_tdata`` once).
without_metadata
    ``latency_ms_p50`` / ``latency_ms_p99`` of the first run again with version-1 TRANSFORMs
    (no per-message metadata): what the metadata costs, in the same run. On the 2-core
    development machine most of it is the viewer's decoding (a pyigtl client in another
    process) competing for the cores.
realtime_factor_with_view, view
    With ``--view``: the realtime factor with the live view open in headless Chromium
    (``openemt track --view``) against the same runs without publishing to it, alternating,
    in this process (:mod:`openemt.bench._view`; ``view.ratio`` target >= 0.9).
latency_end_to_end_ms
    ``p50`` / ``p99`` / ``max`` of the first run, per sample: from its acquisition time (the
    centre of its demodulation frame on the sample clock, UTC) to the return of the
    OpenIGTLink send (docs/live.md#time). It includes the half frame (0.67 ms at 1500/s with
    the Hann window), the wait for the rest of the ``--chunk`` read and the processing.
acquisition
    The framed ADC stream of ``openemt track --source serial:...`` / ``tcp://...``
    (docs/live.md#serial-and-network-acquisition) from the reference emitter
    (:mod:`openemt.live.emitter`) in a thread of this process, ``--acquire-seconds`` of signal
    each (0 skips it): ``sim`` (``--source sim``), ``serial`` (through a real pseudo-terminal
    pair, opened with pyserial) and ``tcp`` (loopback) as fast as possible, each with its
    ``position_error_mm_rms`` against the simulated truth and ``n_samples``;
    ``serial.max_pose_difference_m`` against the ``sim`` poses of the same samples;
    ``damaged`` through the pty with one bit flipped in every 29th frame, bytes dropped from
    every 41st and every 53rd frame left out: the emitter's damaged and left-out frames, the
    link counters (CRC errors, gaps, samples lost), the demodulator restarts and the position
    error (a window bridging a gap would give millimetres); ``paced``: the emitter at the
    sample clock over TCP, the acquisition time of every pose of the last second against the
    emitter's true sample time (``acquisition_time_error_ms`` max and rms, also at the top
    level), the fitted clock drift, and that run's end-to-end latency.
baseline
    ``one_frame_reads`` with the solver unprepared: :func:`openemt.solve.solve_lm` called on
    every read, checking and packing the model and options each time, as the pipeline did
    before it prepared its solver once (``openemt.live.lm_solver``, a
    :class:`~openemt.solve._prepared.PreparedLM`; same poses), and with several sensors one
    call per sensor (no batching of sensors that share a calibration). With one frame per
    read these per-call costs matter most; ``one_frame_reads`` reports
    ``p99_speedup_vs_baseline``.
"""

from __future__ import annotations

import contextlib
import functools
import os
import time

import numpy as np

from .._constants import OUTPUT_RATE_HZ
from .._errors import InputError
from ._timing import best_time, cpu_us_per_item

__all__ = ["add_arguments", "run"]


def add_arguments(parser) -> None:
    parser.add_argument("--seconds", type=float, default=3.0,
                        help="seconds of real-time tracking for the latency test (default 3)")
    parser.add_argument("--noise-seconds", type=float, default=2.0,
                        help="seconds of a static sensor for the noise test (default 2)")
    parser.add_argument("--chunk", type=int, default=640,
                        help="samples per device read in the latency test (default 640 = 10 "
                             "frames)")
    parser.add_argument("--preset", default="concentric", help="simulated tracker")
    parser.add_argument("--sensors", type=int, default=1,
                        help="tri-axial sensors tracked at once (default 1)")
    parser.add_argument("--rate-seconds", type=float, default=2.0,
                        help="seconds of signal for the realtime factor (default 2)")
    parser.add_argument("--tools", type=int, default=4,
                        help="sensors streamed for the many-tools rate test (default 4)")
    parser.add_argument("--tools-seconds", type=float, default=3.0,
                        help="seconds of real-time streaming per way in the many-tools test "
                             "(default 3; 0 skips it)")
    parser.add_argument("--view", action="store_true",
                        help="also measure the realtime factor with the live view open in "
                             "headless Chromium (realtime_factor_with_view, view)")
    parser.add_argument("--view-seconds", type=float, default=30.0,
                        help="seconds of signal per run of the view measurement (default 30)")
    parser.add_argument("--acquire-seconds", type=float, default=2.0,
                        help="seconds of signal per run of the serial / TCP acquisition test "
                             "(default 2; 0 skips it)")
    parser.add_argument("--pin", action="store_true",
                        help="latency runs with this process on one CPU and the viewer on "
                             "another (Linux, 2 CPUs or more): a tracker with a core of its "
                             "own; the JSON says so (pinned)")
    parser.add_argument("--seed", type=int, default=0)


# The viewer: a pyigtl client in its own process (as 3D Slicer would be), so that its polling
# thread does not compete with the pipeline for this interpreter.
# a client that reads version-2 messages says so with a version-2 message (here GET_STATUS)
_HELLO = """
class Hello(pyigtl.messages.MessageBase):
    def __init__(self):
        super().__init__(device_name="bench")
        self._message_type, self._valid_message, self.header_version = "GET_STATUS", True, 2
c.send_message(Hello(), wait=False)
"""

_CLIENT = """
import sys, time, pyigtl
c = pyigtl.OpenIGTLinkClient(host="127.0.0.1", port=int(sys.argv[1]))
""" + _HELLO + """
end, seen = time.time() + float(sys.argv[2]), 0
names = sys.argv[3].split(",")
while time.time() < end:
    for name in names:
        if c.wait_for_message(name, timeout=0.05 / len(names)) is not None:
            seen += 1
c.stop()
print(seen, flush=True)
"""


def _spec(preset, k: int):
    """A simulated tracker with ``k`` tri-axial sensors (devices S0, S1, ...) on one source:
    sensor j on channels 3j..3j+2, references after them, 20 mm apart along x."""
    from ..live import tracker_from_dict
    from ..simulate import get_preset

    p = get_preset(preset)
    if (p.n_source, p.n_sensor) != (3, 3):
        raise InputError(f"expected a tri-axial preset, got {preset!r}")
    if not 1 <= k <= 16:
        raise InputError(f"expected --sensors in 1..16, got {k}")
    doc = {"format": "openemt-tracker", "version": 1,
           "adc": {"sample_rate": 96000.0, "channels": 3 * k + 3},
           "source": {"frequencies": list(p.frequencies),
                      "reference_channels": [3 * k, 3 * k + 1, 3 * k + 2]},
           "sensors": [{"name": f"S{j}", "channels": [3 * j, 3 * j + 1, 3 * j + 2],
                        "simulation_offset": [0.02 * j, 0.0, 0.0]} for j in range(k)],
           "simulation": {"preset": p.name}}
    return tracker_from_dict(doc)


def _unprepared(setup):
    """``setup`` with the default solver unprepared: ``solve_lm`` on every call."""
    from dataclasses import replace

    from ..solve import solve_lm

    def solve(C, initial, model=setup.model, hemisphere=setup.hemisphere):
        return solve_lm(C, model, initial=initial, hemisphere=hemisphere)

    return replace(setup, solver=solve)


def _session(spec, seconds, seed, *, chunk=640, sensors=None, max_queue=None, **options):
    """The tracking session of ``openemt track`` for ``spec`` (simulated, real time, an
    OpenIGTLink server on a free port), as the command assembles it."""
    from ..live import TrackingSession, TrackOptions

    opts = TrackOptions(duration=seconds, seed=seed, igtl_port=0, quiet=True, **options)
    return TrackingSession(spec, opts, sensors=sensors, chunk=chunk, max_queue=max_queue)


def _run_with_client(session):
    """Run ``session`` once its loopback client has connected and announced version 2 (the
    clock restarted then): ``(summary, wall seconds)``."""
    if not session.server.wait_for_client(30.0, header_version=2):
        raise OSError("expected a loopback OpenIGTLink client to connect and announce header "
                      "version 2, got none in 30 s")
    session.backend.restart_clock()
    _, wall, s = best_time(lambda: session.run().summary, 1)
    return s, wall


@contextlib.contextmanager
def _pinned(pin: bool):
    """With ``pin``: this process on its first allowed CPU for the block (the threads and
    processes started in it inherit that; :func:`_latency_run` moves the viewer), yielding
    ``{"tracker_cpu", "viewer_cpu"}``; the CPUs it was allowed restored after. Without:
    None."""
    if not pin:
        yield None
        return
    cpus = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    if len(cpus) < 2:
        raise InputError(f"expected 2 CPUs or more for --pin (Linux), got {len(cpus)}")
    os.sched_setaffinity(0, {cpus[0]})
    try:
        yield {"tracker_cpu": cpus[0], "viewer_cpu": cpus[1]}
    finally:
        os.sched_setaffinity(0, set(cpus))


def _latency_run(spec, seconds, chunk, seed, prepared=True, metadata=True, viewer_cpu=None):
    import subprocess
    import sys

    from ..live import tracker_sensors

    names = [st.device for st in spec.streams()]
    sensors = None if prepared else [_unprepared(st) for st in tracker_sensors(spec)]
    with _session(spec, seconds, seed, chunk=chunk, sensors=sensors, max_queue=64,
                  metadata=metadata) as session:
        # the device's samples exist before they are read (session.backend: the simulator
        # itself, the session's wrappers are around it in session.source)
        session.backend.simulate_ahead()
        srv = session.server
        client = subprocess.Popen([sys.executable, "-c", _CLIENT, str(srv.port),
                                   str(seconds * 20 + 30), ",".join(names)],
                                  stdout=subprocess.DEVNULL)
        try:
            if viewer_cpu is not None:
                os.sched_setaffinity(client.pid, {viewer_cpu})
            s, wall = _run_with_client(session)
            time.sleep(0.05)
        finally:
            client.terminate()
            try:
                client.wait(timeout=5.0)
            except subprocess.TimeoutExpired:  # pragma: no cover
                client.kill()
                client.wait(timeout=5.0)
    send = srv.latencies() * 1e3
    return s, send, wall, srv.stats()


def run(args) -> dict:
    from ..geometry import pose_from_vector
    from ..live import SimulatedBackend, TrackingPipeline, TrackLog
    from ..signal import RawSignalConfig, frame_window
    from ..simulate import get_preset
    from ..solve import cramer_rao

    model = get_preset(args.preset).dipole
    seconds = float(args.seconds)
    if not seconds > 0 or not args.noise_seconds > 0 or not args.rate_seconds > 0:
        raise InputError(f"expected positive --seconds, --noise-seconds and --rate-seconds, "
                         f"got {seconds}, {args.noise_seconds} and {args.rate_seconds}")
    spec = _spec(args.preset, int(args.sensors))

    with _pinned(args.pin) as pinned:
        run_ = functools.partial(_latency_run, spec, seed=args.seed,
                                 viewer_cpu=None if pinned is None else pinned["viewer_cpu"])
        # compile / load every numba kernel the pipeline uses before anything is timed
        run_(0.05, args.chunk)
        s, send, wall, stats = run_(seconds, args.chunk)
        s1, send1, wall1, _ = run_(min(seconds, 1.0), 64)
        _, sendb, _, _ = run_(min(seconds, 1.0), 64, prepared=False)
        _, sendv1, _, _ = run_(seconds, args.chunk, metadata=False)

    def pct(a, q):
        return float(np.percentile(a, q)) if len(a) else None

    out = {
        "preset": args.preset, "sensors": int(args.sensors), "output_rate": OUTPUT_RATE_HZ,
        "chunk_samples": args.chunk,
        "latency_ms_p50": pct(send, 50), "latency_ms_p99": pct(send, 99),
        "latency_ms_max": pct(send, 100), "latency_samples": len(send),
        "latency_target_p99_ms": 2.0, "pinned": pinned,
        "pipeline_latency_ms_p50": s.latency_ms_p50, "pipeline_latency_ms_p99": s.latency_ms_p99,
        "signal_seconds": s.signal_seconds, "wall_seconds": wall,
        "kept_up_with_real_time": bool(wall <= 1.05 * s.signal_seconds + 0.05),
        "igtl": stats, "status_counts": s.status_counts,
        "tracking_error_mm_rms": (s.truth or {}).get("position_error_mm_rms"),
        "baseline": {"what": "one frame per read, the solver unprepared (solve_lm with its "
                             "checks and packing on every call, one call per sensor)",
                     "latency_ms_p50": pct(sendb, 50), "latency_ms_p99": pct(sendb, 99)},
        "without_metadata": {
            "what": "the first run's blocks sent as version-1 TRANSFORMs, without the "
                    "TransformStatus, TransformValid, RelativeResidual, QuadratureRatio and "
                    "DistortionLevel metadata (openemt track --no-metadata)",
            "latency_ms_p50": pct(sendv1, 50), "latency_ms_p99": pct(sendv1, 99)},
        "one_frame_reads": {
            "chunk_samples": 64, "latency_ms_p50": pct(send1, 50),
            "latency_ms_p99": pct(send1, 99),
            "kept_up_with_real_time": bool(wall1 <= 1.05 * s1.signal_seconds + 0.05),
            "wall_seconds": wall1, "signal_seconds": s1.signal_seconds,
            "p99_speedup_vs_baseline": (pct(sendb, 99) / pct(send1, 99)
                                        if len(send1) and len(sendb) else None)},
        "load_average": list(os.getloadavg()), "cpu_count": os.cpu_count(),
    }
    acq = s.extra.get("acquisition") or {}
    out["latency_end_to_end_ms"] = {k: acq.get(f"latency_ms_{k}") for k in ("p50", "p99", "max")}
    out.update(_realtime_factor(spec, float(args.rate_seconds), args.chunk, args.seed))
    if args.view:                           # the live view's cost (openemt.bench._view)
        from ._view import view_cost

        raw, layout = _raw(spec, float(args.rate_seconds), args.seed)
        out["view"] = view_cost(spec, raw, layout, chunk=args.chunk,
                                seconds=float(args.view_seconds))
        out["realtime_factor_with_view"] = out["view"]["realtime_factor_with_view"]

    # --- noise of a static sensor at 200 mm vs the Cramer-Rao bound
    pose = pose_from_vector(np.array([0.2, 0.0, 0.0, 0.1, -0.2, 0.3]))
    cfg = RawSignalConfig()
    backend = SimulatedBackend(model, pose, cfg, seed=args.seed + 1,
                               duration=float(args.noise_seconds), chunk=64 * 150)
    log = TrackLog()
    summ = TrackingPipeline(backend, model, log=log).run()
    a = log.arrays()
    ok = a["status"] == 0
    xyz = a["poses"][ok, :3, 3]
    cov_xyz = np.cov(xyz.T)
    C = a["couplings"][ok].real.reshape(int(ok.sum()), -1)
    cov_c = np.cov(C.T)
    crb = cramer_rao(model, pose[None], cov_c)[0]
    # the same bound from the simulator's noise specification alone (white sensor noise,
    # Hann frame, 1 A drive, 1 V per coupling unit; the 10x smaller reference noise ignored)
    w = frame_window("hann", 128)
    sigma_spec = cfg.noise_rms * np.sqrt(2 * np.sum(w ** 2)) / np.sum(w) / (
        cfg.drive_amplitude * cfg.layout.sensor_gain)
    crb_spec = cramer_rao(model, pose[None], sigma_spec)[0]
    noise_um = 1e6 * float(np.sqrt(np.trace(cov_xyz)))
    crb_um = 1e6 * float(np.sqrt(np.trace(crb[:3, :3])))
    out.update({
        "position_noise_um": noise_um,
        "crb_position_noise_um": crb_um,
        "crb_position_noise_um_from_spec": 1e6 * float(np.sqrt(np.trace(crb_spec[:3, :3]))),
        "noise_to_crb_ratio": noise_um / crb_um,
        "position_noise_um_per_axis": (1e6 * np.sqrt(np.diag(cov_xyz))).tolist(),
        "crb_position_noise_um_per_axis": (1e6 * np.sqrt(np.diag(crb[:3, :3]))).tolist(),
        "noise_pose_mm": [200.0, 0.0, 0.0],
        "noise_samples": int(ok.sum()),
        "noise_status_counts": summ.status_counts,
        "sensor_noise_v_rms": cfg.noise_rms,
        "coupling_noise_rms_measured": float(np.sqrt(np.mean(np.diag(cov_c)))),
        "coupling_magnitude_max": float(np.abs(model.coupling(pose[None])).max()),
    })
    out["filter"] = _filter_report(model, a, ok, noise_um, args.seed)
    if args.tools_seconds > 0:
        out["many_tools"] = _many_tools(args.preset, int(args.tools),
                                        float(args.tools_seconds), args.seed)
    if args.acquire_seconds > 0:
        out["acquisition"] = _acquisition(float(args.acquire_seconds), args.seed)
        out["acquisition_time_error_ms"] = out["acquisition"]["paced"][
            "acquisition_time_error_ms"]
    out["load_average_end"] = list(os.getloadavg())
    return out


def _acquisition(seconds: float, seed: int) -> dict:
    """The framed serial / TCP paths against the simulator (module docstring,
    ``acquisition``)."""
    import tempfile
    from pathlib import Path

    from ..live import (
        SerialBackend,
        TcpBackend,
        TrackingSession,
        TrackOptions,
        read_track_log,
    )
    from ..live.emitter import Emitter, EmitterThread, open_pty

    def track(backend, thread, dur, **opts):
        o = TrackOptions(igtl=False, quiet=True, duration=dur, stall_timeout=30, **opts)
        with TrackingSession.from_tracker(None, o, backend=backend) as session, thread:
            r = session.run()
            restarts = session.pipeline.demod_restarts
        return r, restarts

    def err(r):
        return (r.summary.truth or {}).get("position_error_mm_rms")

    out: dict = {"seconds": seconds}
    with tempfile.TemporaryDirectory() as tmp:
        logs = {k: Path(tmp) / f"{k}.h5" for k in ("sim", "serial", "paced")}
        o = TrackOptions(igtl=False, quiet=True, duration=seconds, fast=True, seed=seed,
                         log=logs["sim"])
        with TrackingSession.from_tracker(None, o) as session:
            r = session.run()
        out["sim"] = {"position_error_mm_rms": err(r), "n_samples": r.summary.n_samples}
        em = Emitter(realtime=False, duration=seconds + 0.2, seed=seed)
        master, slave, path = open_pty()
        try:
            b = SerialBackend(path, em.spec.layout(), em.n_channels, truth=em.truth_poses,
                              drain=False)
            r, _ = track(b, EmitterThread([em], master), seconds, seed=seed,
                         log=logs["serial"])
            a, z = (read_track_log(logs[k]).arrays["openemt"] for k in ("serial", "sim"))
            n = min(len(a["times"]), len(z["times"]))
            out["serial"] = {"position_error_mm_rms": err(r), "n_samples": r.summary.n_samples,
                             "max_pose_difference_m": float(np.abs(
                                 a["pose_vectors"][:n, :3] - z["pose_vectors"][:n, :3]).max()),
                             "link": r.to_dict()["link"]}
            em = Emitter(realtime=False, duration=seconds + 0.5, seed=seed, flip_every=29,
                         drop_every=41, skip_every=53)
            b = SerialBackend(path, em.spec.layout(), em.n_channels, truth=em.truth_poses,
                              drain=False)
            r, restarts = track(b, EmitterThread([em], master), seconds, seed=seed)
            out["damaged"] = {"frames_damaged": em.damaged, "frames_left_out": em.skipped,
                              "link": r.to_dict()["link"], "demodulator_restarts": restarts,
                              "position_error_mm_rms": err(r),
                              "position_error_mm_max": (r.summary.truth or {}).get(
                                  "position_error_mm_max")}
        finally:
            os.close(master)
            os.close(slave)
        em = Emitter(realtime=False, duration=seconds + 0.2, seed=seed)
        et = EmitterThread([em])
        b = TcpBackend("127.0.0.1", et.port, em.spec.layout(), em.n_channels,
                       truth=em.truth_poses, drain=False)
        r, _ = track(b, et, seconds, seed=seed)
        out["tcp"] = {"position_error_mm_rms": err(r), "n_samples": r.summary.n_samples,
                      "link": r.to_dict()["link"]}
        # paced: the acquisition time against the emitter's sample clock
        em = Emitter(realtime=True, seed=seed)
        et = EmitterThread([em])
        b = TcpBackend("127.0.0.1", et.port, em.spec.layout(), em.n_channels, drain=False)
        r, _ = track(b, et, max(seconds, 2.0), log=logs["paced"])
        a = read_track_log(logs["paced"]).arrays["openemt"]
        true_utc = em.sample_utc(b.counter_times(a["times"]) * em.fs)
        last = a["times"] > a["times"][-1] - 1.0
        e = 1e3 * np.abs(a["acquisition_time"][last] - true_utc[last])
        d = r.to_dict()
        out["paced"] = {"acquisition_time_error_ms": {"max": float(e.max()),
                                                      "rms": float(np.sqrt(np.mean(e ** 2))),
                                                      "poses": int(last.sum())},
                        "output_period_ms": 1e3 / OUTPUT_RATE_HZ,
                        "drift_ppm": d["link"]["drift_ppm"],
                        "latency_end_to_end_ms": {"p50": d["acquisition"]["latency_ms_p50"],
                                                  "p99": d["acquisition"]["latency_ms_p99"]},
                        "link": d["link"]}
    out["load_average"] = list(os.getloadavg())
    return out


# A viewer that decodes and counts every message (pyigtl keeps only the latest per device):
# pyigtl's own classes, counted, and a TDATA class (pyigtl has none; the body is K 70-byte
# elements, see openemt.live._tdata). It prints the counts after the STRING on device
# "benchEnd", which the server sends after the run (TCP keeps the order).
_COUNTER = """
import json, sys, time, pyigtl
from pyigtl import messages as M
counts, nbytes = {}, [0]
def counted(base):
    class C(base):
        def unpack(self, header, body):
            super().unpack(header, body)
            counts[(self.message_type, self.device_name)] = counts.get(
                (self.message_type, self.device_name), 0) + 1
            nbytes[0] += 58 + len(body)
    return C
class TData(M.MessageBase):
    def _unpack_content(self, content):
        self.tools = [content[k:k + 20].rstrip(b"\\0").decode()
                      for k in range(0, len(content), 70)]
for name, cls in (("TRANSFORM", M.TransformMessage), ("STRING", M.StringMessage),
                  ("TDATA", TData)):
    M.message_type_to_class_constructor[name] = counted(cls)
c = pyigtl.OpenIGTLinkClient(host="127.0.0.1", port=int(sys.argv[1]))
""" + _HELLO + """
end = time.time() + float(sys.argv[2])
while time.time() < end and ("STRING", "benchEnd") not in counts:
    time.sleep(0.02)
c.stop()
print(json.dumps({"counts": [[t, d, n] for (t, d), n in counts.items()], "bytes": nbytes[0]}))
"""


def _many_tools(preset, k: int, seconds: float, seed: int) -> dict:
    """K sensors in real time to a counting pyigtl client: TRANSFORMs (with and without
    metadata) against one TDATA per sample (see the module docstring, ``many_tools``)."""
    import json
    import subprocess
    import sys

    spec = _spec(preset, k)
    names = [st.device for st in spec.streams()]
    out = {"tools": k, "seconds": seconds, "output_rate": spec.output_rate}
    ways = (("transform", {}), ("transform_v1", {"metadata": False}),
            ("tdata", {"tdata": True}))
    for way, kw in ways:
        with _session(spec, seconds, seed, **kw) as session:
            srv = session.server
            client = subprocess.Popen([sys.executable, "-c", _COUNTER, str(srv.port),
                                       str(seconds + 60)], stdout=subprocess.PIPE, text=True)
            try:
                s, wall = _run_with_client(session)
                stats = srv.stats()
                import pyigtl

                srv.send_message(pyigtl.StringMessage("end", device_name="benchEnd"))
                end = time.monotonic() + 30.0        # the client reads what its socket holds
                while client.poll() is None and time.monotonic() < end:
                    time.sleep(0.02)
            finally:
                srv.close()
                try:
                    got, _ = client.communicate(timeout=30.0)
                except subprocess.TimeoutExpired:  # pragma: no cover
                    client.kill()
                    got, _ = client.communicate()
        rep = json.loads(got)
        counts = {(t, d): n for t, d, n in rep["counts"]}
        sig = s.signal_seconds
        if way == "tdata":
            msgs = counts.get(("TDATA", "openemt"), 0)
            frames = msgs
        else:
            per = [counts.get(("TRANSFORM", d), 0) for d in names]
            msgs, frames = sum(per), min(per)
        out[way] = {"messages_per_s": msgs / sig, "frame_rate_hz": frames / sig,
                    "messages_skipped": stats["messages_skipped"],
                    "messages_sent": stats["sent"], "bytes_per_s": rep["bytes"] / sig,
                    "kept_up_with_real_time": bool(wall <= 1.05 * sig + 0.05),
                    "samples": s.n_samples}
    out.update(_pack_per_sample(k))
    out["load_average"] = list(os.getloadavg())
    return out


def _pack_per_sample(k: int) -> dict:
    """CPU time to pack the K tools of one sample, in blocks of 10 samples (one 640-sample
    read) as the pipeline packs them: the 10 K TRANSFORMs in one call (with and without
    metadata), or 10 TDATA messages."""
    from ..live import frame_messages, pack_tdata, transform_bodies

    M = np.repeat(np.eye(4)[None], 10, axis=0)
    M[:, :3, 3] = [200.0, 10.0, -5.0]
    ts = time.time() + np.arange(10) / OUTPUT_RATE_HZ
    meta = {"TransformStatus": np.full(10, b"OK", "S2"),        # as the pipeline gives them
            "TransformValid": np.full(10, b"true", "S4"),
            "RelativeResidual": np.full(10, 1.234e-9), "QuadratureRatio": np.full(10, 5.6e-6),
            "DistortionLevel": np.full(10, b"001", dtype="S3")}
    MK = np.repeat(M[:, None], k, axis=1)
    valid = np.ones((10, k), bool)
    names = [f"S{j}" for j in range(k)]

    def per_sample(fn):
        fn()                                        # warm-up
        return cpu_us_per_item(fn, 10, repeats=3)

    flat = np.concatenate([M] * k)
    devices = [n for n in names for _ in range(10)]
    stamps = np.concatenate([ts] * k)
    meta_k = {key: (v * k if isinstance(v, list) else np.concatenate([v] * k))
              for key, v in meta.items()}

    def transforms(metadata):
        body, off = transform_bodies(flat, metadata)
        return frame_messages(body, off, "TRANSFORM", devices, stamps,
                              header_version=1 if metadata is None else 2)

    return {"pack_us_per_sample": {
        "transform": per_sample(lambda: transforms(meta_k)),
        "transform_v1": per_sample(lambda: transforms(None)),
        "tdata": per_sample(lambda: pack_tdata(MK, valid, names, ts))}}


def _raw(spec, seconds, seed):
    """``seconds`` of the simulated raw samples of ``spec`` and their channel layout."""
    from ..live import tracker_backend

    sim = tracker_backend(spec, "sim", realtime=False, duration=seconds, chunk=96000,
                          seed=seed)
    parts = []
    while (x := sim.read()) is not None:
        parts.append(x)
    return np.concatenate(parts), sim.layout


def _realtime_factor(spec, seconds, chunk, seed) -> dict:
    from ..live import TrackingSession, TrackOptions, tracker_sensors
    from ._memory import Memory

    raw, layout = _raw(spec, seconds, seed)
    import copy
    from dataclasses import replace

    shared = tracker_sensors(spec)
    # baseline: every sensor with its own model object (as with one calibration file per
    # sensor), so each is solved in its own call
    separate = [replace(st, model=copy.deepcopy(st.model)) for st in shared]

    opts = TrackOptions(igtl=False, quiet=True)

    def timed(sensors):
        with TrackingSession(spec, opts, sensors=sensors,
                             backend=Memory(raw[:6400], layout, chunk)) as warm:
            warm.run()
        with TrackingSession(spec, opts, sensors=sensors,
                             backend=Memory(raw, layout, chunk)) as session:
            cpu, wall, s = best_time(lambda: session.run().summary, 1)
            return s, wall, cpu

    s, wall, cpu = timed(shared)
    sb, wallb, cpub = timed(separate)
    out = {"realtime_factor": s.signal_seconds / wall,
           "realtime_factor_cpu": s.signal_seconds / cpu if cpu > 0 else None,
           "realtime_factor_target": 20.0,
           "realtime_signal_seconds": s.signal_seconds,
           "realtime_status_counts": s.status_counts,
           "realtime_baseline": {
               "what": "one solver call per sensor and chunk (one calibration file per sensor)",
               "realtime_factor": sb.signal_seconds / wallb,
               "realtime_factor_cpu": sb.signal_seconds / cpub if cpub > 0 else None,
               "status_counts": sb.status_counts}}
    out["realtime_speedup_vs_baseline_cpu"] = (
        out["realtime_factor_cpu"] / out["realtime_baseline"]["realtime_factor_cpu"]
        if out["realtime_factor_cpu"] and out["realtime_baseline"]["realtime_factor_cpu"]
        else None)
    out.update(_packing(len(spec.sensors)))
    return out


def _packing(k: int) -> dict:
    """CPU time to pack one chunk's TRANSFORM messages (10 per sensor): the compiled block
    packer against pyigtl's one-message-at-a-time packing."""
    import pyigtl

    from ..live import pack_transforms

    M = np.repeat(np.eye(4)[None], 10, axis=0)
    M[:, :3, 3] = [200.0, 10.0, -5.0]
    ts = time.time() + np.arange(10) / OUTPUT_RATE_HZ
    pack_transforms(M, ts, "S0")
    ours = cpu_us_per_item(lambda: pack_transforms(M, ts, "S0"), 10)
    theirs = cpu_us_per_item(lambda: b"".join(
        pyigtl.TransformMessage(m, timestamp=t, device_name="S0").pack()
        for m, t in zip(M, ts)), 10)
    return {"igtl_pack_us_per_message": ours, "igtl_pack_us_per_message_pyigtl": theirs,
            "igtl_pack_speedup": theirs / ours if ours > 0 else None,
            "igtl_pack_us_per_chunk": 10 * k * ours}


def _filter_report(model, noise_log, ok, noise_um, seed) -> dict:
    """Noise with/without the Kalman filter (static run), lag at a 2 Hz sine, step settling."""
    from ..live import (
        FilterSpec,
        SimulatedBackend,
        TrackingPipeline,
        TrackLog,
        kalman_filter_poses,
    )

    f = FilterSpec(kind="kalman")
    kw = {k: getattr(f, k) for k in ("process_noise", "measurement_noise",
                                     "rotation_process_noise", "rotation_measurement_noise",
                                     "max_gap")}
    # static: the same demodulated poses, filtered
    t = noise_log["times"][ok]
    _, fv, _ = kalman_filter_poses(noise_log["pose_vectors"][ok], t, np.ones(len(t), bool),
                                   **kw)
    settle = 150                                        # skip the filter's first 0.1 s
    filt_um = 1e6 * float(np.sqrt(np.trace(np.cov(fv[settle:, :3].T))))
    raw_um = 1e6 * float(np.sqrt(np.trace(np.cov(noise_log["pose_vectors"][ok][settle:, :3].T))))

    # motion: 10 mm, 2 Hz sine along y at (200, 0, 0) mm
    freq, amp = 2.0, 0.010
    base = np.array([0.2, 0.0, 0.0, 0.1, -0.2, 0.3])

    def trajectory(tt):
        from ..geometry import pose_from_vector

        v = np.tile(base, (len(tt), 1))
        v[:, 1] += amp * np.sin(2 * np.pi * freq * np.asarray(tt))
        return pose_from_vector(v)

    log = TrackLog()
    TrackingPipeline(SimulatedBackend(model, trajectory, seed=seed + 2, duration=2.0,
                                      chunk=6400), model, log=log).run()
    a = log.arrays()
    good = a["status"] == 0
    tt, y = a["times"][good], a["pose_vectors"][good]
    _, fy, _ = kalman_filter_poses(y, tt, np.ones(len(tt), bool), **kw)
    truth = trajectory(tt)[:, 1, 3]

    def phase(sig):
        A = np.column_stack([np.sin(2 * np.pi * freq * tt), np.cos(2 * np.pi * freq * tt),
                             np.ones_like(tt)])
        c = np.linalg.lstsq(A[settle:], sig[settle:], rcond=None)[0]
        return np.arctan2(c[1], c[0])

    lag_ms = 1e3 * (phase(y[:, 1]) - phase(fy[:, 1])) / (2 * np.pi * freq)
    # step response (noise-free): time until the output stays within 1 % of a 1 mm step
    n = 300
    st = np.tile(base, (n, 1))
    st[100:, 0] += 1e-3
    _, fs_, _ = kalman_filter_poses(st, np.arange(n) / OUTPUT_RATE_HZ, np.ones(n, bool), **kw)
    err = np.abs(fs_[100:, 0] - st[100:, 0]) / 1e-3
    worst = np.maximum.accumulate(err[::-1])[::-1]
    settle_samples = int(np.argmax(worst < 0.01))
    return {
        "kind": "kalman", **kw,
        "position_noise_um": raw_um, "position_noise_um_filtered": filt_um,
        "noise_reduction": filt_um / raw_um,
        "motion": "10 mm, 2 Hz sine along y at (200, 0, 0) mm",
        "added_lag_ms": float(lag_ms),
        "motion_error_um_rms": 1e6 * float(np.sqrt(np.mean((y[settle:, 1]
                                                           - truth[settle:]) ** 2))),
        "motion_error_um_rms_filtered": 1e6 * float(np.sqrt(np.mean((fy[settle:, 1]
                                                                    - truth[settle:]) ** 2))),
        "step_settle_ms": 1e3 * settle_samples / OUTPUT_RATE_HZ,
        "step_overshoot": float(max(0.0, np.max(fs_[100:, 0] - st[100:, 0]) / 1e-3)),
    }
