"""``openemt report``: the HTML report of an ILEMT folder and of a calibration on a dataset,
rendered in headless Chromium with every figure decoded."""

import argparse
import dataclasses
import json
import re

import numpy as np
import pytest
from _report_checks import defined_symbols, shown_symbols
from chromium_render import render

from openemt.cli._report import register
from openemt.io import read_calibration, read_dataset, write_calibration, write_dataset
from openemt.report import characterization_report
from openemt.simulate import get_preset, simulate, truth_calibration


def _parser():
    p = argparse.ArgumentParser(prog="openemt")
    register(p.add_subparsers(dest="command"))
    return p


def _run(argv):
    args = _parser().parse_args(argv)
    return args.func(args)


def _self_contained(text):
    assert text.startswith("<!DOCTYPE html>")
    assert not re.search(r'(src|href)="(https?:|file:|//)', text)


@pytest.fixture(scope="module")
def sim_files(tmp_path_factory):
    """A simulated concentric tracker: ld and sweep rows of the home fixtures, truth calibration
    with an output correction of a known small scale error."""
    d = tmp_path_factory.mktemp("sim")
    pre = get_preset("concentric")
    ds = simulate(pre, ["ld", "sweep"], source_fixtures=pre.source_fixtures[0],
                  sensor_fixtures=pre.sensor_fixtures[0], snr_db=80, seed=5)
    cal = truth_calibration(pre)
    write_dataset(ds, d / "test.h5")
    write_calibration(cal, d / "cal.json")
    L = np.diag([1.001, 1.0, 1.0, 1.0])
    write_calibration(cal.replace(linear_correction=L), d / "cal_corr.json")
    return d, ds


def test_report_of_a_calibration_on_a_dataset_renders(sim_files, tmp_path, capsys):
    d, ds = sim_files
    out = tmp_path / "report.html"
    rc = _run(["report", "--dataset", str(d / "test.h5"), "--calibration",
               str(d / "cal_corr.json"), "-o", str(out), "--json", "--quiet"])
    assert rc == 0
    s = json.loads(capsys.readouterr().out)
    assert s["mode"] == "dataset" and s["reference"] == "kinematics"
    assert s["n_test"] == len(ds)
    acc = s["accuracy"]
    assert set(acc) == {"calibration", "calibration + correction"}
    for r in acc.values():
        # eq. 10 with the 0.107 mm / 0.17 deg stage uncertainty
        assert r["trans_uncert_mm"] == pytest.approx(np.hypot(r["trans_rms_mm"], 0.107))
        assert r["rot_uncert_deg"] == pytest.approx(np.hypot(r["rot_rms_deg"], 0.17))
    # the correction changes positions only
    assert acc["calibration"]["rot_rms_deg"] == pytest.approx(
        acc["calibration + correction"]["rot_rms_deg"], rel=1e-12)
    assert acc["calibration"]["trans_rms_mm"] != acc["calibration + correction"]["trans_rms_mm"]
    assert s["table4"]["n_curves"] == {"xyz": 3, "rot": 1}
    assert s["n_figures"] == 3  # error vectors, histograms, sweeps
    text = out.read_text()
    _self_contained(text)
    assert text.count("data:image/png;base64,") == 3
    assert "Calibration parameters and standard errors" in text and "u(P)" in text
    assert shown_symbols(text) <= defined_symbols(text)       # sweep columns included
    n, ok, dom = render(out, tmp_path)
    assert (n, ok) == (3, 3), f"images total/decoded = {n}/{ok}"
    assert "Axis sweeps" in dom


