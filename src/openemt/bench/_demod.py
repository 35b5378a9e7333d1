"""``openemt bench demod``: demodulation speed and accuracy against the simulator's truth.

Keys
----
realtime_factor
    Seconds of signal demodulated per second of wall time, 3 sensor + 3 reference channels at
    96 kS/s, fed in chunks of ``--chunk`` samples as a live stream would (median of
    ``--repeats``). ``realtime_factor_cpu`` uses process CPU time instead (insensitive to other
    load on the machine; ``load_average`` is reported alongside).
baseline_realtime_factor, speedup_vs_baseline
    The same demodulation done the textbook way in the same process: windowed frames and a
    full ``numpy.fft.rfft`` per frame, picking the carrier bins.
amplitude_error_rel_max
    Noise-free, max ``|C_demod - C_true| / max|C_true|`` for a static pose and for a moving
    trajectory (truth at the frame centres).
mains_rejection_db
    ``20 log10(A_mains / rms coupling error)``: the same simulation with and without mains
    (50 and 60 Hz, harmonics 1-5 with amplitudes 1, 1/2, 1/3, 1/5, 1/10 of the fundamental),
    drive amplitude 1 A and 1 V per coupling unit, for both windows.
drift_error_rel_max
    Noise-free error with a 20 % sinusoidal drive drift (period 1 s).
noise_coupling_rms, noise_coupling_predicted
    Measured and analytic (``sigma sqrt(2 sum w^2) / sum w``) coupling noise.
"""

from __future__ import annotations

import os

import numpy as np

from .._constants import OUTPUT_RATE_HZ
from .._errors import InputError
from ._timing import best_time

__all__ = ["add_arguments", "run"]


def add_arguments(parser) -> None:
    parser.add_argument("--seconds", type=float, default=10.0,
                        help="seconds of signal for the throughput test (default 10)")
    parser.add_argument("--chunk", type=int, default=9600,
                        help="samples per call, as a live stream delivers them (default 9600)")
    parser.add_argument("--repeats", type=int, default=3, help="timing repeats (median)")
    parser.add_argument("--window", choices=("hann", "rect"), default="hann",
                        help="window timed for realtime_factor (accuracy reports both)")
    parser.add_argument("--seed", type=int, default=0)


def _fft_baseline(samples, layout, hop, L, window):
    """Textbook demodulation: frame, window, full FFT, pick bins, divide by the reference."""
    from ..signal import frame_window

    w = frame_window(window, L)
    bins = np.round(np.asarray(layout.frequencies) * L / layout.sample_rate).astype(int)
    n_out = (samples.shape[0] - L) // hop + 1
    out = np.empty((n_out, layout.n_source, layout.n_sensor), complex)
    se, ref = list(layout.sensor_channels), list(layout.reference_channels)
    scale = 2.0 / w.sum()
    for k in range(n_out):
        X = np.fft.rfft(samples[k * hop:k * hop + L] * w[:, None], axis=0) * scale
        out[k] = X[bins][:, se] / X[bins, ref][:, None]
    return out


