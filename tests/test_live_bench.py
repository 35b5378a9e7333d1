"""Benchmark modules run end to end on short inputs (numbers checked are physics, not speed)."""

from __future__ import annotations

import argparse
import sys
import types

import numpy as np
import pytest
from _counts import converged_only

from openemt.bench import _demod, _track


def _args(mod, argv):
    p = argparse.ArgumentParser()
    mod.add_arguments(p)
    return p.parse_args(argv)


def test_bench_demod_keys_and_physics():
    out = _demod.run(_args(_demod, ["--seconds", "0.3", "--repeats", "1"]))
    assert out["realtime_factor"] > 0 and out["speedup_vs_baseline"] > 0
    assert out["baseline_max_abs_difference"] < 1e-12      # same estimator as the baseline
    assert out["mains_rejection_db"]["hann_50hz"] > 60
    assert out["amplitude_error_rel_max"]["hann"]["static"] < 1e-10
    n = out["noise_coupling_rms"]["hann"]
    assert n["measured"] == pytest.approx(n["predicted"], rel=0.1)


def test_bench_track_noise_matches_cramer_rao():
    out = _track.run(_args(_track, ["--seconds", "0.2", "--noise-seconds", "0.5",
                                    "--tools-seconds", "0", "--acquire-seconds", "0"]))
    for key in ("latency_ms_p50", "latency_ms_p99", "position_noise_um",
                "crb_position_noise_um"):
        assert np.isfinite(out[key])
    e2e = out["latency_end_to_end_ms"]
    assert 0 < e2e["p50"] <= e2e["p99"] <= e2e["max"]
    assert out["igtl"]["sent"] > 0
    # the LM solution of the demodulated couplings is efficient: noise at the bound
    assert 0.8 < out["noise_to_crb_ratio"] < 1.2
    # and the bound from the simulator's noise setting alone agrees with the measured one
    assert out["crb_position_noise_um_from_spec"] == pytest.approx(
        out["crb_position_noise_um"], rel=0.1)
    assert 0.5 < out["position_noise_um"] < 10


def test_sounddevice_backend_with_a_stand_in_module(monkeypatch):
    from openemt.live import SoundDeviceBackend
    from openemt.signal import ChannelLayout

    streams = []

    class InputStream:
        def __init__(self, samplerate, channels, dtype, blocksize, device, callback):
            self.callback, self.channels, self.blocksize = callback, channels, blocksize
            self.started = self.closed = False
            streams.append(self)

        def start(self):
            self.started = True

        def stop(self):
            self.started = False

        def close(self):
            self.closed = True

    monkeypatch.setitem(sys.modules, "sounddevice", types.SimpleNamespace(InputStream=InputStream))
    b = SoundDeviceBackend(ChannelLayout(), chunk=64, timeout=0.01, max_blocks=2)
    s = streams[0]
    assert s.started and s.channels == 6
    blocks = [np.full((64, 6), k, np.float32) for k in range(4)]
    for blk in blocks:                      # the audio thread delivers 4 blocks, 2 fit
        s.callback(blk, 64, None, None)
    assert b.n_overflow == 2
    np.testing.assert_array_equal(b.read(), blocks[0])
    np.testing.assert_array_equal(b.read(), blocks[1])
    # nothing within the timeout: an empty block, not the end of the stream
    assert b.read().shape == (0, 6)
    b.close()
    assert s.closed
    assert b.read() is None                 # closed: the end


def test_sounddevice_missing_is_a_clear_error(monkeypatch):
    from openemt.live import SoundDeviceBackend
    from openemt.signal import ChannelLayout

    monkeypatch.setitem(sys.modules, "sounddevice", None)
    with pytest.raises(ImportError, match="openemt\\[sound\\]"):
        SoundDeviceBackend(ChannelLayout())


def test_bench_track_several_sensors_and_filter():
    out = _track.run(_args(_track, ["--seconds", "0.2", "--noise-seconds", "0.4", "--sensors",
                                    "2", "--rate-seconds", "0.2", "--tools-seconds", "0",
                                    "--acquire-seconds", "0"]))
    assert out["sensors"] == 2
    assert out["status_counts"] == converged_only(2 * round(out["signal_seconds"] * 1500))
    assert out["igtl"]["sent"] > 0 and out["igtl"]["clients_max"] == 1
    assert out["realtime_factor"] > 0 and out["realtime_status_counts"] == converged_only(
        2 * round(out["realtime_signal_seconds"] * 1500))
    assert out["realtime_baseline"]["status_counts"] == out["realtime_status_counts"]
    assert out["igtl_pack_us_per_message"] > 0 and out["igtl_pack_us_per_message_pyigtl"] > 0
    f = out["filter"]
    assert f["position_noise_um_filtered"] < 0.8 * f["position_noise_um"]
    assert abs(f["added_lag_ms"]) < 1.0 and 0 < f["step_settle_ms"] < 20
    with pytest.raises(ValueError, match="--sensors"):
        _track.run(_args(_track, ["--sensors", "0"]))


def test_bench_track_acquisition_section():
    out = _track._acquisition(0.4, 0)
    sim, ser, tcp = out["sim"], out["serial"], out["tcp"]
    assert ser["position_error_mm_rms"] == pytest.approx(sim["position_error_mm_rms"], rel=0.05)
    assert tcp["position_error_mm_rms"] == pytest.approx(sim["position_error_mm_rms"], rel=0.05)
    assert ser["max_pose_difference_m"] < 1e-8
    d = out["damaged"]
    assert d["frames_damaged"] > 0 and d["link"]["gaps"] > 0 and d["link"]["crc_errors"] > 0
    assert d["position_error_mm_max"] < 0.05
    p = out["paced"]
    assert p["acquisition_time_error_ms"]["max"] < p["output_period_ms"]
    assert 0 < p["latency_end_to_end_ms"]["p50"] <= p["latency_end_to_end_ms"]["p99"]
