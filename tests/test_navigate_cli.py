"""``openemt pivot``, ``spin``, ``register`` and ``assess`` on simulated files: JSON keys, output
files, and refusals as one error line with exit status 2 and no output file."""

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from openemt.cli import main
from openemt.io import pose_dataset, write_dataset, write_poses_csv
from openemt.navigate import (
    regular_grid,
    simulate_grid_points,
    simulate_pivot_poses,
    simulate_spin_poses,
)

TIP = np.array([0.01, 0.0, 0.16])
PIVOT = np.array([0.1, 0.02, 0.2])


def _run(capsys, *argv):
    rc = main([str(a) for a in argv])
    cap = capsys.readouterr()
    return rc, cap


def _points_csv(path, pts):
    path.write_text("x_mm,y_mm,z_mm\n" + "".join(f"{a},{b},{c}\n" for a, b, c in 1e3 * pts))


def test_pivot_and_spin_commands(tmp_path, capsys):
    rng = np.random.default_rng(0)
    P = simulate_pivot_poses(50, TIP, PIVOT, rng, n_outliers=5)
    write_poses_csv(tmp_path / "pivot.csv", P)
    rc, cap = _run(capsys, "pivot", tmp_path / "pivot.csv", "-o", tmp_path / "tip.json",
                   "--method", "ransac", "--json")
    assert rc == 0, cap.err
    s = json.loads(cap.out)
    for key in ("tip_mm", "pivot_mm", "rms_mm", "rms_component_mm", "n", "n_inliers",
                "tip_se_mm", "pivot_se_mm"):
        assert key in s
    assert s["n"] == 50 and s["n_inliers"] == 45 and s["outlier_rows"] == [0, 1, 2, 3, 4]
    assert np.all(np.abs(np.array(s["tip_mm"]) - 1e3 * TIP) < 3 * np.array(s["tip_se_mm"]))
    f = json.loads((tmp_path / "tip.json").read_text())
    assert f["format"] == "openemt.tool-calibration" and f["kind"] == "pivot"
    assert len(f["per_pose"]["distance_mm"]) == 50
    np.testing.assert_allclose(np.array(f["tip_transform"])[:3, 3], 1e-3 * np.array(s["tip_mm"]))
    # the same poses from a pose dataset (.h5)
    write_dataset(pose_dataset(P, file_index=np.zeros(50, int), files=["sim"]),
                  tmp_path / "pivot.h5")
    rc, cap = _run(capsys, "pivot", tmp_path / "pivot.h5", "-o", tmp_path / "tip2.json",
                   "--method", "ransac", "--json")
    assert rc == 0
    # the CSV stores the rotations as rotation vectors: equal to rounding
    np.testing.assert_allclose(json.loads(cap.out)["tip_mm"], s["tip_mm"], rtol=0, atol=1e-9)
    # spin, signed by the tip
    axis = TIP / np.linalg.norm(TIP)
    S = simulate_spin_poses(40, axis, [0.0, 0.0, 0.0], rng)
    write_poses_csv(tmp_path / "spin.csv", S)
    rc, cap = _run(capsys, "spin", tmp_path / "spin.csv", "--tip", tmp_path / "tip.json",
                   "-o", tmp_path / "axis.json", "--json")
    assert rc == 0, cap.err
    s = json.loads(cap.out)
    assert np.dot(s["axis"], axis) > 0.9999
    assert json.loads((tmp_path / "axis.json").read_text())["kind"] == "spin"


def test_pivot_refusals_write_nothing(tmp_path, capsys):
    rng = np.random.default_rng(1)
    write_poses_csv(tmp_path / "few.csv", simulate_pivot_poses(6, TIP, PIVOT, rng))
    rc, cap = _run(capsys, "pivot", tmp_path / "few.csv", "-o", tmp_path / "tip.json")
    assert rc == 2 and cap.err.strip().startswith("error: expected at least 10 poses")
    assert len(cap.err.strip().splitlines()) == 1
    P = simulate_pivot_poses(40, TIP, PIVOT, rng, n_outliers=6)
    write_poses_csv(tmp_path / "slipped.csv", P)
    _points_csv(tmp_path / "points.csv", P[:, :3, 3])
    rc, cap = _run(capsys, "pivot", tmp_path / "points.csv", "-o", tmp_path / "tip.json")
    assert rc == 2 and "positions only" in cap.err
    assert not (tmp_path / "tip.json").exists()
    # a residual above the expected level is answered and flagged, not refused
    rc, cap = _run(capsys, "pivot", tmp_path / "slipped.csv", "-o", tmp_path / "tip.json",
                   "--json")
    s = json.loads(cap.out)
    assert rc == 0 and s["rms_mm"] > 2 and len(s["warnings"]) == 1
    assert f"warning: pivot residual RMS {s['rms_mm']:.3g} mm is above the expected 2 mm" \
        in cap.err
    assert json.loads((tmp_path / "tip.json").read_text())["warnings"] == s["warnings"]


