"""``openemt points`` (dwells of a log -> 3D Slicer markups) and the simulated tool motions
(``simulate_tool_session``, ``openemt simulate --motion``)."""

import json

import numpy as np
import pytest

from openemt.cli import main
from openemt.io import write_poses_csv
from openemt.navigate import (
    MotionOptions,
    PointsOptions,
    points,
    read_markups,
    read_tool_poses,
    simulate_tool_session,
)


def _dwell_log(path, stops, rng, rate=50.0, scale=1.0):
    """A tool that holds still 1 s at each stop and moves 0.5 s between them."""
    key_t, key_p = [0.0], [stops[0] + [0, 0, 0.02]]
    for s in stops:
        key_t += [key_t[-1] + 0.5, key_t[-1] + 1.5]
        key_p += [s, s]
    key_t.append(key_t[-1] + 0.5)
    key_p.append(stops[-1] + [0, 0, 0.02])
    t = np.arange(0, key_t[-1], 1 / rate)
    p = np.stack([np.interp(t, key_t, np.array(key_p)[:, a]) for a in range(3)], axis=1)
    P = np.tile(np.eye(4), (len(t), 1, 1))
    P[:, :3, 3] = p + rng.normal(0, 3e-5, p.shape)
    write_poses_csv(path, P, time=scale * t)
    return path


def test_points_finds_every_dwell_and_writes_markups(tmp_path, capsys):
    rng = np.random.default_rng(0)
    stops = rng.uniform(-0.05, 0.05, (4, 3))
    log = _dwell_log(tmp_path / "log.csv", stops, rng)
    run = points(PointsOptions(log=str(log), output=str(tmp_path / "p.mrk.json"),
                               labels="A,B,C,D"))
    assert run.summary["n_points"] == 4 and run.summary["labels"] == ["A", "B", "C", "D"]
    m = read_markups(tmp_path / "p.mrk.json")
    np.testing.assert_allclose(m.points, stops, atol=2e-5)
    assert m.labels.tolist() == ["A", "B", "C", "D"]
    # .fcsv by its suffix, labels F-1.. by default
    rc = main(["points", str(log), "-o", str(tmp_path / "p.fcsv"), "--json"])
    s = json.loads(capsys.readouterr().out)
    assert rc == 0 and s["labels"] == ["F-1", "F-2", "F-3", "F-4"]
    np.testing.assert_allclose(read_markups(tmp_path / "p.fcsv").points, stops, atol=2e-5)


@pytest.mark.parametrize("case, message", [
    ("ms", "times in ms"), ("back", "times that do not increase"),
    ("labels", "expected 4 labels")])
def test_points_refusals_are_one_line(tmp_path, capsys, case, message):
    rng = np.random.default_rng(1)
    stops = rng.uniform(-0.05, 0.05, (4, 3))
    log = _dwell_log(tmp_path / "log.csv", stops, rng, scale=1e3 if case == "ms" else 1.0)
    if case == "back":
        lines = log.read_text().splitlines()
        lines[20], lines[21] = lines[21], lines[20]
        log.write_text("\n".join(lines) + "\n")
    extra = ["--labels", "a,b"] if case == "labels" else []
    rc = main(["points", str(log), "-o", str(tmp_path / "p.mrk.json"), *extra])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and message in err, err
    assert not (tmp_path / "p.mrk.json").exists()


@pytest.mark.parametrize("motion", ["pivot", "fiducials"])
def test_simulated_motion_writes_log_and_truth(tmp_path, motion):
    run = simulate_tool_session(MotionOptions(motion=motion, output=str(tmp_path / "m.csv"),
                                              seed=2, rate_hz=20))
    t = read_tool_poses(tmp_path / "m.csv")
    assert t.kind == "track-log" and t.n_usable == run.summary["n_converged"] > 100
    truth = json.loads((tmp_path / "m.truth.json").read_text())
    assert truth["tip_mm"] == [2.0, -1.0, 120.0]
    # the tool's tip stays where the truth says (the tracker's error is about 1 mm here)
    tips = t.poses[:, :3, :3] @ (1e-3 * np.array(truth["tip_mm"])) + t.poses[:, :3, 3]
    if motion == "pivot":
        assert np.abs(1e3 * tips - truth["pivot_mm"]).max() < 5
    else:
        image = read_markups(tmp_path / "m.image.mrk.json")
        np.testing.assert_allclose(1e3 * image.points, truth["fiducials_image_mm"], atol=1e-3)
        T = np.array(truth["image_from_tracker"])
        f = 1e-3 * np.array(truth["fiducials_tracker_mm"])
        np.testing.assert_allclose(f @ T[:3, :3].T + T[:3, 3], image.points, atol=1e-6)


def test_simulate_motion_command_refusals(tmp_path, capsys):
    rc = main(["simulate", "--motion", "spin", "--preset", "anser", "-o",
               str(tmp_path / "s.csv")])
    assert rc == 2 and "6-DOF sensor" in capsys.readouterr().err
    rc = main(["simulate", "--motion", "spin", "-o", str(tmp_path / "s.h5")])
    assert rc == 2 and "ending in .csv" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