def run(args) -> dict:
    from ..field import DipoleModel
    from ..geometry import pose_from_vector
    from ..live import default_trajectory
    from ..signal import (
        Demodulator,
        RawSignalConfig,
        demodulate,
        frame_length,
        frame_window,
        simulate_raw,
    )

    model = DipoleModel.concentric()
    pose = pose_from_vector(np.array([0.17, 0.08, -0.07, 0.4, -0.3, 0.6]))
    Ct = model.coupling(pose[None])
    quiet = {"noise_rms": 0.0, "reference_noise_rms": 0.0}

    # --- throughput: realistic signal (noise, mains) through the streaming demodulator
    seconds = float(args.seconds)
    if not seconds > 0:
        raise InputError(f"expected positive --seconds, got {seconds}")
    raw = simulate_raw(model, default_trajectory, seconds,
                       RawSignalConfig(mains_amplitudes=(0.01, 0.003)), seed=args.seed,
                       coupling_stride=16)
    x, lay, chunk = raw.samples, raw.layout, max(1, int(args.chunk))

    def stream():
        dem = Demodulator(lay, window=args.window)
        for a in range(0, x.shape[0], chunk):
            dem.process(x[a:a + chunk])

    stream()  # warm caches
    cpu, wall, _ = best_time(stream, args.repeats, np.median)
    hop, L = frame_length(lay, OUTPUT_RATE_HZ, args.window)
    base_secs = min(seconds, 2.0)
    nb = int(base_secs * lay.sample_rate)
    _, bwall, _ = best_time(lambda: _fft_baseline(x[:nb], lay, hop, L, args.window), 1)
    # the baseline and ours agree (same estimator)
    ours = demodulate(x[:nb], lay, window=args.window).couplings
    agree = float(np.abs(_fft_baseline(x[:nb], lay, hop, L, args.window) - ours).max())

    out = {
        "channels": {"sensor": lay.n_sensor, "reference": lay.n_source},
        "sample_rate": lay.sample_rate, "output_rate": OUTPUT_RATE_HZ, "window": args.window,
        "frame_samples": L, "hop_samples": hop, "chunk_samples": chunk,
        "signal_seconds": seconds,
        "realtime_factor": seconds / wall,
        "realtime_factor_cpu": seconds / cpu if cpu > 0 else None,
        "realtime_factor_target": 100.0,
        "baseline_realtime_factor": base_secs / bwall,
        "speedup_vs_baseline": (seconds / wall) / (base_secs / bwall),
        "baseline_max_abs_difference": agree,
        "load_average": list(os.getloadavg()),
        "cpu_count": os.cpu_count(),
    }

    # --- accuracy (noise-free unless stated)
    amp, mains, drift = {}, {}, {}
    for window in ("hann", "rect"):
        r = simulate_raw(model, pose, 0.2, RawSignalConfig(**quiet), seed=args.seed + 1)
        d = demodulate(r.samples, r.layout, window=window)
        static = np.abs(d.couplings - Ct).max() / np.abs(Ct).max()
        r = simulate_raw(model, default_trajectory, 0.5, RawSignalConfig(**quiet),
                         seed=args.seed + 2, coupling_stride=1)
        d = demodulate(r.samples, r.layout, window=window)
        Cm = model.coupling(default_trajectory(d.times))
        moving = np.abs(d.couplings - Cm).max() / np.abs(Cm).max()
        amp[window] = {"static": float(static), "moving": float(moving)}

        base = demodulate(simulate_raw(model, pose, 0.5, RawSignalConfig(**quiet),
                                       seed=args.seed + 3).samples, lay, window=window)
        for f in (50.0, 60.0):
            a1 = 0.1
            cfg = RawSignalConfig(mains_frequency=f, mains_amplitudes=(a1, a1 / 2, a1 / 3,
                                                                        a1 / 5, a1 / 10),
                                  **quiet)
            hum = demodulate(simulate_raw(model, pose, 0.5, cfg, seed=args.seed + 3).samples,
                             lay, window=window)
            rms = np.sqrt(np.mean(np.abs(hum.couplings - base.couplings) ** 2))
            mains[f"{window}_{int(f)}hz"] = float(20 * np.log10(a1 / rms))

        cfg = RawSignalConfig(drift_amplitude=0.2, drift_period=1.0, **quiet)
        r = simulate_raw(model, pose, 1.0, cfg, seed=args.seed + 4)
        d = demodulate(r.samples, r.layout, window=window)
        drift[window] = float(np.abs(d.couplings - Ct).max() / np.abs(Ct).max())
    out["amplitude_error_rel_max"] = amp
    out["mains_rejection_db"] = mains
    out["drift_error_rel_max"] = drift

    sigma = RawSignalConfig().noise_rms
    r = simulate_raw(model, pose, 1.0, RawSignalConfig(reference_noise_rms=0.0),
                     seed=args.seed + 5)
    noise = {}
    for window in ("hann", "rect"):
        d = demodulate(r.samples, r.layout, window=window)
        _, L = frame_length(r.layout, OUTPUT_RATE_HZ, window)
        w = frame_window(window, L)
        noise[window] = {"measured": float(np.sqrt(np.mean(d.in_phase.var(axis=0)))),
                         "predicted": float(sigma * np.sqrt(2 * np.sum(w ** 2)) / np.sum(w))}
    out["noise_sensor_v_rms"] = sigma
    out["noise_coupling_rms"] = noise
    return out
