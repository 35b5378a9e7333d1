"""The solver benchmarks run end to end on small sample counts (the full runs are commands)."""

from __future__ import annotations

import argparse

import numpy as np

from openemt.bench import _noise, _speed


def test_noise_bench_small(tmp_path):
    args = argparse.Namespace(samples=300, seed=1, snr_per="signal",
                              figure=str(tmp_path / "fig.png"))
    out = _noise.run(args)
    assert out["snr_db"] == [20, 40, 60, 80, 100]
    for name in ("svd", "kuipers", "kim18", "lm"):
        s = out["solvers"][name]
        for key in ("position_rms_mm", "rotation_rms_deg", "distance_rms_mm"):
            assert len(s[key]) == 5
            # errors fall by ~10x per 20 dB (Kuipers' element-wise Euler read-out of a
            # non-orthogonal matrix amplifies noise near gimbal lock, so not its rotation)
            if not (name == "kuipers" and key == "rotation_rms_deg"):
                assert s[key][0] > s[key][-1] * 1e3
        # machine precision without noise
        assert out["noiseless"][name]["position_rms_mm"] < 1e-9
    assert out["noiseless"]["lm"]["rotation_rms_deg"] < 1e-9
    for key in ("position_rms_mm", "rotation_rms_deg"):
        assert len(out["crb"][key]) == 5
    # the LM estimate is efficient at high SNR (loose bound for 300 samples)
    for snr in ("60", "80", "100"):
        ratio = out["checks"]["lm_over_sqrt_crb"][snr]
        assert 0.8 < ratio["position"] < 1.25 and 0.8 < ratio["rotation"] < 1.25
    assert (tmp_path / "fig.png").stat().st_size > 1000


def test_speed_bench_small():
    args = argparse.Namespace(samples=500, baseline_samples=3, repeats=1, snr_db=80.0, seed=0)
    out = _speed.run(args)
    for key in ("lm_tracking_poses_per_s", "lm_cold_poses_per_s", "svd_poses_per_s",
                "kuipers_poses_per_s", "kim18_poses_per_s", "scipy_per_pose_poses_per_s",
                "lm_vs_scipy_ratio", "max_position_diff_m"):
        assert np.isfinite(out[key]) and out[key] >= 0
    assert out["max_position_diff_m"] < 1e-9
    assert out["lm_tracking_status_counts"]["converged"] == 500
