"""Demodulation against the raw-signal simulator's truth."""

from __future__ import annotations

import numpy as np
import pytest

from openemt.field import DipoleModel
from openemt.geometry import pose_from_vector
from openemt.signal import (
    ChannelLayout,
    Demodulator,
    RawSignalConfig,
    demodulate,
    eddy_factor,
    frame_length,
    phase_calibration,
    simulate_raw,
)

MODEL = DipoleModel.concentric()
# a pose near 200 mm with every coupling entry clearly non-zero and of mixed sign
POSE = pose_from_vector(np.array([0.17, 0.08, -0.07, 0.4, -0.3, 0.6]))


def _circle(t):
    t = np.asarray(t, dtype=np.float64)
    a = 2 * np.pi * 0.5 * t
    v = np.stack([0.2 + 0.02 * np.cos(a), 0.02 * np.sin(a), 0.01 * np.sin(2 * a),
                  0.3 + 0.2 * np.sin(a), -0.2 + 0.0 * a, 0.5 + 0.3 * np.cos(a)], axis=1)
    return pose_from_vector(v)


def _quiet(**kw):
    kw.setdefault("noise_rms", 0.0)
    kw.setdefault("reference_noise_rms", 0.0)
    return RawSignalConfig(**kw)


@pytest.mark.parametrize("window", ["hann", "rect"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_static_round_trip_with_random_drive_phase(window, seed):
    raw = simulate_raw(MODEL, POSE, 0.05, _quiet(), seed=seed)
    d = demodulate(raw.samples, raw.layout, window=window)
    C = MODEL.coupling(POSE[None])[0]
    hop, L = frame_length(raw.layout, 1500, window)
    assert len(d) == (raw.n_samples - L) // hop + 1
    assert np.all(np.sign(C) != 0)
    np.testing.assert_allclose(d.couplings.real, np.broadcast_to(C, d.couplings.shape),
                               rtol=0, atol=1e-11)
    np.testing.assert_allclose(d.couplings.imag, 0, atol=1e-11)
    np.testing.assert_array_equal(np.sign(d.in_phase), np.broadcast_to(np.sign(C), d.in_phase.shape))
    np.testing.assert_allclose(np.abs(d.reference), 1.0, rtol=1e-12)


def test_gains_and_amplitude_scale_out():
    lay = ChannelLayout(sensor_gain=37.0, reference_gain=0.25)
    raw = simulate_raw(MODEL, POSE, 0.02, _quiet(layout=lay, drive_amplitude=2.5), seed=3)
    d = demodulate(raw.samples, raw.layout)
    np.testing.assert_allclose(d.in_phase, np.broadcast_to(MODEL.coupling(POSE[None]),
                                                           d.in_phase.shape), atol=1e-11)
    np.testing.assert_allclose(np.abs(d.reference), 2.5, rtol=1e-12)


def test_drive_drift_cancels():
    cfg = _quiet(drift_amplitude=0.3, drift_period=1.0)
    raw = simulate_raw(MODEL, POSE, 0.5, cfg, seed=4)
    d = demodulate(raw.samples, raw.layout)
    amp = np.abs(d.reference)
    assert amp.max() / amp.min() > 1.25         # the drive really drifted
    C = MODEL.coupling(POSE[None])
    err = np.abs(d.couplings - C).max() / np.abs(C).max()
    assert err < 2e-5                           # second-order residue of the in-frame slope


def test_moving_trajectory_matches_truth_at_frame_centres():
    raw = simulate_raw(MODEL, _circle, 0.2, _quiet(), seed=5)
    d = demodulate(raw.samples, raw.layout)
    C = MODEL.coupling(_circle(d.times))
    np.testing.assert_allclose(d.in_phase, C, rtol=0, atol=2e-5 * np.abs(C).max())


def test_eddy_current_shows_as_quadrature():
    cfg = _quiet(eddy_strength=0.02, eddy_time_constant=20e-6)
    raw = simulate_raw(MODEL, POSE, 0.02, cfg, seed=6)
    d = demodulate(raw.samples, raw.layout)
    C = MODEL.coupling(POSE[None])[0] * (1 + eddy_factor(raw.layout.frequencies, 0.02,
                                                         20e-6))[:, None]
    np.testing.assert_allclose(d.couplings, np.broadcast_to(C, d.couplings.shape), atol=1e-11)
    np.testing.assert_allclose(raw.truth_couplings[0], C, rtol=1e-12)
    assert np.all(d.distortion_ratio() > 5e-3)
    clean = demodulate(simulate_raw(MODEL, POSE, 0.02, _quiet(), seed=6).samples, raw.layout)
    assert np.all(clean.distortion_ratio() < 1e-10)


def test_distortion_ratio_per_column_group():
    """The compiled ratio over each group's columns equals ``||Im C|| / ||C||`` of those
    columns, groups may overlap, an all-zero sample gives 0 and NaN stays NaN."""
    from openemt.signal import distortion_ratio

    rng = np.random.default_rng(11)
    C = rng.normal(size=(7, 3, 6)) + 1j * rng.normal(size=(7, 3, 6)) * 0.1
    C[2] = 0.0
    C[4, 1, 5] = complex(np.nan, np.nan)
    mask = np.zeros((3, 6), bool)
    mask[0, :3], mask[1, 3:], mask[2, [0, 4, 5]] = True, True, True
    got = distortion_ratio(C, mask)
    assert got.shape == (3, 7)
    for g in range(3):
        sub = C[:, :, mask[g]]
        num = np.sqrt(np.sum(sub.imag ** 2, axis=(1, 2)))
        den = np.sqrt(np.sum(np.abs(sub) ** 2, axis=(1, 2)))
        want = num / np.where(den > 0, den, np.inf)
        np.testing.assert_allclose(got[g], want, rtol=1e-14, atol=0)
    assert got[0, 2] == 0.0 and np.isnan(got[1, 4]) and not np.isnan(got[0, 4])
    np.testing.assert_allclose(distortion_ratio(C), distortion_ratio(C, np.ones((1, 6), bool))[0])
    assert distortion_ratio(C.real).max() == 0.0
    with pytest.raises(ValueError, match=r"column mask of shape \(K, 6\), got \(2, 5\)"):
        distortion_ratio(C, np.ones((2, 5), bool))


@pytest.mark.parametrize("mains", [50.0, 60.0])
def test_mains_rejection(mains):
    amps = (0.1, 0.05, 0.03, 0.02, 0.01)      # harmonics 1..5, volts, >> the carriers' noise
    base = simulate_raw(MODEL, POSE, 0.2, _quiet(), seed=7)
    hum = simulate_raw(MODEL, POSE, 0.2, _quiet(mains_frequency=mains, mains_amplitudes=amps),
                       seed=7)
    rej = {}
    for window in ("hann", "rect"):
        a = demodulate(base.samples, base.layout, window=window).couplings
        b = demodulate(hum.samples, hum.layout, window=window).couplings
        rej[window] = 20 * np.log10(amps[0] / np.sqrt(np.mean(np.abs(b - a) ** 2)))
    # Hann sidelobes at >= 8 bins from the mains lines are below -60 dB; rect leaks ~ -40 dB
    assert rej["hann"] > 60
    assert rej["hann"] > rej["rect"] + 20


@pytest.mark.parametrize("window", ["hann", "rect"])
def test_noise_matches_analytic_prediction(window):
    sigma = 1e-3
    raw = simulate_raw(MODEL, POSE, 1.0, _quiet(noise_rms=sigma), seed=8)
    d = demodulate(raw.samples, raw.layout, window=window)
    _, L = frame_length(raw.layout, 1500, window)
    w = np.ones(L) if window == "rect" else 0.5 - 0.5 * np.cos(2 * np.pi * np.arange(L) / L)
    predicted = sigma * np.sqrt(2 * np.sum(w ** 2)) / np.sum(w)
    measured = d.in_phase.std(axis=0)
    np.testing.assert_allclose(measured, predicted, rtol=0.12)
    np.testing.assert_allclose(d.quadrature.std(axis=0), predicted, rtol=0.12)


def test_streaming_equals_batch():
    rng = np.random.default_rng(9)
    raw = simulate_raw(MODEL, _circle, 0.05, RawSignalConfig(mains_amplitudes=(0.01,)), seed=9)
    ref = demodulate(raw.samples, raw.layout)
    dem = Demodulator(raw.layout)
    parts, a = [], 0
    while a < raw.n_samples:
        n = int(rng.integers(1, 300))
        parts.append(dem.process(raw.samples[a:a + n]))
        a += n
    C = np.concatenate([p.couplings for p in parts])
    t = np.concatenate([p.times for p in parts])
    np.testing.assert_allclose(C, ref.couplings, rtol=0, atol=1e-13)
    np.testing.assert_allclose(t, ref.times, rtol=0, atol=1e-12)
    assert np.all(np.diff(t) > 0)


def test_phase_calibration_removes_sensor_chain_delay():
    cfg = _quiet(delay=3e-6)
    raw = simulate_raw(MODEL, _circle, 0.3, cfg, seed=10)
    d = demodulate(raw.samples, raw.layout)
    assert np.abs(d.quadrature).max() > 0.05 * np.abs(d.couplings).max()   # chain phase shows
    phase = phase_calibration(d.couplings)
    expected = 2 * np.pi * np.asarray(raw.layout.frequencies) * 3e-6
    # exact up to the small quadrature that motion within a frame produces
    np.testing.assert_allclose(phase, np.broadcast_to(-expected[:, None], phase.shape), atol=1e-4)
    run = simulate_raw(MODEL, POSE, 0.02, cfg, seed=11)
    c = demodulate(run.samples, run.layout, phase=phase)
    C = MODEL.coupling(POSE[None])
    np.testing.assert_allclose(c.couplings, np.broadcast_to(C, c.couplings.shape),
                               atol=1e-4 * np.abs(C).max())
    assert np.abs(c.quadrature).max() < 1e-3 * np.abs(d.quadrature).max()


def test_validation_messages():
    lay = ChannelLayout()
    with pytest.raises(ValueError, match="integer"):
        frame_length(lay, 1400.0)
    with pytest.raises(ValueError, match="whole cycles"):
        frame_length(ChannelLayout(frequencies=(7600.0, 10500.0, 13500.0)))
    with pytest.raises(ValueError, match="bins apart"):
        frame_length(ChannelLayout(frequencies=(7500.0, 8250.0, 13500.0)), window="hann")
    frame_length(ChannelLayout(frequencies=(7500.0, 9000.0, 13500.0)), window="rect")
    with pytest.raises(ValueError, match="window"):
        frame_length(lay, window="kaiser")
    with pytest.raises(ValueError, match="shape"):
        Demodulator(lay).process(np.zeros((10, 4)))
    with pytest.raises(ValueError, match="phase"):
        Demodulator(lay, phase=np.zeros((2, 3)))
    with pytest.raises(ValueError, match="reference channel"):
        ChannelLayout(reference_channels=(3, 4))
    with pytest.raises(ValueError, match="distinct"):
        ChannelLayout(sensor_channels=(0, 1, 3))
    with pytest.raises(ValueError, match="complex couplings"):
        phase_calibration(np.zeros((4, 3, 3)))


def test_drive_off_gives_non_finite_couplings_not_garbage():
    raw = simulate_raw(MODEL, POSE, 0.01, _quiet(), seed=12)
    x = raw.samples.copy()
    x[:, list(raw.layout.reference_channels)] = 0.0      # no current measured
    d = demodulate(x, raw.layout)
    assert not np.any(np.isfinite(d.couplings))
