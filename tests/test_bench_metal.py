"""``openemt bench metal``: environment terms fitted with the metal in place take out most of
an aluminium sheet's distortion; nothing makes the clean workspace worse; the distortion level
tells the distorted samples from the clean ones."""

import argparse

import numpy as np
import pytest

from openemt._errors import InputError
from openemt.bench import _metal


def _args(**kw):
    base = dict(train=40, test=16, noise=1e-4, max_dipoles=1, witnesses=4, period=120.0,
                scenes="clean,aluminium_sheet", seed=1)
    return argparse.Namespace(**{**base, **kw})


def test_bench_metal_small():
    out = _metal.run(_args())
    clean, sheet = out["scenes"]["clean"], out["scenes"]["aluminium_sheet"]
    assert set(sheet["compensated_rms_mm"]) == {"environment", "two_band", "two_band_cole_cole",
                                                "two_band_sheet"}
    # two bands, no calibration of the object: the sheet fitted with each sample's pose
    assert sheet["uncompensated_rms_mm"] > 5 * sheet["compensated_rms_mm"]["two_band_sheet"]
    assert out["targets"]["aluminium_sheet_two_band_sheet_5x"] is True
    assert sheet["sheet_fit"] == {"n_flagged": 16, "n_fitted": 16}
    assert clean["sheet_fit"] == {"n_flagged": 0, "n_fitted": 0}
    # one induced dipole already takes out most of the sheet's image field
    assert sheet["environment"]["dipoles"] == 1
    assert sheet["uncompensated_rms_mm"] > 10 * sheet["compensated_rms_mm"]["environment"]
    # the clean workspace: no term is kept and the gated two-band method changes nothing
    assert clean["environment"]["dipoles"] == 0
    assert all(v <= 1.05 * clean["uncompensated_rms_mm"]
               for v in clean["compensated_rms_mm"].values())
    assert clean["roc_auc"] is None                       # no distorted sample there
    assert sheet["roc_auc"] >= 0.95 and out["roc_auc_pooled"] >= 0.95


def test_roc_auc_is_the_mann_whitney_statistic():
    assert _metal.roc_auc([1, 2, 3, 4], [False, False, True, True]) == 1.0
    assert _metal.roc_auc([1, 1, 1, 1], [False, False, True, True]) == 0.5
    assert _metal.roc_auc([4, 3, 2, 1], [False, False, True, True]) == 0.0
    assert _metal.roc_auc([1, 2], [True, True]) is None
    rng = np.random.default_rng(0)
    s, p = rng.normal(size=200), rng.random(200) < 0.5
    pairs = np.mean([(a > b) + 0.5 * (a == b) for a in s[p] for b in s[~p]])
    assert _metal.roc_auc(s, p) == pytest.approx(pairs)


def test_bench_metal_refuses_unknown_scenes():
    with pytest.raises(InputError, match="--scenes"):
        _metal.run(_args(scenes="lead_box"))