def test_report_against_reference_poses(sim_files, tmp_path, capsys):
    d, _ = sim_files
    out = tmp_path / "r.html"
    assert _run(["report", str(d / "test.h5"), "--calibration", str(d / "cal.json"),
                 "--reference", "poses", "-o", str(out), "--json", "--quiet"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["reference"] == "poses" and set(s["accuracy"]) == {"calibration"}
    # the simulated truth calibration is close to the finite-coil truth at most poses
    assert set(s["by_fixture"]) == {"soYoutZup_seYoutZup ld", "soYoutZup_seYoutZup sweep"}
    assert s["by_fixture"]["soYoutZup_seYoutZup ld"]["trans_p50_mm"] < 1.0
    assert out.is_file()


def test_report_bad_input_leaves_no_file(sim_files, tmp_path):
    d, _ = sim_files
    out = tmp_path / "r.html"
    with pytest.raises(ValueError, match="expected --calibration"):
        _run(["report", str(d / "test.h5"), "-o", str(out)])
    with pytest.raises(ValueError, match="expected an ILEMT folder or a dataset"):
        _run(["report", "-o", str(out)])
    with pytest.raises(FileNotFoundError, match="expected an ILEMT folder or a dataset file"):
        _run(["report", str(tmp_path / "missing.h5"), "--calibration", str(d / "cal.json"),
              "-o", str(out)])
    # simulated datasets carry poses; an imported ILEMT dataset would not: drop them here
    ds = dataclasses.replace(read_dataset(d / "test.h5"), poses=None)
    with pytest.raises(ValueError, match="expected a dataset with reference `poses`"):
        characterization_report(ds, read_calibration(d / "cal.json"), reference="poses")
    assert not out.exists()
    assert [p.name for p in tmp_path.iterdir()] == []


def test_report_of_an_ilemt_folder_renders(ilemt_dir, tmp_path, capsys):
    out = tmp_path / "ilemt.html"
    assert _run(["report", str(ilemt_dir), "-o", str(out), "--json", "--quiet"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["mode"] == "ilemt" and s["n_test"] == 1896
    t2 = s["table2"]
    # MacLachlan et al. 2025, Table II, concentric source (the calibration module reproduces it to 4-5 digits)
    assert t2["default"]["trans_rms_mm"] == pytest.approx(0.41555, rel=1e-3)
    assert t2["corrected"]["trans_rms_mm"] == pytest.approx(0.26306, rel=1e-3)
    assert t2["concentric"]["trans_rms_mm"] == pytest.approx(0.90484, rel=1e-3)
    assert t2["default"]["trans_uncert_mm"] == pytest.approx(np.hypot(0.41555, 0.107), rel=1e-3)
    assert s["table3"]["within_5_percent"] is True
    assert s["table4"]["n_curves"] == {"xyz": 9, "rot": 3}
    assert set(s["by_fixture"]) == {"soYoutZup_seYoutZup", "soYoutZup_seZinYup",
                                    "soYoutZup_seZinXdown"}
    # held-out breakdown and the md/ld repeat-pose noise floor
    b = s["breakdown"]["default"]
    assert sum(v["n"] for v in b["by_range"].values()) == 1896
    assert list(b["by_rz"]) == ["-90 deg", "-45 deg", "0 deg", "45 deg", "90 deg"]
    assert s["noise_floor"]["n_pairs"] >= 3 * 5 * 27
    assert 0 < s["noise_floor"]["trans_rms_mm"] < t2["default"]["trans_rms_mm"]
    text = out.read_text()
    assert "Held-out errors by range" in text
    _self_contained(text)
    for heading in ("Table II", "Table III", "Table IV", "parameters and standard errors"):
        assert heading in text
    # every symbol defined; the concentric row's invalid solutions explained from the models
    assert shown_symbols(text) <= defined_symbols(text)
    assert t2["default"]["reason"] is None
    assert t2["concentric"]["n_invalid"] > 0
    assert t2["concentric"]["reason"].startswith(f"{t2['concentric']['n_invalid']} of 1896 rows")
    assert "the concentric approximation of source coils" in t2["concentric"]["reason"]
    assert ">fixed (gauge)<" in text
    n, ok, dom = render(out, tmp_path)
    assert (n, ok) == (3, 3), f"images total/decoded = {n}/{ok}"
    assert "cal_9_15_premo_cmu" in dom


def test_report_through_openemt_main(sim_files, tmp_path, capsys):
    # bad input is one error line and exit code 2, no partial file
    from openemt import cli

    d, _ = sim_files
    out = tmp_path / "r.html"
    assert cli.main(["report", str(d / "test.h5"), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: expected --calibration") and err.count("\n") == 1
    assert cli.main(["report", str(d / "test.h5"), "--calibration", str(d / "missing.json"),
                     "-o", str(out)]) == 2
    assert not out.exists()
