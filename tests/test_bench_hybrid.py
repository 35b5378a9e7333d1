"""``openemt bench hybrid`` (tiny version): alignment + auto correction never end worse than
no correction, and approach the noise floor with enough pairs."""

import argparse

from openemt.bench import _hybrid


def test_bench_hybrid_small():
    out = _hybrid.run(argparse.Namespace(pairs="10,60", folds=3, seed=1))
    assert [r["pairs"] for r in out["rows"]] == [10, 60]
    assert out["all_auto_not_worse"]
    for r in out["rows"]:
        t = r["test"]
        assert t["corrected"]["trans_rms_mm"] <= t["uncorrected"]["trans_rms_mm"] + 1e-9
        assert r["held_out"]["chosen"]["trans_rms_mm"] <= r["held_out"]["none"]["trans_rms_mm"]
        assert t["floor"]["trans_rms_mm"] < t["corrected"]["trans_rms_mm"] + 1e-9
    big = out["rows"][1]
    assert big["chosen"] != "none"
    assert big["test"]["corrected"]["trans_rms_mm"] < 0.5 * big["test"]["uncorrected"]["trans_rms_mm"]
    assert big["align"]["X_max_abs_z_vs_limit"] < 4
