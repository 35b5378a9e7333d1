"""``openemt bench correct``: held-out errors expose overfitting on a known distortion."""

import argparse

from openemt.bench import _correct


def test_bench_correct_small():
    out = _correct.run(argparse.Namespace(samples=150, folds=3, seed=2))
    unc = out["uncorrected"]["trans_rms_mm"]
    poly = out["methods"]["poly"]
    # the polynomial removes most of the distortion, also on data it did not see
    assert poly["held_out"]["trans_rms_mm"] < 0.5 * unc
    assert poly["held_out"]["rot_rms_deg"] < 0.5 * out["uncorrected"]["rot_rms_deg"]
    # an interpolating RBF is perfect in sample and much worse held out
    rbf = out["forced_overfit"]["rbf_no_smoothing"]
    assert rbf["in_sample"]["trans_rms_mm"] < 1e-3
    assert rbf["held_out"]["trans_rms_mm"] > out["noise_floor"]["trans_rms_mm"]
    for m in out["methods"].values():
        assert m["held_out"]["trans_rms_mm"] >= 0.9 * m["in_sample"]["trans_rms_mm"]
