"""Generated carrier-band inputs: refused in one line, or couplings to solve that are finite
where the bands are and the same block by block as whole."""

from __future__ import annotations

from openemt_fuzz._fuzzbands import fuzz_bands


def test_generated_band_inputs_hold():
    out = fuzz_bands(300, seed=4)
    assert out["findings"] == 0, out["examples"]
    assert out["refused"] > 0 and out["evaluated"] > 100
