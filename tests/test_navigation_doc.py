"""docs/navigation.md: the worked example runs as written and prints what the page says, and
the command block runs verbatim, each command on the files of the commands before it."""

import contextlib
import io
import json
import re
import shlex
from pathlib import Path

import numpy as np

from openemt.cli import main

DOC = Path(__file__).resolve().parents[1] / "docs" / "navigation.md"


def test_worked_example_prints_what_the_page_says():
    text = DOC.read_text()
    code = re.search(r"## Worked example.*?```python\n(.*?)```", text, re.DOTALL).group(1)
    printed = re.search(r"It prints\n\n```\n(.*?)```", text, re.DOTALL).group(1)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(code, str(DOC), "exec"), {})
    assert out.getvalue() == printed


def test_page_commands_run_on_files_of_the_steps_before(tmp_path, monkeypatch, capsys):
    """The command block, run verbatim in an empty folder: each command reads only files that
    a command before it wrote; the answers agree with the simulation's truth."""
    text = DOC.read_text()
    block = text[text.index("The same path with the commands"):]
    block = re.search(r"```bash\n(.*?)```", block, re.DOTALL).group(1)
    monkeypatch.chdir(tmp_path)
    out = {}
    for line in block.splitlines():
        argv = shlex.split(line)
        assert argv[0] == "openemt"
        rc = main(argv[1:])
        cap = capsys.readouterr()
        assert rc == 0, f"{line}\n{cap.err}"
        out[argv[1] + (":" + argv[2] if argv[1] == "points" else "")] = \
            json.loads(cap.out) if "--json" in argv else None
    truth = {m: json.loads((tmp_path / f"{m}.truth.json").read_text())
             for m in ("pivot", "spin", "touch", "grid")}
    pivot = out["pivot"]
    assert pivot["warnings"] == [] and pivot["dropped"]["not_converged"] == 0
    np.testing.assert_allclose(pivot["tip_mm"], truth["pivot"]["tip_mm"], atol=1.5)
    np.testing.assert_allclose(pivot["pivot_mm"], truth["pivot"]["pivot_mm"], atol=1.5)
    assert np.dot(out["spin"]["axis"], truth["spin"]["axis_tool"]) > np.cos(np.deg2rad(1.0))
    touched = out["points:touch.csv"]
    assert touched["n_points"] == 6 and touched["labels"][0] == "F-1"
    reg = out["register"]
    assert reg["paired_by"] == "label" and reg["fre_rms_mm"] < 1.0 and reg["warnings"] == []
    T, T_true = np.array(reg["transform"]), np.array(truth["touch"]["image_from_tracker"])
    f = 1e-3 * np.array(truth["touch"]["fiducials_tracker_mm"])
    moved = f @ T[:3, :3].T + T[:3, 3] - (f @ T_true[:3, :3].T + T_true[:3, 3])
    assert np.linalg.norm(moved, axis=1).max() < 2e-3
    assert (tmp_path / "reg.tfm").read_text().startswith("#Insight Transform File V1.0")
    assess = out["assess"]
    assert assess["n"] == 18 and assess["rigid_rms_mm"] < 1.0
    assert (tmp_path / "grid.html").is_file()
