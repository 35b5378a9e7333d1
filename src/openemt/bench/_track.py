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
    Target p99 < 2 ms. ``pipeline_latency_ms_*`` stop at the hand-over to the sender.
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
baseline
    ``one_frame_reads`` with numba's default thread pool for the one-sample solves (what the
    pipeline avoids by solving small chunks on its own thread); ``one_frame_reads`` reports
    ``p99_speedup_vs_baseline``.
"""

from __future__ import annotations

import os
import time

import numpy as np

from .._constants import OUTPUT_RATE_HZ
from .._errors import InputError

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
    parser.add_argument("--seed", type=int, default=0)


# The viewer: a pyigtl client in its own process (as 3D Slicer would be), so that its polling
# thread does not compete with the pipeline for this interpreter.
_CLIENT = """
import sys, time, pyigtl
c = pyigtl.OpenIGTLinkClient(host="127.0.0.1", port=int(sys.argv[1]))
end, seen = time.time() + float(sys.argv[2]), 0
while time.time() < end:
    if c.wait_for_message("openemt", timeout=0.05) is not None:
        seen += 1
c.stop()
print(seen, flush=True)
"""


def _latency_run(model, seconds, chunk, seed, serial=True):
    import subprocess
    import sys

    from ..live import IgtlServer, SimulatedBackend, TrackingPipeline

    backend = SimulatedBackend(model, seed=seed, realtime=True, duration=seconds, chunk=chunk)
    srv = IgtlServer(port=0, device_name="openemt", max_queue=64)
    client = subprocess.Popen([sys.executable, "-c", _CLIENT, str(srv.port),
                               str(seconds * 20 + 30)], stdout=subprocess.DEVNULL)
    try:
        if not srv.wait_for_client(30.0):
            raise OSError("expected a loopback OpenIGTLink client to connect, got none in 30 s")
        pipe = TrackingPipeline(backend, model, igtl=srv, serial_small_batches=serial)
        backend.restart_clock()
        t0 = time.perf_counter()
        s = pipe.run()
        wall = time.perf_counter() - t0
        time.sleep(0.05)
    finally:
        client.terminate()
        try:
            client.wait(timeout=5.0)
        except subprocess.TimeoutExpired:  # pragma: no cover
            client.kill()
            client.wait(timeout=5.0)
        srv.close()
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
    if not seconds > 0 or not args.noise_seconds > 0:
        raise InputError(f"expected positive --seconds and --noise-seconds, got {seconds} and "
                         f"{args.noise_seconds}")

    # compile / load every numba kernel the pipeline uses before anything is timed
    _latency_run(model, 0.05, args.chunk, args.seed)
    s, send, wall, stats = _latency_run(model, seconds, args.chunk, args.seed)
    s1, send1, wall1, _ = _latency_run(model, min(seconds, 1.0), 64, args.seed)
    _, sendb, _, _ = _latency_run(model, min(seconds, 1.0), 64, args.seed, serial=False)

    def pct(a, q):
        return float(np.percentile(a, q)) if len(a) else None

    out = {
        "preset": args.preset, "output_rate": OUTPUT_RATE_HZ, "chunk_samples": args.chunk,
        "latency_ms_p50": pct(send, 50), "latency_ms_p99": pct(send, 99),
        "latency_ms_max": pct(send, 100), "latency_samples": len(send),
        "latency_target_p99_ms": 2.0,
        "pipeline_latency_ms_p50": s.latency_ms_p50, "pipeline_latency_ms_p99": s.latency_ms_p99,
        "signal_seconds": s.signal_seconds, "wall_seconds": wall,
        "kept_up_with_real_time": bool(wall <= 1.05 * s.signal_seconds + 0.05),
        "igtl": stats, "status_counts": s.status_counts,
        "tracking_error_mm_rms": (s.truth or {}).get("position_error_mm_rms"),
        "baseline": {"what": "one frame per read, numba's default thread pool for the "
                             "one-sample solves",
                     "latency_ms_p50": pct(sendb, 50), "latency_ms_p99": pct(sendb, 99)},
        "one_frame_reads": {
            "chunk_samples": 64, "latency_ms_p50": pct(send1, 50),
            "latency_ms_p99": pct(send1, 99),
            "kept_up_with_real_time": bool(wall1 <= 1.05 * s1.signal_seconds + 0.05),
            "wall_seconds": wall1, "signal_seconds": s1.signal_seconds,
            "p99_speedup_vs_baseline": (pct(sendb, 99) / pct(send1, 99)
                                        if len(send1) and len(sendb) else None)},
        "load_average": list(os.getloadavg()), "cpu_count": os.cpu_count(),
    }

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
    return out
