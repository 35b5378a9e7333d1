"""``openemt bench metal`` with two carrier bands: the conductive-only scenes whose eddy part
the bands separate (stainless ring, titanium disk) lose most of their error without any
calibration of the object; the aluminium sheet does not, and the bench says why."""

import argparse

from openemt.bench import _metal


def _args(**kw):
    base = dict(train=20, test=24, noise=1e-4, max_dipoles=0, witnesses=4, period=120.0,
                scenes="stainless_ring,titanium_disk,aluminium_sheet", seed=2,
                sheet_searches=0)
    return argparse.Namespace(**{**base, **kw})


def test_two_bands_on_conductive_scenes():
    out = _metal.run(_args())
    for name in ("stainless_ring", "titanium_disk"):
        s = out["scenes"][name]
        assert s["uncompensated_rms_mm"] > 5 * s["compensated_rms_mm"]["two_band"], s
        assert out["targets"][f"{name}_two_band_5x"] is True
        assert set(s["bands"]) == {"fast", "slow", "eddy_free", "sheet"}
        assert "note" not in s                          # no infinite sheet
    sheet = out["scenes"]["aluminium_sheet"]
    note = sheet["note"]
    # both bands inductive: the thin-sheet parameter well above 1 at the slow band
    assert note["thin_sheet_parameter"]["slow"] > 3
    assert note["thin_sheet_parameter"]["fast"] > 30 * note["thin_sheet_parameter"]["slow"]
    assert 5 < note["slow_band_hz_for_parameter_0.25"] < 50
    assert "inductive" in note["text"]
    assert out["targets"]["aluminium_sheet_two_band_5x"] is False
    # no search allowed here (tests/test_bench_metal.py runs the sheet fit on this scene): every
    # flagged sample keeps the eddy-free couplings
    assert sheet["sheet_fit"] == {"n_flagged": 24, "n_fitted": 0}
    assert sheet["compensated_rms_mm"]["two_band_sheet"] == \
        sheet["compensated_rms_mm"]["two_band"]
