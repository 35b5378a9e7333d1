"""The navigation steps read every pose file openemt writes (made here by the real commands:
simulate -> solve, track --log to .h5 and .csv), refuse what is not a rotation or too large
before parsing, count the rows they leave out, and the registration pairs by label and exports
to 3D Slicer."""

import json
import shutil

import h5py
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from openemt.cli import main
from openemt.io import pose_dataset, write_dataset, write_poses_csv
from openemt.live import example_tracker
from openemt.navigate import (
    RegisterOptions,
    read_registration,
    read_tool_poses,
    register,
    register_points,
    simulate_pivot_poses,
    write_markups,
    write_slicer_transform,
)
from openemt.solve import Status, read_poses


def _run(capsys, *argv):
    rc = main([str(a) for a in argv])
    return rc, capsys.readouterr()


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """Files from the real commands: a solve output and track logs in both formats."""
    d = tmp_path_factory.mktemp("made")
    for argv in (["simulate", "-o", d / "sim.h5", "--truth-calibration", d / "cal.json",
                  "--seed", "1", "--quiet"],
                 ["solve", d / "sim.h5", "--calibration", d / "cal.json", "-o", d / "poses.h5",
                  "--quiet"],
                 ["track", "--source", "sim", "--fast", "--duration", "1", "--no-igtl", "--log",
                  d / "log.h5", "--quiet"],
                 ["track", "--source", "sim", "--fast", "--duration", "1", "--no-igtl", "--log",
                  d / "log.csv", "--quiet"],
                 ["track", "--tracker", example_tracker("simulated-2"), "--source", "sim",
                  "--fast", "--duration", "0.5", "--no-igtl", "--log", d / "two.h5", "--quiet"],
                 ["track", "--tracker", example_tracker("simulated-2"), "--source", "sim",
                  "--fast", "--duration", "0.5", "--no-igtl", "--log", d / "two.csv", "--quiet"]):
        assert main([str(a) for a in argv]) == 0, argv
    return d


def test_solve_output_reads_with_unconverged_rows_counted(made, tmp_path):
    res = read_poses(made / "poses.h5")
    t = read_tool_poses(made / "poses.h5")
    ok = res.status == Status.CONVERGED
    assert t.kind == "poses-h5" and len(t.poses) == len(res.status)
    np.testing.assert_array_equal(t.poses[ok], res.poses[ok])
    assert np.all(np.isnan(t.poses[~ok]))
    assert t.dropped["not_converged"] == int((~ok).sum())
    # some rows marked failed: counted, and said on stderr and in the JSON
    shutil.copy(made / "poses.h5", tmp_path / "p.h5")
    with h5py.File(tmp_path / "p.h5", "r+") as f:
        f["status"][:5] = int(Status.MAX_ITERATIONS)
    assert read_tool_poses(tmp_path / "p.h5").dropped["not_converged"] >= 5


@pytest.mark.parametrize("cmd", ["pivot", "spin", "assess", "points"])
def test_nothing_converged_is_one_error_line(made, tmp_path, capsys, cmd):
    shutil.copy(made / "poses.h5", tmp_path / "p.h5")
    with h5py.File(tmp_path / "p.h5", "r+") as f:
        f["status"][:] = int(Status.NOT_CONVERGED)
        n = len(f["status"])
    extra = ["--grid-pitch-mm", "50", "--grid-shape", "3,3"] if cmd == "assess" else []
    rc, cap = _run(capsys, cmd, tmp_path / "p.h5", *extra)
    assert rc == 2 and cap.err.count("\n") == 1, cap.err
    assert cap.err.startswith(f"error: expected at least one usable pose in {tmp_path / 'p.h5'},"
                              f" got none of {n} rows ({n} not converged)")


def test_track_logs_read_alike_in_both_formats(made):
    h5, csv = read_tool_poses(made / "log.h5"), read_tool_poses(made / "log.csv")
    assert h5.kind == csv.kind == "track-log" and h5.has_orientation and csv.has_orientation
    assert len(h5.poses) > 100 and h5.times is not None and csv.times is not None
    # two sessions of the same simulation: the same poses, the CSV rounded to 9 digits
    m = min(len(h5.poses), len(csv.poses))
    np.testing.assert_allclose(csv.poses[:m], h5.poses[:m], atol=1e-6)
    np.testing.assert_allclose(csv.times[:m], h5.times[:m], atol=1e-5)


