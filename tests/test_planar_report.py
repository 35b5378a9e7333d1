"""`openemt report` and `openemt solve` on a finite-coil (board) calibration give the figures of
`openemt calibrate --mode planar`; bad input is one error line."""

import json

import numpy as np
import pytest
from _report_checks import defined_symbols, shown_symbols

from openemt.board import BoardModel
from openemt.cli import main
from openemt.simulate import stage_pattern


def _run(argv, capsys):
    rc = main(argv)
    out = capsys.readouterr()
    return rc, out.out, out.err


def _grid_dataset(model, path, sigma_rel=1e-4, seed=3):
    from openemt.io import Dataset, write_dataset

    base = stage_pattern("grid")[:, :3]
    pts = base + [0.0, 0.0, 0.072]
    n = len(pts)
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, 3] = pts
    poses[:, :3, :3] = np.diag([1.0, -1.0, -1.0])            # sensor axis -z
    C = model.coupling(poses)
    C = C + np.random.default_rng(seed).normal(0.0, sigma_rel * np.abs(C).max(), C.shape)
    ds = Dataset(couplings=C, stage=np.zeros((n, 6)), source_fixture=["YoutZup"] * n,
                 sensor_fixture=["YoutZup"] * n, pattern=["grid"] * n,
                 file_index=np.full(n, -1), poses=poses)
    write_dataset(ds, path)
    return path


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("planar_report")
    rng = np.random.default_rng(11)
    truth = BoardModel.from_board("anser", gains=rng.uniform(0.9, 1.1, 8),
                                   offsets=rng.normal(0.0, 2e-3, (8, 3)))
    grid = _grid_dataset(truth, tmp / "grid.h5")
    cal = tmp / "cal.json"
    rc = main(["calibrate", str(grid), "--mode", "planar", "--holdout", "checkerboard", "-o",
               str(cal), "--json", "--quiet"])
    assert rc == 0
    return tmp, grid, cal


def _close(a, b, rtol):
    for k in ("position_rms_mm", "position_max_mm", "axis_rms_deg"):
        assert a[k] == pytest.approx(b[k], rel=rtol), k
    assert a["n"] == b["n"]
    np.testing.assert_allclose(a["coil_residual_percent"], b["coil_residual_percent"],
                               rtol=rtol)


def test_report_gives_the_calibration_figures(calibrated, capsys):
    tmp, grid, cal = calibrated
    rc, out, err = _run(["calibrate", str(grid), "--mode", "planar", "--holdout",
                         "checkerboard", "--json"], capsys)
    assert rc == 0, err
    fit = json.loads(out)
    html = tmp / "report.html"
    rc, out, err = _run(["report", str(grid), "--calibration", str(cal), "--holdout",
                         "checkerboard", "-o", str(html), "--json"], capsys)
    assert rc == 0, err
    rep = json.loads(out)
    assert rep["mode"] == "planar" and rep["board"] == "anser" and rep["n_points"] == 49
    for key in ("insample", "holdout"):
        _close(rep[key], fit[key], 1e-6)
    assert rep["holdout"]["scheme"] == "checkerboard"
    assert rep["accuracy"]["n"] == 49
    text = html.read_text()          # every symbol of its tables defined in words
    assert "Symbols and terms" in text and shown_symbols(text) <= defined_symbols(text)
    assert rep["status_counts"]["converged"] == 49
    assert rep["gains"] == fit["gains"]
    np.testing.assert_allclose(rep["offsets_se_mm"], fit["offsets_se_mm"], rtol=1e-12)
    assert rep["n_figures"] == 1
    text = html.read_text()
    assert text.startswith("<!DOCTYPE html>") and "data:image/png;base64," in text
    assert "coil8" in text and "anser" in text
    # no temporary file left beside the report (written atomically)
    assert sorted(p.name for p in tmp.iterdir() if "report" in p.name) == ["report.html"]


