"""``openemt correct fit|apply`` in-process, on pose-pair CSV files."""

import argparse
import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from openemt.cli import _correct
from openemt.geometry import pose_from_rt
from openemt.io import read_poses_csv, write_poses_csv


def _main(argv):
    parser = argparse.ArgumentParser(prog="openemt")
    sub = parser.add_subparsers(dest="command")
    _correct.register(sub)
    args = parser.parse_args(argv)
    return args.func(args)


def _pairs(rng, n):
    p = rng.uniform([0.05, -0.15, -0.15], [0.35, 0.15, 0.15], (n, 3))
    D = pose_from_rt(Rotation.random(n, random_state=int(rng.integers(1000))).as_matrix(), p)
    q = (p - [0.2, 0, 0]) / 0.15
    dp = 1e-3 * np.stack([q[:, 0] ** 2, 0.5 * q[:, 1] * q[:, 2], -0.7 * q[:, 0] * q[:, 2]], 1)
    rho = np.deg2rad(0.3) * np.stack([q[:, 0] * q[:, 1], q[:, 2] ** 2, q[:, 0]], 1)
    M = pose_from_rt(Rotation.from_rotvec(rho).as_matrix() @ D[:, :3, :3],
                     p + dp + 2e-5 * rng.standard_normal((n, 3)))
    return M, D


@pytest.mark.parametrize("method", ["poly", "dlt"])
def test_fit_then_apply_on_held_out_file(tmp_path, capsys, method):
    rng = np.random.default_rng(50)
    M1, D1 = _pairs(rng, 150)
    M2, D2 = _pairs(rng, 60)
    f1 = write_poses_csv(tmp_path / "cal.csv", M1, D1)
    f2 = write_poses_csv(tmp_path / "test.csv", M2, D2)
    out = tmp_path / "corr.json"
    assert _main(["correct", "fit", str(f1), "-o", str(out), "--method", method, "--json",
                  "--quiet"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["method"] == method and s["n"] == 150
    assert s["held_out"]["corrected"]["trans_rms_mm"] < s["in_sample"]["uncorrected"]["trans_rms_mm"]
    assert json.loads(out.read_text())["format"] == "openemt.correction"
    res = tmp_path / "corrected.csv"
    assert _main(["correct", "apply", str(out), str(f2), "-o", str(res), "--json"]) == 0
    cap = capsys.readouterr()
    a = json.loads(cap.out)
    assert "corrected" in cap.err  # human summary on stderr
    e = a["errors"]
    # a projective map only partly captures the quadratic distortion; the polynomial does
    ratio = 0.9 if method == "dlt" else 0.3
    assert e["corrected"]["trans_rms_mm"] < ratio * e["uncorrected"]["trans_rms_mm"]
    if method == "poly":
        assert a["orientation_corrected"]
        assert e["corrected"]["rot_rms_deg"] < 0.3 * e["uncorrected"]["rot_rms_deg"]
    t = read_poses_csv(res)
    np.testing.assert_allclose(t.reference, D2, atol=1e-14)


def test_fit_options_static_average_and_holdout_files(tmp_path, capsys):
    rng = np.random.default_rng(51)
    files = []
    for i in range(3):
        M, D = _pairs(rng, 40)
        Mr, Dr = np.repeat(M, 3, axis=0), np.repeat(D, 3, axis=0)
        Mr[:, :3, 3] += 1e-5 * rng.standard_normal((len(Mr), 3))
        files.append(str(write_poses_csv(tmp_path / f"f{i}.csv", Mr, Dr,
                                         group=np.repeat(np.arange(40), 3))))
    out = tmp_path / "c.json"
    assert _main(["correct", "fit", *files, "-o", str(out), "--method", "poly", "--order", "2",
                  "--rot-order", "1", "--average-static", "--holdout-files", "--json",
                  "--quiet"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["n"] == 120
    assert s["selected"] == {"pos_order": 2, "rot_order": 1}
    assert s["held_out"]["scheme"] == "leave-one-group-out" and s["held_out"]["n_folds"] == 3
    assert _main(["correct", "fit", *files, "-o", str(out), "--method", "grid",
                  "--grid-shape", "3,3,3", "--smoothing", "0.01", "--positions-only", "--json",
                  "--quiet"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["selected"]["shape"] == [3, 3, 3] and s["positions_only"]
    assert "rot_rms_deg" not in s["in_sample"]["corrected"]


def test_bad_inputs(tmp_path):
    f = tmp_path / "noref.csv"
    f.write_text("x,y,z\n0,0,0\n")
    with pytest.raises(ValueError, match="ref_x"):
        _main(["correct", "fit", str(f), "-o", str(tmp_path / "c.json")])
    assert not (tmp_path / "c.json").exists()
    g = tmp_path / "pairs.csv"
    g.write_text("x,y,z,ref_x,ref_y,ref_z\n" + "\n".join(f"{i},{i},{i},{i},{i},{i}" for i in range(20)))
    with pytest.raises(ValueError, match="grid-shape"):
        _main(["correct", "fit", str(g), "-o", str(tmp_path / "c.json"), "--method", "grid",
               "--grid-shape", "a,b"])


def test_registered_command_exit_codes(tmp_path, capsys):
    from openemt.cli import main

    assert main(["correct", "fit", str(tmp_path / "missing.csv"), "-o",
                 str(tmp_path / "c.json")]) == 2
    assert "error:" in capsys.readouterr().err
    rng = np.random.default_rng(52)
    M, D = _pairs(rng, 40)
    f = write_poses_csv(tmp_path / "p.csv", M, D)
    assert main(["correct", "fit", str(f), "-o", str(tmp_path / "c.json"), "--method", "rbf",
                 "--quiet"]) == 0
    assert main(["correct", "apply", str(tmp_path / "c.json"), str(f), "-o",
                 str(tmp_path / "o.csv"), "--quiet"]) == 0
    assert read_poses_csv(tmp_path / "o.csv").poses.shape == (40, 4, 4)
