"""Carrier bands: simulated per band, the eddy part taken out from two bands, band fusion."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from openemt._errors import InputError
from openemt.simulate import simulate
from openemt.solve import eddy_free_couplings, fuse_bands

BANDS = [[274.0, 334.0, 370.0], [7500.0, 10500.0, 13500.0]]
SHEET = {"object": [{"kind": "sheet", "material": "stainless_steel",
                     "position": [0.0, 0.244, -0.134], "thickness": 0.002}]}


def test_single_pole_responses_are_removed_exactly():
    """C(w) = C0 + k i w tau / (1 + i w tau), k differing per entry: C0 comes back."""
    rng = np.random.default_rng(1)
    n = 50
    C0 = rng.standard_normal((n, 3, 3))
    k = 0.2 * rng.standard_normal((n, 3, 3))
    tau = rng.uniform(1e-5, 2e-3, n)[:, None, None]
    f = np.array(BANDS)
    B = np.stack([C0 + k * (1j * 2 * np.pi * f[b][None, :, None] * tau)
                  / (1 + 1j * 2 * np.pi * f[b][None, :, None] * tau) for b in range(2)], axis=1)
    out, t = eddy_free_couplings(B, f, return_tau=True)
    np.testing.assert_allclose(out, C0, atol=1e-9)
    np.testing.assert_allclose(t, tau[:, 0, 0], rtol=1e-9)
    # no eddy signal: the slow band unchanged
    clean = np.repeat(C0[:, None], 2, axis=1).astype(complex)
    np.testing.assert_array_equal(eddy_free_couplings(clean, f), C0)
    with pytest.raises(InputError, match="n_bands"):
        eddy_free_couplings(B[:, :1], f[:1])


def test_simulated_bands_and_the_stainless_sheet():
    kw = dict(source_fixtures="YoutZup", sensor_fixtures="YoutZup", stage_sigma=0)
    clean = simulate("dipole-approx", "md", **kw)
    data = simulate("dipole-approx", "md", metal=SHEET, bands=BANDS, **kw)
    B = data.extra["couplings_bands"]
    assert B.shape == (len(data), 2, 3, 3)
    np.testing.assert_array_equal(data.couplings, B[:, 0])
    np.testing.assert_array_equal(data.band_frequencies, BANDS)
    np.testing.assert_array_equal(data.band_couplings, B)
    # the slow band sees less eddy current than the fast one, the extrapolation far less
    err = [np.abs(C - clean.couplings).max() for C in (B[:, 1].real, B[:, 0].real,
                                                        eddy_free_couplings(B, BANDS))]
    assert err[1] < err[0] / 3 and err[2] < err[0] / 50, err
    one = simulate("dipole-approx", "md", **kw)
    assert one.band_couplings is None and one.band_frequencies is None


def test_band_couplings_survive_the_dataset_file(tmp_path):
    from openemt.io import read_dataset, write_dataset

    data = simulate("dipole-approx", "md", source_fixtures="YoutZup", sensor_fixtures="YoutZup",
                    metal=SHEET, bands=BANDS)
    write_dataset(data, tmp_path / "d.h5")
    back = read_dataset(tmp_path / "d.h5")
    np.testing.assert_array_equal(back.band_couplings, data.band_couplings)
    np.testing.assert_array_equal(back.band_frequencies, BANDS)
    with pytest.raises(InputError, match="couplings_bands"):
        dataclasses.replace(data, extra={"couplings_bands": data.couplings})


def test_fuse_bands_follows_fast_and_settles_on_slow():
    n, rate, tc = 400, 100.0, 0.5
    fast = np.zeros((n, 2))
    fast[200:] += 1.0                                  # a step the fast band sees at once
    slow = fast + np.array([0.3, -0.1])                # the slow band: offset, no lag here
    out = fuse_bands(fast, slow, time_constant=tc, rate=rate)
    np.testing.assert_allclose(out, slow, atol=1e-12)  # steady difference: all of it
    # a difference that appears at sample 100 is taken up with the time constant
    slow2 = fast.copy()
    slow2[100:] += 1.0
    out = fuse_bands(fast, slow2, time_constant=tc, rate=rate)
    d = out[:, 0] - fast[:, 0]
    assert d[99] == 0 and abs(d[100 + int(tc * rate) - 1] - (1 - np.exp(-1))) < 0.01
    assert d[-1] == pytest.approx(1 - np.exp(-(n - 100) / (tc * rate)), rel=1e-9)
    with pytest.raises(InputError, match="one shape"):
        fuse_bands(fast, slow[:, :1], time_constant=tc, rate=rate)


def test_raw_signal_bands_with_metal_demodulate_to_the_truth():
    """Two carriers per coil through one current reference each; a copper sphere near the
    tracker responds differently per band; the demodulator returns every band's coupling."""
    from openemt.field import DipoleModel
    from openemt.geometry import pose_from_vector
    from openemt.signal import ChannelLayout, RawSignalConfig, demodulate, simulate_raw
    from openemt.simulate import MetalObject, MetalScene

    layout = ChannelLayout(frequencies=(7500.0, 10500.0, 13500.0),
                           bands=((1500.0, 3000.0, 4500.0),))
    assert layout.n_bands == 2 and layout.band_frequencies.shape == (2, 3)
    scene = MetalScene((MetalObject("sphere", "copper", (0.1, 0.05, 0.0), radius=0.03),))
    pose = pose_from_vector(np.array([0.15, 0.05, 0.02, 0.3, -0.2, 0.5]))
    raw = simulate_raw(DipoleModel.concentric(), pose, 0.02,
                       RawSignalConfig(layout=layout, noise_rms=0.0, reference_noise_rms=0.0),
                       metal=scene)
    out = demodulate(raw.samples, raw.layout)
    assert out.bands.shape == (len(out), 2, 3, 3)
    np.testing.assert_array_equal(out.couplings, out.bands[:, 0])
    from openemt.signal import RawSimulator

    sim = RawSimulator(DipoleModel.concentric(), pose,
                       RawSignalConfig(layout=layout, noise_rms=0.0, reference_noise_rms=0.0),
                       metal=scene)
    true = sim.true_couplings(out.times, bands=True)
    np.testing.assert_allclose(out.bands, true, rtol=0, atol=1e-9 * np.abs(true).max())
    # the sphere's response differs between the bands, and shows in the quadrature
    assert np.abs(true[:, 1] - true[:, 0]).max() > 1e-3 * np.abs(true).max()
    assert np.abs(true.imag).max() > 1e-3 * np.abs(true).max()
    with pytest.raises(InputError, match="one frequency per source"):
        ChannelLayout(bands=((1500.0, 3000.0),))