def test_report_writes_atomically(calibrated, capsys, monkeypatch, tmp_path):
    _tmp, grid, cal = calibrated
    html = tmp_path / "atomic.html"
    html.write_text("old")

    def broken(self):
        raise RuntimeError("rendering failed")

    monkeypatch.setattr("openemt.report._html.Report.html", broken)
    rc = main(["report", str(grid), "--calibration", str(cal), "-o", str(html), "--quiet"])
    capsys.readouterr()
    assert rc != 0
    assert html.read_text() == "old"                       # the old file is untouched
    assert [p.name for p in tmp_path.iterdir()] == ["atomic.html"]   # and no stray file


def test_report_bad_inputs_are_one_line(calibrated, capsys, tmp_path):
    from openemt.datasets import path as dataset_path

    _tmp, grid, cal = calibrated
    out_html = tmp_path / "r.html"
    # a dipole (tri-axial) dataset with a board calibration
    rc, _, err = _run(["report", str(dataset_path("cal_9_15_premo_cmu")), "--calibration",
                       str(cal), "-o", str(out_html)], capsys)
    assert rc == 2 and err.startswith("error: ") and err.count("\n") == 1
    assert not out_html.exists()
    # a single-coil dataset of another coil count
    from openemt.io import Dataset, write_dataset

    n = 5
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, 2, 3] = 0.1
    ds = Dataset(couplings=np.ones((n, 3, 1)), stage=np.zeros((n, 6)),
                 source_fixture=["YoutZup"] * n, sensor_fixture=["YoutZup"] * n,
                 pattern=["grid"] * n, file_index=np.full(n, -1), poses=poses)
    three = write_dataset(ds, tmp_path / "three.h5") or tmp_path / "three.h5"
    rc, _, err = _run(["report", str(three), "--calibration", str(cal), "-o", str(out_html)],
                      capsys)
    assert rc == 2 and "8 coil columns" in err and err.count("\n") == 1
    assert not out_html.exists()
    # --holdout is for board calibrations only
    dip = tmp_path / "dip.json"
    from openemt.live import example_tracker

    dip.write_text((example_tracker("simulated").parent / "concentric.json").read_text())
    rc, _, err = _run(["report", str(grid), "--calibration", str(dip), "--holdout",
                       "checkerboard", "-o", str(out_html)], capsys)
    assert rc == 2 and "--holdout only with a finite-coil" in err and err.count("\n") == 1


def test_solve_adds_the_accuracy_of_known_poses(calibrated, capsys):
    tmp, grid, _cal = calibrated
    rc, out, err = _run(["calibrate", str(grid), "--mode", "planar", "--json"], capsys)
    assert rc == 0, err
    fit = json.loads(out)
    cal_all = tmp / "cal_all.json"
    assert main(["calibrate", str(grid), "--mode", "planar", "-o", str(cal_all),
                 "--quiet"]) == 0
    rc, out, err = _run(["solve", str(grid), "-c", str(cal_all), "-o", str(tmp / "p.h5"),
                         "--json"], capsys)
    assert rc == 0, err
    s = json.loads(out)
    assert s["status_counts"]["converged"] == 49
    # tracked from point to point instead of cold starts: the same minima to the solver's
    # step tolerance (1e-9 m against errors of tens of micrometres)
    _close(s["accuracy"], fit["insample"], 1e-4)


@pytest.mark.parametrize("poses", ["short", "flat", "group"])
def test_solve_refuses_malformed_true_poses(calibrated, capsys, tmp_path, poses):
    import shutil

    import h5py

    _tmp, grid, cal = calibrated
    bad = tmp_path / "bad.h5"
    shutil.copy(grid, bad)
    with h5py.File(bad, "r+") as f:
        P = f["poses"][()]
        del f["poses"]
        if poses == "short":
            f["poses"] = P[:10]
        elif poses == "flat":
            f["poses"] = np.zeros(5)
        else:
            f.create_group("poses")
    out = tmp_path / "p.h5"
    rc, _out, err = _run(["solve", str(bad), "-c", str(cal), "-o", str(out), "--json"], capsys)
    assert rc == 2 and err.strip().count("\n") == 0
    assert "expected `poses` to have shape (49, 4, 4)" in err
    assert not out.exists()
