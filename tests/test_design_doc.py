"""docs/design.md: the worked example (Anser board -> optimised board) runs as written, and
what its text says holds."""

import json
import re
import shlex
from pathlib import Path

from openemt.cli import main

DOC = Path(__file__).resolve().parents[1] / "docs" / "design.md"


def _commands():
    text = DOC.read_text()
    block = re.search(r"<!-- worked-example -->\s*```bash\n(.*?)```", text, flags=re.DOTALL)
    assert block, "docs/design.md lost its worked-example block"
    return [shlex.split(ln) for ln in block.group(1).splitlines() if ln.strip()]


def test_worked_example_runs_as_written(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    out = []
    for argv in _commands():
        assert argv[0] == "openemt"
        rc = main(argv[1:])
        cap = capsys.readouterr()
        assert rc == 0, f"{' '.join(argv)}\n{cap.err}"
        out.append(json.loads(cap.out))
    start, opt, again, sim, every, rig, rig_map = out
    # the Monte Carlo agrees with the bound (raw signals, demodulated, solved)
    for m in (start, again):
        assert abs(m["montecarlo_ratio_median"] - 1) < 0.1, m["montecarlo"]
        assert "raw ADC samples" in m["montecarlo"]["noise"]
    # the optimised board is better at the 95th percentile, and its own map says so
    assert opt["improvement_p95"] > 0.05
    assert again["position_mm"]["p95"] < start["position_mm"]["p95"]
    assert abs(again["position_mm"]["p95"] - opt["optimized"]["position_mm"]["p95"]) < 1e-9
    assert abs(start["position_mm"]["p95"] - opt["start"]["position_mm"]["p95"]) < 1e-9
    assert sim["n_samples"] == 49
    assert (tmp_path / "anser-map.html").stat().st_size > 10_000
    assert (tmp_path / "anser-opt.html").stat().st_size > 10_000
    # sizes and turns within the start's drive power; the rig source's calibration file
    assert every["power"]["ratio"] <= 1 + 1e-9 and every["improvement_p95"] > 0.05
    assert abs(rig["power"]["ratio"] - 1) < 1e-9 and rig["improvement_p95"] > 0.05
    assert abs(rig_map["position_mm"]["p95"] - rig["optimized"]["position_mm"]["p95"]) < 1e-9
    assert rig_map["kind"] == "calibration" and abs(rig_map["montecarlo_ratio_median"] - 1) < 0.1