def test_tracker_file_bands_and_metal(tmp_path):
    """A tracker file names each coil's carriers (band 0 first) and a metal scene for its
    simulated source; the simulated session's raw signal carries both bands."""
    import shutil
    from importlib import resources

    from openemt.live import read_tracker, tracker_backend
    from openemt.signal import demodulate

    folder = resources.files("openemt.live") / "trackers"
    text = (folder / "simulated.toml").read_text()
    text = text.replace("frequencies = [7500.0, 10500.0, 13500.0]",
                        "frequencies = [[7500.0, 1500.0], [10500.0, 3000.0], [13500.0, 4500.0]]")
    text = text.replace('preset = "concentric"',
                        'preset = "concentric"\nmetal = "sphere.toml"')
    (tmp_path / "t.toml").write_text(text)
    shutil.copy(folder / "concentric.json", tmp_path / "concentric.json")
    (tmp_path / "sphere.toml").write_text(
        '[[object]]\nkind = "sphere"\nmaterial = "copper"\nposition = [0.1, 0.0, 0.0]\n'
        'radius = 0.03\n')
    spec = read_tracker(tmp_path / "t.toml")
    assert spec.frequencies == (7500.0, 10500.0, 13500.0)
    assert spec.bands == ((1500.0, 3000.0, 4500.0),)
    assert spec.layout().n_bands == 2
    assert spec.simulation["metal"].objects[0].kind == "sphere"
    b = tracker_backend(spec, "sim", realtime=False, duration=0.02, noise_rms=0.0)
    chunks = []
    while (c := b.read()) is not None:
        chunks.append(c)
    raw = np.concatenate(chunks)
    out = demodulate(raw, spec.layout())
    assert out.bands.shape[1:] == (2, 3, 3)
    assert np.abs(out.bands[:, 1] - out.bands[:, 0]).max() > 1e-4 * np.abs(out.bands).max()
    bad = text.replace("[13500.0, 4500.0]", "[13500.0]")
    (tmp_path / "bad.toml").write_text(bad)
    with pytest.raises(InputError, match="same number of carrier bands"):
        read_tracker(tmp_path / "bad.toml")
    (tmp_path / "bad2.toml").write_text(text.replace("sphere.toml", "nothing.toml"))
    with pytest.raises(InputError, match="simulation.metal"):
        read_tracker(tmp_path / "bad2.toml")
