"""A planar board read by a 6-DOF sensor of two coils, through the commands every tracker uses
(docs/planar.md#a-6-dof-sensor-on-a-board): simulate a robot collection, calibrate it in
reference mode, solve, report, inspect and track -- no code written for this combination."""

from __future__ import annotations

import json

import numpy as np
import pytest

from openemt.cli import main
from openemt.io import read_calibration, read_dataset
from openemt.live import example_tracker


def _run(argv, capsys):
    rc = main([str(a) for a in argv])
    out = capsys.readouterr()
    return rc, out.out, out.err


@pytest.fixture(scope="module")
def collection(tmp_path_factory):
    d = tmp_path_factory.mktemp("six")
    rc = main(["simulate", "--preset", "anser-6dof", "--reference", "robot", "--n-poses", "80",
               "--seed", "1", "-o", str(d / "b.h5"), "--truth-calibration", str(d / "t.json"),
               "--quiet"])
    assert rc == 0
    return d


def test_simulate_calibrate_solve_report(collection, capsys):
    d = collection
    ds = read_dataset(d / "b.h5")
    assert ds.couplings.shape == (80, 8, 2) and "reference_poses" in ds.extra
    truth = read_calibration(d / "t.json")
    assert truth.kind == "finite" and truth.model.dof == 6

    rc, out, err = _run(["calibrate", d / "b.h5", "--mode", "reference", "--holdout", "0.25",
                         "-o", d / "c.json", "--json"], capsys)
    assert rc == 0, err
    s = json.loads(out)
    h = s["holdout"]
    assert h["n"] == 20 and h["n_not_converged"] == 0
    # the robot's own noise (0.05 mm, 0.02 deg) is the floor: the fit is near it
    assert h["trans_rms_mm"] < 0.15 and h["rot_rms_deg"] < 0.08
    cal = read_calibration(d / "c.json")
    assert cal.mode == "reference" and cal.model.dof == 6 and not s["undetermined"]
    # fitted gains and the second sensor coil's relative gain against the simulation's truth
    np.testing.assert_allclose(cal.model.gains, truth.model.gains, rtol=5e-3)
    assert abs(cal.model.sensor_gains[1] - truth.model.sensor_gains[1]) < 2e-3

    rc, out, err = _run(["solve", d / "b.h5", "--calibration", d / "c.json", "-o", d / "p.h5",
                         "--json"], capsys)
    assert rc == 0, err
    s = json.loads(out)
    assert s["dof"] == 6 and s["status_counts"]["converged"] == 80
    assert s["accuracy"]["position_rms_mm"] < 0.5 and s["accuracy"]["rot_rms_deg"] < 0.2

    rc, out, err = _run(["report", d / "b.h5", "--calibration", d / "c.json", "--reference",
                         "poses", "-o", d / "r.html", "--json"], capsys)
    assert rc == 0, err
    acc = json.loads(out)["accuracy"]["calibration"]
    assert acc["n"] == 80 and acc["n_invalid"] == 0 and acc["trans_rms_mm"] < 0.5
    assert "gains[0]" in (d / "r.html").read_text()

    rc, out, err = _run(["info", d / "c.json", "--json"], capsys)
    assert rc == 0, err
    info = json.loads(out)
    assert info["model_kind"] == "finite" and info["dof"] == 6 and info["n_sensor"] == 2


def test_track_with_the_shipped_6dof_tracker(tmp_path, capsys):
    rc, out, err = _run(["track", "--tracker", example_tracker("anser-6dof"), "--source", "sim",
                         "--duration", "0.4", "--fast", "--no-igtl", "--log", tmp_path / "l.csv",
                         "--json"], capsys)
    assert rc == 0, err
    s = json.loads(out)
    assert s["status_counts"]["converged"] == sum(s["status_counts"].values()) > 500
    assert s["truth"]["position_error_mm_rms"] < 0.05
