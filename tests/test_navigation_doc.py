"""docs/navigation.md: the worked example runs as written and prints what the page says, and
the commands shown on the page run on files written from the same simulation."""

import contextlib
import io
import json
import re
import shlex
from pathlib import Path

import numpy as np

from openemt.cli import main
from openemt.io import write_poses_csv
from openemt.navigate import (
    regular_grid,
    simulate_grid_points,
    simulate_pivot_poses,
    simulate_spin_poses,
)

DOC = Path(__file__).resolve().parents[1] / "docs" / "navigation.md"


def test_worked_example_prints_what_the_page_says():
    text = DOC.read_text()
    code = re.search(r"## Worked example.*?```python\n(.*?)```", text, re.DOTALL).group(1)
    printed = re.search(r"It prints\n\n```\n(.*?)```", text, re.DOTALL).group(1)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(code, str(DOC), "exec"), {})
    assert out.getvalue() == printed


def _points_csv(path, pts):
    path.write_text("x_mm,y_mm,z_mm\n" + "".join(f"{a},{b},{c}\n" for a, b, c in 1e3 * pts))


def test_page_commands_run(tmp_path, monkeypatch, capsys):
    rng = np.random.default_rng(1)
    tip = np.array([0.002, -0.001, 0.155])
    write_poses_csv(tmp_path / "pivot.csv", simulate_pivot_poses(50, tip, [0.1, 0, 0.2], rng,
                                                                 n_outliers=3))
    write_poses_csv(tmp_path / "spin.csv",
                    simulate_spin_poses(40, tip / np.linalg.norm(tip), [0, 0, 0], rng))
    image = rng.uniform(-0.08, 0.08, (6, 3))
    _points_csv(tmp_path / "image_fiducials.csv", image)
    lps = 1e3 * (image + [0.01, 0.02, 0.03] + rng.normal(0, 2e-4, image.shape)) * [-1, -1, 1]
    (tmp_path / "tracker_fiducials.fcsv").write_text(
        "# Markups fiducial file version = 4.11\n# CoordinateSystem = LPS\n"
        "# columns = id,x,y,z,ow,ox,oy,oz,vis,sel,lock,label,desc,associatedNodeID\n"
        + "".join(f"{i},{p[0]},{p[1]},{p[2]},0,0,0,1,1,1,0,F-{i},,\n" for i, p in enumerate(lps)))
    _points_csv(tmp_path / "target.csv", np.array([[0.0, 0.0, 0.05]]))
    nominal = regular_grid(0.05, (4, 4, 2))
    pts, hole = simulate_grid_points(nominal, rng, noise=2e-4, repeats=2)
    perm = rng.permutation(len(pts))
    cps = [{"label": f"P{h}", "position": list(1e3 * p), "positionStatus": "defined"}
           for p, h in zip(pts[perm], hole[perm])]
    (tmp_path / "grid.mrk.json").write_text(json.dumps(
        {"markups": [{"type": "Fiducial", "coordinateSystem": "RAS", "controlPoints": cps}]}))
    text = DOC.read_text()
    block = text[text.index("The same with the commands"):]
    block = re.search(r"```bash\n(.*?)```", block, re.DOTALL).group(1)
    monkeypatch.chdir(tmp_path)
    out = []
    for line in block.splitlines():
        argv = shlex.split(line)
        assert argv[0] == "openemt"
        rc = main(argv[1:])
        cap = capsys.readouterr()
        assert rc == 0, f"{line}\n{cap.err}"
        out.append(json.loads(cap.out))
    pivot, spin, reg, assess = out
    assert pivot["n_inliers"] == 47
    assert spin["axis"][2] > 0.99
    assert reg["fre_rms_mm"] < 1.0 and len(reg["predicted_tre_mm"]) == 1
    assert assess["n"] == 32 and assess["jitter"]["n_samples"] == 64
    assert (tmp_path / "grid.html").is_file()
