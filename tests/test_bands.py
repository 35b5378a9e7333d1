"""Carrier bands: simulated per band, the eddy part taken out from two bands, band fusion."""

from __future__ import annotations

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
    assert data.meta["truth"]["band_frequencies_hz"] == BANDS
    # the slow band sees less eddy current than the fast one, the extrapolation far less
    err = [np.abs(C - clean.couplings).max() for C in (B[:, 1].real, B[:, 0].real,
                                                        eddy_free_couplings(B, BANDS))]
    assert err[1] < err[0] / 3 and err[2] < err[0] / 50, err
    one = simulate("dipole-approx", "md", **kw)
    assert "couplings_bands" not in one.extra


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
