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
    per = set()

    def fake(cache_dir, what="kernels"):
        if what == "per_kernel":        # a cache of its own, compiled then loaded
            t = 2.0 if cache_dir not in per else 0.01
            per.add(cache_dir)
            return {"a:k": {"s": t, "cpu_s": t}, "b:k": {"s": t / 2, "cpu_s": t / 2},
                    "process_wall_s": 3.0}
        seen.append(cache_dir)
        t = 10.0 if len(seen) == 1 else 0.1
        return {"import_s": 0.5, "kernels_s": dict.fromkeys(_compile.KERNELS, t),
                "total_s": t * 6, "kernels_cpu_s": dict.fromkeys(_compile.KERNELS, t),
                "total_cpu_s": t * 6, "process_wall_s": t * 6 + 1}

    monkeypatch.setattr(_compile, "_process", fake)
    out = _compile.run(argparse.Namespace(keep_cache=str(tmp_path / "cache")))
    assert seen[0] == seen[1] == str(tmp_path / "cache")
    assert out["compile_total_s"] == 60.0 and out["cached_total_s"] == pytest.approx(0.6)
    assert out["per_kernel"] == {"a:k": {"compile_s": 2.0, "compile_cpu_s": 2.0,
                                         "cached_s": 0.01},
                                 "b:k": {"compile_s": 1.0, "compile_cpu_s": 1.0,
                                         "cached_s": 0.005}}
    assert out["per_kernel_compile_cpu_s"] == 3.0
    assert "first_demo_cpu_s" not in out                      # only with --commands
    (tmp_path / "cache" / "x").write_text("")
    with pytest.raises(InputError, match="empty folder"):
        _compile.run(argparse.Namespace(keep_cache=str(tmp_path / "cache")))


def test_per_kernel_child_lists_every_announced_kernel():
    from openemt._compile_notice import (
        BOARD_LM_KERNELS,
        COLD_START_KERNELS,
        INDUCED_DIPOLE_KERNELS,
        LIVE_KERNELS,
        PLANAR_KERNELS,
        SOLVER_KERNELS,
    )

    out = _compile._child_per_kernel()
    assert list(out) == list(dict.fromkeys(SOLVER_KERNELS + COLD_START_KERNELS + LIVE_KERNELS
                                           + PLANAR_KERNELS + INDUCED_DIPOLE_KERNELS
                                           + BOARD_LM_KERNELS))
    assert all(v["s"] >= 0 and v["cpu_s"] >= 0 for v in out.values())


def test_command_timing_counts_the_child_process(tmp_path):
    out = _compile._command(["info", "--help"], str(tmp_path / "cache"), str(tmp_path))
    assert out["cpu_s"] > 0 and out["wall_s"] >= 0 and out["compile_notice"] is False
    with pytest.raises(RuntimeError, match="failed"):
        _compile._command(["info", str(tmp_path / "missing.h5")], str(tmp_path / "cache"),
                          str(tmp_path))