def test_register_command(tmp_path, capsys):
    rng = np.random.default_rng(2)
    rot = Rotation.from_rotvec([0.2, 0.1, -0.3])
    moving = rng.uniform(-0.06, 0.06, (6, 3))
    fixed = rot.apply(moving) + [0.1, 0.2, 0.3] + rng.normal(0, 2e-4, (6, 3))
    _points_csv(tmp_path / "fixed.csv", fixed)
    _points_csv(tmp_path / "moving.csv", moving)
    _points_csv(tmp_path / "targets.csv", np.array([[0.0, 0.0, 0.0], [0.1, 0.1, 0.1]]))
    rc, cap = _run(capsys, "register", tmp_path / "fixed.csv", tmp_path / "moving.csv",
                   "-o", tmp_path / "reg.json", "--targets", tmp_path / "targets.csv", "--json")
    assert rc == 0, cap.err
    s = json.loads(cap.out)
    assert len(s["residual_mm"]) == 6 and len(s["predicted_tre_mm"]) == 2
    assert s["predicted_tre_mm"][1] > s["predicted_tre_mm"][0]
    r = np.linalg.norm(np.array(s["residual_mm"]), axis=1)
    assert s["fre_rms_mm"] == pytest.approx(np.sqrt(np.mean(r ** 2)))
    T = np.array(json.loads((tmp_path / "reg.json").read_text())["transform"])
    np.testing.assert_allclose(T[:3, :3], rot.as_matrix(), atol=0.01)
    _points_csv(tmp_path / "five.csv", moving[:5])
    rc, cap = _run(capsys, "register", tmp_path / "fixed.csv", tmp_path / "five.csv",
                   "-o", tmp_path / "reg2.json")
    assert rc == 2 and "as many points" in cap.err and not (tmp_path / "reg2.json").exists()


def test_assess_command_with_grid_and_html(tmp_path, capsys):
    rng = np.random.default_rng(3)
    nominal = regular_grid(0.05, (4, 3, 2))
    samples, labels = simulate_grid_points(nominal, rng, noise=2e-4, repeats=2)
    P = np.tile(np.eye(4), (len(samples), 1, 1))
    P[:, :3, 3] = samples
    write_poses_csv(tmp_path / "measured.csv", P, group=labels.astype(str))
    rc, cap = _run(capsys, "assess", tmp_path / "measured.csv", "--grid-pitch-mm", 50,
                   "--grid-shape", "4,3,2", "-o", tmp_path / "report.html", "--json")
    assert rc == 0, cap.err
    s = json.loads(cap.out)
    for key in ("rigid_rms_mm", "rigid_mean_mm", "rigid_max_mm", "distance_error_mean_mm",
                "distance_error_rms_mm", "n"):
        assert np.isfinite(s[key])
    assert s["n"] == 24 and s["jitter"]["n_samples"] == 48
    html = (tmp_path / "report.html").read_text()
    assert html.count("<img") == 2 and "Distance errors" in html
    _points_csv(tmp_path / "nominal.csv", nominal)
    rc, cap = _run(capsys, "assess", tmp_path / "measured.csv", "--nominal",
                   tmp_path / "nominal.csv", "--json")
    assert rc == 0 and json.loads(cap.out)["rigid_rms_mm"] == s["rigid_rms_mm"]
    rc, cap = _run(capsys, "assess", tmp_path / "measured.csv", "-o", tmp_path / "r2.html")
    assert rc == 2 and "--nominal FILE or --grid-pitch-mm" in cap.err
    assert not (tmp_path / "r2.html").exists()
