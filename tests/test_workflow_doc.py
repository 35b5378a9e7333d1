"""docs/workflow.md: the whole path, bare tracker to tool tip in image coordinates, runs verbatim
in an empty folder; an OpenIGTLink client connected to the last step receives the tool and its
tip in the image frame, consistent with the pivot calibration, and the page's counts hold."""

from __future__ import annotations

import json
import os
import re
import shlex
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from _igtl_listener import Listener

from openemt.cli import main

DOC = Path(__file__).resolve().parents[1] / "docs" / "workflow.md"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _block() -> list[str]:
    text = DOC.read_text()
    return re.search(r"```bash\n(.*?)```", text, re.DOTALL).group(1).splitlines()


def test_the_page_states_its_counts():
    lines = _block()
    counts = re.search(r"\*\*(\d+) commands, (\d+) files written\*\*", DOC.read_text())
    assert int(counts.group(1)) == len(lines) <= 10
    assert all(shlex.split(line)[0] == "openemt" for line in lines)
    outputs = set()
    for line in lines:
        argv = shlex.split(line)
        outputs |= {argv[i + 1] for i, a in enumerate(argv) if a in ("-o", "--log",
                                                                      "--slicer-transform")}
    # plus the simulator's truth and image-fiducial files beside its logs
    assert int(counts.group(2)) == len(outputs) + 3


def test_the_workflow_runs_verbatim(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    *steps, track = _block()
    out = {}
    for line in steps:
        argv = shlex.split(line)
        rc = main(argv[1:])
        cap = capsys.readouterr()
        assert rc == 0, f"{line}\n{cap.err}"
        out[argv[1] + (":" + argv[3] if argv[1] == "simulate" else "")] = json.loads(cap.out)
    assert out["collect"]["n_poses"] == 30
    held = out["calibrate"]
    assert held["holdout"]["n"] >= 5 and held["holdout"]["trans_rms_mm"] < 0.5
    truth = json.loads((tmp_path / "pivot.truth.json").read_text())
    np.testing.assert_allclose(out["pivot"]["tip_mm"], truth["tip_mm"], atol=2.0)
    assert out["points"]["n_points"] == 6
    assert out["register"]["paired_by"] == "label" and out["register"]["fre_rms_mm"] < 1.0
    files = sorted(p.name for p in tmp_path.iterdir())

    # the last step in its own process, as a user runs it, with a viewer connected; on a free
    # port instead of Slicer's 18944 (a later --igtl-port wins), which a running Slicer or
    # another test run may hold
    port = _free_port()
    argv = shlex.split(track) + ["--igtl-port", str(port)]
    code = "import sys; from openemt.cli import main; sys.exit(main(sys.argv[1:]))"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    proc = subprocess.Popen([sys.executable, "-c", code, *argv[1:]], cwd=tmp_path, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    devices = ("SensorToImage", "SensorTipToImage")
    viewer = None
    try:
        deadline = time.monotonic() + 60
        while viewer is None and time.monotonic() < deadline and proc.poll() is None:
            try:
                viewer = Listener(port, devices)
            except OSError:
                time.sleep(0.2)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
        if viewer is not None:
            time.sleep(0.2)
            viewer.stop()
    assert proc.returncode == 0, stderr
    assert "OpenIGTLink: serving TRANSFORM 'SensorToImage'" in stderr
    summary = json.loads(stdout)
    kinds = {s["device"]: (s["kind"], s["frame"], s["units"]) for s in summary["streams"]}
    assert kinds == {"SensorToImage": ("tool", "Image", "mm"),
                     "SensorTipToImage": ("tip", "Image", "mm")}
    assert viewer is not None
    tool = dict(viewer.got["SensorToImage"])
    tip = dict(viewer.got["SensorTipToImage"])
    both = sorted(set(tool) & set(tip))
    assert len(both) >= 20, (len(tool), len(tip))
    # what the client receives: the tip is the tool's pose applied to the pivot's tip offset
    tip_mm = np.array(out["pivot"]["tip_mm"])
    for t in both[:: max(1, len(both) // 50)]:
        expected = tool[t][:3, :3] @ tip_mm + tool[t][:3, 3]
        np.testing.assert_allclose(tip[t][:3, 3], expected, atol=0.01)
    # and the image frame is the registration's: back in the tracker frame, the tool is where
    # the simulated sensor moves (tens of cm from the source, not at the image's origin)
    reg = np.array(out["register"]["transform"])
    pos = np.array([tool[t][:3, 3] for t in both]) * 1e-3
    in_tracker = (pos - reg[:3, 3]) @ reg[:3, :3]
    assert np.all(np.linalg.norm(in_tracker, axis=1) > 0.05)
    assert files == sorted(["col.h5", "cal.json", "pivot.csv", "pivot.truth.json", "tip.json",
                            "touch.csv", "touch.image.mrk.json", "touch.truth.json",
                            "touch.mrk.json", "reg.json", "reg.tfm"])
    assert (tmp_path / "track.csv").is_file()