def test_track_logs_of_two_sensors(made, capsys):
    for name in ("two.h5", "two.csv"):
        rc, cap = _run(capsys, "pivot", made / name)
        assert rc == 2 and cap.err == (f"error: expected --sensor naming one of Probe, "
                                       f"Reference for {made / name}, got none\n")
    probe = [read_tool_poses(made / n, sensor="Probe") for n in ("two.h5", "two.csv")]
    ref = read_tool_poses(made / "two.h5", sensor="Reference")
    assert len(probe[0].poses) == len(probe[1].poses) == len(ref.poses) > 100
    np.testing.assert_allclose(probe[1].poses, probe[0].poses, atol=1e-6)
    # the two sensors of the example tracker keep a fixed distance (about 58 mm)
    d = np.linalg.norm(ref.poses[:, :3, 3] - probe[0].poses[:, :3, 3], axis=1)
    assert np.all(np.abs(d - np.median(d)) < 1e-3) and np.median(d) > 0.01


def test_track_log_rows_dropped_by_reason(made, tmp_path, capsys):
    """A pivot recorded as a track-log CSV (the header of a real one) with a failed, a
    non-finite and a torn row: the fit leaves them out and says so, by reason."""
    from openemt.geometry import vector_from_pose

    head = (made / "log.csv").read_text().splitlines()[0]
    P = simulate_pivot_poses(40, [0.002, -0.001, 0.155], [0.1, 0.0, 0.2],
                             np.random.default_rng(3))
    body = [",".join([f"{0.01 * k:.6f}"] + [f"{v:.9g}" for v in vector_from_pose(p)]
                     + ["0"] * (len(head.split(",")) - 7)) for k, p in enumerate(P)]
    cols = body[3].split(",")
    cols[7] = str(int(Status.MAX_ITERATIONS))
    body[3] = ",".join(cols)
    body[5] = ",".join(["nan" if k == 2 else v for k, v in enumerate(body[5].split(","))])
    body[7] = ",".join(body[7].split(",")[:4])                  # a torn row
    body[9] = ",".join(["1e300" if k == 1 else v for k, v in enumerate(body[9].split(","))])
    (tmp_path / "log.csv").write_text("\n".join([head] + body) + "\n")
    t = read_tool_poses(tmp_path / "log.csv")
    assert t.kind == "track-log" and t.n_usable == 36
    assert t.dropped == {"bad_line": 1, "not_converged": 1, "not_finite": 1, "out_of_range": 1}
    rc, cap = _run(capsys, "pivot", tmp_path / "log.csv", "--json")
    s = json.loads(cap.out)
    assert rc == 0 and s["n"] == 36 and s["dropped"] == t.dropped
    assert ("left out 4 of 40 rows of log.csv: 1 bad line, 1 not converged, 1 not finite, "
            "1 out of range" in cap.err)


def test_rotation_blocks_that_are_not_rotations_are_refused(made, tmp_path, capsys):
    P = simulate_pivot_poses(40, [0.002, -0.001, 0.155], [0.1, 0.0, 0.2],
                             np.random.default_rng(0))
    for name, M in (("scaled", 2 * np.eye(3)), ("sheared", np.array([[1, 0.3, 0], [0, 1, 0],
                                                                      [0, 0, 1.0]]))):
        shutil.copy(made / "log.h5", tmp_path / f"{name}.h5")
        with h5py.File(tmp_path / f"{name}.h5", "r+") as f:
            Q = P[np.arange(len(f["poses"])) % len(P)].copy()
            Q[:, :3, :3] = Q[:, :3, :3] @ M
            f["poses"][...] = Q
        rc, cap = _run(capsys, "pivot", tmp_path / f"{name}.h5", "--json")
        assert rc == 2 and cap.out == "" and cap.err.count("\n") == 1
        assert "rotation blocks within 1e-05 of a rotation" in cap.err
        assert "scaled, sheared or reflected" in cap.err
    # the same poses unscaled give the tip
    with h5py.File(tmp_path / "scaled.h5", "r+") as f:
        f["poses"][...] = P[np.arange(len(f["poses"])) % len(P)]
    rc, cap = _run(capsys, "pivot", tmp_path / "scaled.h5", "--json")
    assert rc == 0 and np.allclose(json.loads(cap.out)["tip_mm"], [2, -1, 155], atol=0.5)


