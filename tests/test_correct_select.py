"""Corrections that do no harm: "none" beside every method, ``auto`` by held-out error,
warnings for worse-than-none and too few pairs, bounded folds, counted bad CSV rows."""

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from openemt.cli import main
from openemt.correct import (
    MAX_FOLDS,
    fit_auto_correction,
    fit_correction,
    pair_requirements,
    read_correction,
    write_correction,
)
from openemt.geometry import pose_from_rt
from openemt.io import write_poses_csv


def _pairs(n, seed, distortion_mm=2.0, noise_mm=0.1):
    rng = np.random.default_rng(seed)
    p = rng.uniform([0.05, -0.15, -0.15], [0.35, 0.15, 0.15], (n, 3))
    D = pose_from_rt(Rotation.random(n, random_state=seed).as_matrix(), p)
    q = (p - [0.2, 0, 0]) / 0.15
    dp = distortion_mm * 1e-3 * np.stack([q[:, 0] ** 2, 0.5 * q[:, 1] * q[:, 2],
                                          -0.7 * q[:, 0] * q[:, 2]], 1)
    rho = np.deg2rad(0.2) * (distortion_mm / 2) * np.stack([q[:, 0] * q[:, 1], q[:, 2] ** 2,
                                                             q[:, 0]], 1)
    rho += np.deg2rad(0.02) * rng.standard_normal((n, 3))
    M = pose_from_rt(Rotation.from_rotvec(rho).as_matrix() @ D[:, :3, :3],
                     p + dp + noise_mm * 1e-3 * rng.standard_normal((n, 3)))
    return M, D


def test_none_is_a_method_and_round_trips(tmp_path):
    M, D = _pairs(40, 1)
    c = fit_correction(M, D, "none")
    ho = c.stats["held_out"]
    assert ho["corrected"] == ho["uncorrected"] and not c.stats["worse_than_none"]
    np.testing.assert_array_equal(c.apply(M), M)
    write_correction(c, tmp_path / "none.json")
    assert read_correction(tmp_path / "none.json").method == "none"


def test_auto_picks_a_correction_for_a_distortion_and_none_for_pure_noise():
    M, D = _pairs(150, 2)
    c = fit_auto_correction(M, D, methods=("dlt", "poly"))
    assert c.method == "poly" and c.meta["method_requested"] == "auto"
    cand = c.stats["auto"]["candidates"]
    assert set(cand) == {"none", "dlt", "poly"}
    assert cand["poly"]["score_mm"] < cand["dlt"]["score_mm"] < cand["none"]["score_mm"]
    # no distortion at all: every fitted correction only adds estimation noise
    M0, D0 = _pairs(25, 3, distortion_mm=0.0, noise_mm=0.3)
    c0 = fit_auto_correction(M0, D0, methods=("dlt", "poly", "rbf"))
    best = c0.stats["auto"]["candidates"][c0.method]["score_mm"]
    assert best <= c0.stats["auto"]["candidates"]["none"]["score_mm"]
    assert c0.method == "none"
    assert not c0.stats["worse_than_none"]


def test_warnings_worse_than_none_and_too_few_pairs():
    M, D = _pairs(12, 4, distortion_mm=0.0, noise_mm=0.3)
    c = fit_correction(M, D, "dlt")
    assert c.stats["requirements"] == {"parameters_per_coordinate": 5, "min_pairs": 15}
    w = " ".join(c.stats["warnings"])
    assert "12 pose pairs are fewer than the 15 recommended" in w
    assert c.stats["worse_than_none"] and "worse than no correction" in w
    assert pair_requirements("poly", {"pos_order": 2, "rot_order": 1,
                                      "max_power": None})["min_pairs"] == 30
    assert pair_requirements("grid", {"shape": [3, 3, 3]})["min_pairs"] == 81
    # enough pairs and a real distortion: no warning
    M2, D2 = _pairs(200, 5)
    assert fit_correction(M2, D2, "dlt").stats["warnings"] == []


