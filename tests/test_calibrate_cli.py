"""The ``calibrate`` and ``reproduce`` commands, run in-process on a fresh parser."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from openemt.cli import _calibrate, _reproduce
from openemt.io import read_calibration


def _main(module, argv):
    parser = argparse.ArgumentParser(prog="openemt")
    sub = parser.add_subparsers(dest="command")
    module.register(sub)
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except (ValueError, TypeError, OSError) as exc:
        print(f"error: {exc}")
        return 2


def test_calibrate_command_writes_calibration(ilemt_dir, tmp_path, capsys):
    out = tmp_path / "xyz.json"
    rc = _main(_calibrate, ["calibrate", str(ilemt_dir), "--mode", "XYZ", "-o", str(out),
                            "--json", "--quiet"])
    assert rc == 0
    summary = json.loads(capsys.readouterr().out)
    # from base_calibration.mat: the paper's XYZ residue (ilemt-format.md §9)
    assert summary["rms_residue"] == pytest.approx(0.004847097, rel=2e-6)
    assert summary["num_points"] == 426 and summary["n_free"] == 35
    assert summary["jacobian_rank"] == 35 and summary["undetermined_groups"] == []
    cal = read_calibration(out)
    assert cal.mode == "XYZ"
    assert cal.linear_correction is not None and cal.linear_correction.shape == (4, 4)
    assert cal.stats["rms_residue"] == pytest.approx(summary["rms_residue"], rel=1e-12)
    assert cal.standard_errors["M_se"].shape == (3, 3)
    assert np.all(np.isfinite(cal.standard_errors["M_se"]))
    assert "d_so_z_gain" in cal.frozen
    assert cal.provenance["inputs"]  # SHA-256 of the md files used
    assert all(len(h) == 64 for h in cal.provenance["inputs"].values())

    # staged: start from the written file, fit source and stage fixtures on all fixtures
    rc = _main(_calibrate, ["calibrate", str(ilemt_dir), "--from", str(out), "--mode",
                            "so_fixture_all", "--correction", "none", "--json", "--quiet"])
    assert rc == 0
    s2 = json.loads(capsys.readouterr().out)
    assert s2["rms_residue"] == pytest.approx(0.016104433, rel=2e-6)
    assert s2["num_points"] == 852


def test_calibrate_command_warns_on_undetermined_groups(ilemt_dir, capsys):
    rc = _main(_calibrate, ["calibrate", str(ilemt_dir), "--mode", "XYZ", "--optimize",
                            "so_fix,st_fix,se_fix", "--correction", "none", "--json", "--quiet"])
    assert rc == 0
    s = json.loads(capsys.readouterr().out)
    assert set(s["undetermined_groups"]) == {"so_fix", "st_fix"}
    assert s["warnings"] and "cannot determine" in s["warnings"][0]


def test_calibrate_command_bad_input(tmp_path, capsys):
    assert _main(_calibrate, ["calibrate", str(tmp_path / "missing")]) == 2
    assert _main(_calibrate, ["calibrate", str(tmp_path)]) == 2  # no base_calibration.mat
    assert "expected" in capsys.readouterr().out


def test_reproduce_command_json(ilemt_dir, capsys):
    rc = _main(_reproduce, ["reproduce", "table2", str(ilemt_dir), "--json", "--quiet"])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    for row in ("default", "corrected", "concentric"):
        assert set(out[row]) >= {"trans_rms_mm", "trans_max_mm", "rot_rms_deg", "rot_max_deg"}
    assert out["n_test"] == 1896
    assert set(out["calibration_residues"]) >= {"XYZ", "XYZ_concentric", "so_fixture_all"}
    assert out["seconds"]["total"] > 0
    assert abs(out["default"]["trans_rms_mm"] - 0.416) <= 0.005