def test_pose_dataset_and_csv_read(tmp_path):
    P = simulate_pivot_poses(30, [0.0, 0.0, 0.1], [0.1, 0.0, 0.2], np.random.default_rng(1))
    write_dataset(pose_dataset(P, file_index=np.zeros(30, int), files=["x"]), tmp_path / "d.h5")
    write_poses_csv(tmp_path / "p.csv", P, time=np.arange(30) * 0.1)
    d, c = read_tool_poses(tmp_path / "d.h5"), read_tool_poses(tmp_path / "p.csv")
    assert (d.kind, c.kind) == ("dataset", "csv")
    np.testing.assert_allclose(c.poses, d.poses, atol=1e-12)
    np.testing.assert_allclose(c.times, np.arange(30) * 0.1)


def test_files_too_large_are_refused_before_parsing(tmp_path, capsys):
    big = tmp_path / "big.fcsv"
    with open(big, "wb") as f:
        f.truncate(5 << 30)                                  # sparse: no disk used
    (tmp_path / "a.csv").write_text("x_mm,y_mm,z_mm\n0,0,0\n1,0,0\n0,1,0\n")
    rc, cap = _run(capsys, "register", tmp_path / "a.csv", big)
    assert rc == 2 and cap.err.count("\n") == 1 and "at most 256 MiB" in cap.err


# ------------------------------------------------------------------------------ registration

def _labelled(tmp_path, name, pts, labels):
    write_markups(tmp_path / name, pts, labels)
    return tmp_path / name


def test_register_pairs_by_label_and_refuses_labels_that_differ(tmp_path, capsys):
    rng = np.random.default_rng(4)
    moving = rng.uniform(-0.06, 0.06, (6, 3))
    rot = Rotation.from_rotvec([0.2, -0.3, 0.5])
    fixed = rot.apply(moving) + [0.01, 0.02, -0.03] + rng.normal(0, 2e-4, (6, 3))
    labels = [f"F-{i + 1}" for i in range(6)]
    f = _labelled(tmp_path, "fixed.mrk.json", fixed, labels)
    perm = rng.permutation(6)
    m = _labelled(tmp_path, "moving.fcsv", moving[perm], [labels[i] for i in perm])
    rc, cap = _run(capsys, "register", f, m, "-o", tmp_path / "reg.json", "--json")
    s = json.loads(cap.out)
    assert rc == 0 and s["paired_by"] == "label" and s["fre_rms_mm"] < 0.5
    np.testing.assert_allclose(np.array(s["transform"])[:3, :3], rot.as_matrix(), atol=5e-3)
    # by row order only when asked: here the wrong pairs, flagged by the FRE
    rc, cap = _run(capsys, "register", f, m, "--match", "order", "--json")
    s = json.loads(cap.out)
    assert rc == 0 and s["paired_by"] == "order" and s["fre_rms_mm"] > 10
    assert "FRE RMS" in s["warnings"][0] and "warning: FRE RMS" in cap.err
    # labels that do not match: one line naming them
    m2 = _labelled(tmp_path, "other.fcsv", moving, labels[:5] + ["G-9"])
    rc, cap = _run(capsys, "register", f, m2, "-o", tmp_path / "r2.json")
    assert rc == 2 and cap.err.count("\n") == 1 and not (tmp_path / "r2.json").exists()
    assert "F-6 only in the first and G-9 only in the second" in cap.err
    # -o naming its own input
    rc, cap = _run(capsys, "register", f, m, "-o", m)
    assert rc == 2 and "different from the input" in cap.err
    # points near 1e300, and collinear points: one line each
    (tmp_path / "huge.csv").write_text("x,y,z\n" + "".join(f"{1e300 * (i > 4)},{i},0\n"
                                                           for i in range(6)))
    rc, cap = _run(capsys, "register", tmp_path / "huge.csv", f, "--match", "order")
    assert rc == 2 and cap.err.count("\n") == 1 and "within 10000 m" in cap.err
    assert "got 1 that are not (rows 5)" in cap.err
    with pytest.raises(ValueError, match="within 10000 m"):
        register_points(np.full((4, 3), 1e5) + np.eye(4, 3), np.eye(4, 3))
    (tmp_path / "line.csv").write_text("x,y,z\n" + "".join(f"{i},{2 * i},0\n" for i in range(6)))
    rc, cap = _run(capsys, "register", f, tmp_path / "line.csv")
    assert rc == 2 and cap.err.count("\n") == 1 and "collinear" in cap.err