def test_folds_are_bounded():
    M, D = _pairs(200, 6)
    with pytest.raises(ValueError, match=f"<= {MAX_FOLDS}"):
        fit_correction(M, D, "poly", k=100000)
    with pytest.raises(ValueError, match="folds"):
        fit_correction(M, D, "poly", k=MAX_FOLDS + 1)


def test_cli_auto_reports_none_rows_and_warnings(tmp_path, capsys):
    M, D = _pairs(60, 7)
    f = write_poses_csv(tmp_path / "pairs.csv", M, D)
    lines = f.read_text().splitlines()
    lines[5] = ",".join(lines[5].split(",")[:7])           # a truncated row
    cells = lines[9].split(",")
    cells[2] = "nan"
    lines[9] = ",".join(cells)                              # a NaN row
    lines[-1] = lines[-1][:20]                              # the last row cut short
    f.write_text("\n".join(lines) + "\n")
    out = tmp_path / "corr.json"
    assert main(["correct", "fit", str(f), "-o", str(out), "--method", "auto", "--json"]) == 0
    cap = capsys.readouterr()
    s = json.loads(cap.out)
    assert s["n"] == 57 and s["n_dropped"] == 3 and s["method_requested"] == "auto"
    r = s["input_rows"][0]
    assert r["bad_lines"] == [6, 61] and r["nonfinite_lines"] == [10]
    assert "rows not used" in cap.err and "lines 6, 61" in cap.err
    assert s["held_out"]["uncorrected"]["trans_rms_mm"] > s["held_out"]["corrected"]["trans_rms_mm"]
    assert set(s["auto"]["candidates"]) == {"none", "dlt", "poly", "bernstein", "grid", "rbf"}
    assert s["worse_than_none"] is False
    assert read_correction(out).method == s["method"]


def test_cli_exact_interpolant_shows_its_held_out_figure(tmp_path, capsys):
    M, D = _pairs(40, 8, distortion_mm=0.0, noise_mm=0.3)
    f = write_poses_csv(tmp_path / "pairs.csv", M, D)
    assert main(["correct", "fit", str(f), "-o", str(tmp_path / "c.json"), "--method", "rbf",
                 "--smoothing", "1e-9", "--positions-only", "--json"]) == 0
    cap = capsys.readouterr()
    s = json.loads(cap.out)
    assert s["in_sample"]["corrected"]["trans_rms_mm"] < 1e-3
    assert s["worse_than_none"] is True
    row = next(ln for ln in cap.err.splitlines() if ln.startswith("  rbf "))
    ins, held = (float(v) for v in row.split()[1::2][:2])
    assert ins < 1e-3 and held == pytest.approx(s["held_out"]["corrected"]["trans_rms_mm"],
                                                abs=1e-4)
    assert "warning: rbf: held-out translation error" in cap.err
    # a fold count far beyond the limit is refused at once, with no output file
    assert main(["correct", "fit", str(f), "-o", str(tmp_path / "d.json"), "--folds",
                 "100000"]) == 2
    assert "error: expected 2 <= --folds <= 20" in capsys.readouterr().err
    assert not (tmp_path / "d.json").exists()


def test_cli_fit_reads_a_pose_dataset_with_reference_poses(tmp_path, capsys):
    M, D = _pairs(80, 9)
    f = write_poses_csv(tmp_path / "pairs.csv", M, D)
    h5 = tmp_path / "pairs.h5"
    assert main(["import", "poses", str(f), "-o", str(h5)]) == 0
    capsys.readouterr()
    assert main(["correct", "fit", str(h5), "-o", str(tmp_path / "c.json"), "--method", "dlt",
                 "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["n"] == 80 and s["input_rows"][0]["n_rows"] == 80
    assert s["held_out"]["corrected"]["trans_rms_mm"] < s["held_out"]["uncorrected"]["trans_rms_mm"]
    # a pose dataset without reference poses is refused with one line
    P = tmp_path / "poses.csv"
    write_poses_csv(P, M)
    assert main(["import", "poses", str(P), "-o", str(tmp_path / "p.h5")]) == 0
    assert main(["correct", "fit", str(tmp_path / "p.h5"), "-o", str(tmp_path / "d.json")]) == 2
    assert "openemt align" in capsys.readouterr().err
