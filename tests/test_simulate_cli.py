"""``openemt simulate``: JSON summary, files written, one-line errors with exit 2 and no output."""

from __future__ import annotations

import json

import numpy as np
import pytest

from openemt import cli
from openemt.io import read_calibration, read_dataset
from openemt.simulate import simulate, truth_calibration


@pytest.fixture
def main():
    """``openemt.cli.main``."""
    return cli.main


def test_json_summary_and_files(main, tmp_path, capsys):
    out, cal = tmp_path / "sim.h5", tmp_path / "truth.json"
    code = main(["simulate", "--preset", "dipole-approx", "--pattern", "md",
                 "--source-fixtures", "all", "--sensor-fixtures", "all", "--snr-db", "80",
                 "--seed", "1", "-o", str(out), "--truth-calibration", str(cal), "--json"])
    assert code == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["n_samples"] == 852 and summary["n_source"] == 3 and summary["n_sensor"] == 3
    assert summary["path"] == str(out) and summary["truth_calibration"] == str(cal)
    assert summary["errors"]["snr_db"] == 80.0
    ds = read_dataset(out)
    want = simulate("dipole-approx", "md", snr_db=80, seed=1)
    np.testing.assert_allclose(ds.couplings, want.couplings, rtol=0, atol=0)
    np.testing.assert_allclose(ds.poses, want.poses, rtol=0, atol=0)
    assert ds.files == want.files
    c = read_calibration(cal)
    assert c.mode == "truth"
    np.testing.assert_allclose(c.model.L_so, truth_calibration("dipole-approx").model.L_so)


def test_options(main, tmp_path, capsys):
    out = tmp_path / "sim.h5"
    code = main(["simulate", "--preset", "concentric", "--pattern", "mdtrans,ldtrans",
                 "--source-fixtures", "YoutZup", "--sensor-fixtures", "YoutZup,ZinYup",
                 "--noise-abs", "1e-6", "--stage-sigma", "0", "--drift", "1e-4,2e-4,3e-4",
                 "--distortion", "conductive,0.05,0.2,0,0.03,conductivity=1e7",
                 "--distortion", "ferromagnetic,-0.05,0.2,0,0.01", "--no-clip-z",
                 "-o", str(out), "--json", "--quiet"])
    assert code == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["n_samples"] == 2 * (30 + 128) and summary["complex"] is True
    assert summary["truth_calibration"] is None
    ds = read_dataset(out)
    assert np.iscomplexobj(ds.couplings)
    assert ds.stage[:, 2].min() == pytest.approx(-0.050)
    assert [d["kind"] for d in ds.meta["errors"]["distortion"]] == ["conductive", "ferromagnetic"]
    assert ds.meta["errors"]["drift"] == [1e-4, 2e-4, 3e-4]
    np.testing.assert_array_equal(ds.extra["stage_true"], ds.stage)


@pytest.mark.parametrize("bad", [
    ["--pattern", "md,xd"],
    ["--preset", "cube"],
    ["--snr-db", "loud"],
    ["--snr-db", "60", "--noise-abs", "1e-5"],
    ["--source-fixtures", "YoutZdown"],
    ["--drift", "1e-4,2e-4"],
    ["--distortion", "conductive,0,0.2,0"],
    ["--distortion", "wooden,0,0.2,0,0.01"],
    ["--stage-sigma", "-1"],
])
def test_bad_input_exit_2_no_file(main, tmp_path, capsys, bad):
    out, cal = tmp_path / "sim.h5", tmp_path / "cal.json"
    code = main(["simulate", "-o", str(out), "--truth-calibration", str(cal), *bad])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("error: ")
    assert not out.exists() and not cal.exists()
    assert list(tmp_path.iterdir()) == []


def test_missing_output_folder(main, tmp_path, capsys):
    out = tmp_path / "sim.h5"
    code = main(["simulate", "--pattern", "mdtrans", "-o", str(out),
                 "--truth-calibration", str(tmp_path / "nope" / "cal.json")])
    assert code == 2
    assert "missing folder" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