def test_slicer_transform_of_a_known_case(tmp_path):
    """A 90 deg rotation about z and a translation (10, 20, 30) mm, tracker -> image (RAS).

    By hand: the inverse is R^T = [[0, 1, 0], [-1, 0, 0], [0, 0, 1]] with translation
    -R^T t = (-20, 10, -30); in LPS (x and y negated on both sides) the matrix keeps its signs
    and the translation becomes (20, -10, -30)."""
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    T[:3, 3] = [0.010, 0.020, 0.030]
    text = write_slicer_transform(tmp_path / "reg.tfm", T).read_text().splitlines()
    assert text[0] == "#Insight Transform File V1.0"
    assert text[2] == "Transform: AffineTransform_double_3_3"
    params = [float(v) for v in text[3].split(":")[1].split()]
    np.testing.assert_allclose(params, [0, 1, 0, -1, 0, 0, 0, 0, 1, 20, -10, -30], atol=1e-12)
    assert text[4] == "FixedParameters: 0 0 0"
    # read back (as track would read a transform saved by Slicer): the registration again
    T2, meta = read_registration(tmp_path / "reg.tfm")
    np.testing.assert_allclose(T2, T, atol=1e-15)
    assert meta == {"format": "itk"}
    # an ITK centre is honoured: y = A (x - c) + c + t
    lines = list(text)
    lines[3] = "Parameters: 0 1 0 -1 0 0 0 0 1 20 -10 -30"
    lines[4] = "FixedParameters: 5 6 7"
    (tmp_path / "c.txt").write_text("\n".join(lines) + "\n")
    A = np.array([[0, 1, 0], [-1, 0, 0], [0, 0, 1.0]])
    M = np.eye(4)
    M[:3, :3], M[:3, 3] = A, np.array([20, -10, -30]) + [5, 6, 7] - A @ [5, 6, 7]
    F = np.diag([-1.0, -1, 1, 1])
    want = np.linalg.inv(F @ M @ F)
    want[:3, 3] *= 1e-3
    np.testing.assert_allclose(read_registration(tmp_path / "c.txt")[0], want, atol=1e-15)


def test_registration_file_reads_back(tmp_path):
    moving = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1]])
    fixed = moving @ Rotation.from_rotvec([0, 0, 0.4]).as_matrix().T + [0.01, 0, 0]
    write_markups(tmp_path / "f.mrk.json", fixed, list("ABCD"))
    write_markups(tmp_path / "m.mrk.json", moving, list("ABCD"))
    run = register(RegisterOptions(fixed=str(tmp_path / "f.mrk.json"),
                                   moving=str(tmp_path / "m.mrk.json"),
                                   output=str(tmp_path / "reg.json"),
                                   slicer_transform=str(tmp_path / "reg.txt")))
    T, meta = read_registration(tmp_path / "reg.json")
    np.testing.assert_allclose(T, run.result.transform)
    np.testing.assert_allclose(T[:3, :3] @ moving.T + T[:3, 3:], fixed.T, atol=1e-12)
    assert meta["format"] == "openemt.registration" and meta["fre_rms_mm"] < 1e-9
    (tmp_path / "bad.json").write_text(json.dumps({**meta, "transform": (2 * T).tolist()}))
    with pytest.raises(ValueError, match="rigid"):
        read_registration(tmp_path / "bad.json")
