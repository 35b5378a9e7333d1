"""'openemt info' reads every file openemt writes, each made by the real command or writer."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

import openemt
from openemt.cli import main

TRACKERS = Path(openemt.__file__).parent / "live" / "trackers"


def _run(capsys, *argv):
    rc = main([str(a) for a in argv])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    return cap


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """Every kind of file, written by openemt's commands (and the board calibration writer)."""
    d = tmp_path_factory.mktemp("made")
    files = {}

    def run(*argv):
        assert main([str(a) for a in argv] + ["--quiet"]) == 0, argv

    run("simulate", "--preset", "dipole-approx", "--pattern", "md", "--source-fixtures",
        "YoutZup,XinYup", "--sensor-fixtures", "YoutZup", "--snr-db", "80", "-o", d / "sim.h5",
        "--truth-calibration", d / "truth.json")
    run("solve", d / "sim.h5", "-c", d / "truth.json", "-o", d / "poses.h5")
    run("simulate", "--reference", "optical", "--format", "ndi", "--n-poses", "40",
        "--seed", "3", "-o", d / "session.tsv")
    run("import", "ndi", d / "session.tsv", "--tool", "10", "-o", d / "aurora.h5")
    run("import", "ndi", d / "session.tsv", "--tool", "Port 1", "-o", d / "polaris.h5")
    run("align", d / "aurora.h5", d / "polaris.h5", "--match", "frame", "-o", d / "pairs.csv")
    run("correct", "fit", d / "pairs.csv", "--method", "dlt", "-o", d / "corr.json")
    run("correct", "apply", d / "corr.json", d / "aurora.h5", "-o", d / "corrected.csv")
    run("track", "--source", "sim", "--duration", "0.2", "--fast", "--no-igtl",
        "--save-raw", d / "raw.h5", "--log", d / "log.h5")
    run("track", "--tracker", TRACKERS / "simulated-2.toml", "--duration", "0.2", "--fast",
        "--no-igtl", "--log", d / "log2.csv")
    openemt.write_calibration(openemt.read_calibration(TRACKERS / "anser-nominal.json"),
                      d / "board_cal.json")
    shutil.copy(openemt.datasets.path("cal_9_15_premo_cmu") / "base_calibration.mat",
                d / "base.mat")
    files.update({k: d / v for k, v in {
        "dataset": "sim.h5", "poses": "poses.h5", "calibration": "truth.json",
        "board": "board_cal.json", "mat": "base.mat", "correction": "corr.json",
        "raw": "raw.h5", "log_h5": "log.h5", "log_csv": "log2.csv", "pairs": "pairs.csv",
        "pose_csv": "corrected.csv", "pose_dataset": "aurora.h5", "ndi": "session.tsv"}.items()})
    return files


#: file -> (kind in the JSON, a field and its expected value)
EXPECTED = {
    "dataset": ("dataset", "n_source", 3),
    "poses": ("poses", "solver", "lm"),
    "calibration": ("calibration", "n_sensor", 3),
    "board": ("calibration", "model_kind", "finite"),
    "mat": ("calibration", "mode", "XYZ"),
    "correction": ("correction", "method", "dlt"),
    "raw": ("raw", "n_channels", 6),
    "log_h5": ("track-log", "format", "hdf5"),
    "log_csv": ("track-log", "format", "csv"),
    "pairs": ("pose-pairs", "has_reference", True),
    "pose_csv": ("pose-csv", "has_reference", False),
    "pose_dataset": ("dataset", "pose_dataset", True),
    "ndi": ("ndi-export", "n_bad_rows", 0),
}


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_info_reads_every_file_openemt_writes(made, name, capsys):
    path = made[name]
    kind, key, value = EXPECTED[name]
    info = json.loads(_run(capsys, "info", path, "--json").out)
    assert info["kind"] == kind and info[key] == value and info["path"] == str(path)
    err = _run(capsys, "info", path).err
    assert err.startswith(f"{path}: ") and len(err.splitlines()) >= 1


def test_info_numbers_agree_with_the_files(made, capsys):
    def info(name):
        return json.loads(_run(capsys, "info", made[name], "--json").out)

    ds, poses = info("dataset"), info("poses")
    assert poses["n_samples"] == ds["n_samples"] == 284
    assert sum(poses["status_counts"].values()) == 284
    assert poses["meta"]["hemisphere"] == "per source fixture"
    raw = info("raw")
    assert raw["duration_s"] == pytest.approx(0.2, abs=0.01) and raw["has_truth"]
    whole = info("log_h5")
    (log,) = whole["sensors"].values()          # one sensor, named as the session named it
    with h5py.File(made["log_h5"]) as f:
        assert log["n_samples"] == whole["rows"] == len(f["status"]) > 0
    assert whole["complete"] is True
    two = info("log_csv")["sensors"]
    assert sorted(two) == ["Probe", "Reference"]
    pairs, ndi = info("pairs"), info("ndi")
    assert pairs["n_samples"] <= 40 and len(ndi["tools"]) == 2
    assert [t["n_valid"] for t in ndi["tools"]] == [40, 40]
    corr = info("correction")
    assert corr["n_pairs"] == pairs["n_samples"]
    assert corr["held_out"]["corrected"]["trans_rms_mm"] > 0


def test_info_refuses_other_files_in_one_line(tmp_path, capsys):
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["x"] = np.zeros(3)
    assert main(["info", str(other)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert err.startswith("error: expected an openemt HDF5 file") and "other.h5" in err
    assert main(["info", str(tmp_path / "missing.h5")]) == 2
    assert "missing file" in capsys.readouterr().err


def test_info_refuses_damaged_logs_and_poses_files_in_one_line(made, tmp_path, capsys):
    import shutil

    cases = []
    for name, edit in (("log_h5", lambda f: f.__delitem__("status")),
                       ("poses", lambda f: f.attrs.__delitem__("solver"))):
        path = tmp_path / made[name].name
        shutil.copy(made[name], path)
        with h5py.File(path, "a") as f:
            edit(f)
        cases.append(path)
    path = tmp_path / "log.csv"
    text = made["log_csv"].read_text().splitlines()
    path.write_text("\n".join([text[0].replace("distorted", "flag")] + text[1:]) + "\n")
    cases.append(path)
    path = tmp_path / "log2.csv"
    row = text[3].split(",")
    row[2] = "abc"                       # x_m of a row: not a number
    path.write_text("\n".join(text[:3] + [",".join(row)]) + "\n")
    cases.append(path)
    for path in cases:
        assert main(["info", str(path), "--json"]) == 2, path
        cap = capsys.readouterr()
        assert cap.out == "" and len(cap.err.strip().splitlines()) == 1, cap.err
        assert cap.err.startswith("error: expected") and path.name in cap.err


def test_info_loads_only_what_the_file_needs(made):
    """``openemt info`` on a dataset loads neither the report's figures and tables nor the
    field models, solvers and numba nor scipy's signal module (lazy imports: 1.5 s of CPU
    before, about 0.25 s without them)."""
    import subprocess
    import sys

    probe = ("import sys; from openemt.cli import main; "
             f"assert main(['info', {str(made['dataset'])!r}, '--json']) == 0; "
             "print([m for m in ('magpylib', 'matplotlib', 'numba', 'scipy.signal', "
             "'openemt.field', 'openemt.solve', 'openemt.paper', 'openemt.calibrate', "
             "'openemt.report._built') if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         timeout=120, check=True)
    assert out.stdout.strip().splitlines()[-1] == "[]"
