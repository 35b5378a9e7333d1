"""``openemt bench compile`` measures in fresh processes (a command, not a test); here its
measuring function runs in this process and the summary is checked with the processes stubbed."""

from __future__ import annotations

import argparse

import pytest

from openemt._errors import InputError
from openemt.bench import _compile


def test_child_times_every_kernel():
    out = _compile._child()
    assert set(out["kernels_s"]) == set(_compile.KERNELS) == set(out["kernels_cpu_s"])
    assert all(v >= 0 for v in out["kernels_s"].values())
    assert out["total_s"] == pytest.approx(sum(out["kernels_s"].values()))


def test_run_reports_first_use_and_cached(monkeypatch, tmp_path):
    seen = []

    def fake(cache_dir):
        seen.append(cache_dir)
        t = 10.0 if len(seen) == 1 else 0.1
        return {"import_s": 0.5, "kernels_s": dict.fromkeys(_compile.KERNELS, t),
                "total_s": t * 6, "kernels_cpu_s": dict.fromkeys(_compile.KERNELS, t),
                "total_cpu_s": t * 6, "process_wall_s": t * 6 + 1}

    monkeypatch.setattr(_compile, "_process", fake)
    out = _compile.run(argparse.Namespace(keep_cache=str(tmp_path / "cache")))
    assert seen[0] == seen[1] == str(tmp_path / "cache")
    assert out["compile_total_s"] == 60.0 and out["cached_total_s"] == pytest.approx(0.6)
    (tmp_path / "cache" / "x").write_text("")
    with pytest.raises(InputError, match="empty folder"):
        _compile.run(argparse.Namespace(keep_cache=str(tmp_path / "cache")))
