"""The hostile live cases of ``openemt bench fuzz`` run and hold (a short sample of them)."""

from __future__ import annotations

from openemt_fuzz._fuzzhostile_live import fuzz_live


def test_hostile_live_cases_hold():
    out = fuzz_live(3, seed=1, kinds=("sigterm", "stall_never", "sigkill"), max_delay=2.0,
                    time_limit=60.0)
    assert out["cases"] == 3
    assert sum(sum(c.values()) for c in out["by_kind"].values()) == 3
    assert out["findings"] == 0, out["examples"]
    assert out["by_kind"]["stall_never"] == {"held": 1}
