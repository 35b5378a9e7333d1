"""Raw HDF5 recordings: round trip and one-line errors for bad files."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from openemt.field import DipoleModel
from openemt.geometry import pose_from_vector
from openemt.signal import ChannelLayout, RawSignalConfig, read_raw, simulate_raw, write_raw

POSE = pose_from_vector(np.array([0.2, 0.01, -0.03, 0.1, 0.2, -0.3]))


def _raw(seed=0):
    lay = ChannelLayout(sensor_channels=(3, 4, 5), reference_channels=(0, 1, 2), sensor_gain=2.0)
    return simulate_raw(DipoleModel.concentric(), POSE, 0.01, RawSignalConfig(layout=lay),
                        seed=seed)


def test_round_trip(tmp_path):
    raw = _raw()
    path = tmp_path / "rec.h5"
    write_raw(raw, path)
    back = read_raw(path)
    np.testing.assert_array_equal(back.samples, raw.samples)
    assert back.layout == raw.layout
    np.testing.assert_array_equal(back.truth_couplings, raw.truth_couplings)
    np.testing.assert_array_equal(back.truth_poses, raw.truth_poses)
    np.testing.assert_array_equal(back.truth_times, raw.truth_times)
    assert [p.name for p in tmp_path.iterdir()] == ["rec.h5"]     # no temp file left


def test_simulation_is_seeded():
    np.testing.assert_array_equal(_raw(3).samples, _raw(3).samples)
    assert not np.array_equal(_raw(3).samples, _raw(4).samples)


def _one_line_value_error(path):
    with pytest.raises(ValueError) as info:
        read_raw(path)
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith("expected")
    return msg


def test_corrupt_files_give_one_line_errors(tmp_path):
    garbage = tmp_path / "garbage.h5"
    garbage.write_bytes(np.random.default_rng(0).bytes(4096))
    assert "readable" in _one_line_value_error(garbage)

    wrong = tmp_path / "wrong.h5"
    with h5py.File(wrong, "w") as f:
        f["x"] = np.zeros(3)
    assert "format" in _one_line_value_error(wrong)

    raw = _raw()
    trunc = tmp_path / "trunc.h5"
    write_raw(raw, trunc)
    data = trunc.read_bytes()
    trunc.write_bytes(data[: len(data) // 2])
    _one_line_value_error(trunc)

    nan = tmp_path / "nan.h5"
    write_raw(raw, nan)
    with h5py.File(nan, "r+") as f:
        f["samples"][5, 1] = np.nan
    assert "finite" in _one_line_value_error(nan)

    nokey = tmp_path / "nokey.h5"
    write_raw(raw, nokey)
    with h5py.File(nokey, "r+") as f:
        del f["samples"]
    _one_line_value_error(nokey)

    with pytest.raises(FileNotFoundError):
        read_raw(tmp_path / "missing.h5")


def test_config_validation():
    with pytest.raises(ValueError, match="noise_rms"):
        RawSignalConfig(noise_rms=-1)
    with pytest.raises(ValueError, match="drive phases"):
        RawSignalConfig(drive_phase=(0.0, 1.0))
    with pytest.raises(TypeError, match="ChannelLayout"):
        RawSignalConfig(layout="x")
    with pytest.raises(ValueError, match="sources"):
        simulate_raw(DipoleModel.concentric(M_so=np.eye(3)[:, :2]), POSE, 0.01)
