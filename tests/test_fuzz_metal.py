"""Generated metal scenes: refused in one line or evaluated to finite couplings."""

from __future__ import annotations

from openemt_fuzz._fuzzmetal import fuzz_metal


def test_generated_metal_scenes_hold():
    out = fuzz_metal(40, seed=3)
    assert out["findings"] == 0, out["examples"]
    assert out["refused"] > 0 and out["evaluated"] > 0
    assert out["refused"] + out["evaluated"] == 40
