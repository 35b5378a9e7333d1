"""The real ILEMT couplings: their quadrature is mostly a fixed chain phase ("Ref cal")."""

from __future__ import annotations

import numpy as np

from openemt.io import read_ilemt_dat
from openemt.signal import Demodulated, phase_calibration


def _ratio(C):
    return Demodulated(C, np.zeros(len(C)), np.ones((len(C), 3))).distortion_ratio()


def test_phase_calibration_on_real_couplings(ilemt_dir):
    files = sorted(ilemt_dir.glob("*_md.dat"))
    assert len(files) >= 5
    ref = read_ilemt_dat(files[0]).couplings
    # docs/ilemt-data.md#dat-format: good values are nearly real, max |Im| / max |C| of 0.2-1 %
    assert 0.002 < np.abs(ref.imag).max() / np.abs(ref).max() < 0.01
    phase = phase_calibration(ref)
    assert np.abs(phase).max() < 0.05                 # a few mrad per (source, sensor) entry
    rotated = ref * np.exp(-1j * phase)
    np.testing.assert_allclose(np.abs(rotated), np.abs(ref), rtol=1e-12)
    # the signed real coupling keeps its sign: the phase is removed modulo pi
    assert np.array_equal(np.sign(rotated.real), np.sign(ref.real))
    assert np.median(_ratio(rotated)) < np.median(_ratio(ref)) / 5
    # the same phase applied to the other fixture files of the session lowers their quadrature
    for f in files[1:]:
        C = read_ilemt_dat(f).couplings
        assert np.median(_ratio(C * np.exp(-1j * phase))) < np.median(_ratio(C))
