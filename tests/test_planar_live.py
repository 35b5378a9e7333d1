"""`openemt track` with a finite-coil (board) calibration: the simulated board (8 carriers, one
sensor channel), demodulation, the warm-started 5-DOF solver, log, replay, OpenIGTLink."""

from __future__ import annotations

import json
import time
import tomllib

import numpy as np
import pytest
from _counts import converged_only
from _igtl_listener import Listener

from openemt.board import BoardModel
from openemt.io import Calibration, write_calibration
from openemt.live import IgtlServer, TrackingPipeline, example_tracker, read_tracker
from openemt.live._board import (
    BOARD_FREQUENCIES,
    board_default_spec,
    board_solver,
    board_trajectory,
)
from openemt.live._session import tracker_backend, tracker_sensors
from openemt.solve import Status


@pytest.fixture(scope="module")
def board_cal(tmp_path_factory):
    rng = np.random.default_rng(5)
    model = BoardModel.from_board("anser", gains=rng.uniform(0.9, 1.1, 8),
                                   offsets=rng.normal(0.0, 1e-3, (8, 3)))
    path = tmp_path_factory.mktemp("board") / "board_cal.json"
    write_calibration(Calibration(model, mode="planar"), path)
    return path


def test_shipped_board_tracker_and_carrier_plan():
    spec = read_tracker(example_tracker("anser"))
    assert spec.frequencies == BOARD_FREQUENCIES
    assert spec.layout().sensor_channels == (0,) and spec.n_channels == 9
    cal = spec.calibrations()[0]
    assert cal.kind == "finite" and cal.n_source == 8
    from openemt.signal import frame_length

    hop, L = frame_length(spec.layout(), spec.output_rate, "hann")
    bins = np.asarray(BOARD_FREQUENCIES) * L / spec.sample_rate
    assert (hop, L) == (64, 128) and np.all(np.diff(bins) == 4)
    doc = tomllib.loads(example_tracker("anser").read_text())
    assert doc["sensors"][0]["calibration"] == "anser-nominal.json"


def test_cli_track_with_a_board_calibration(cli, capsys, board_cal):
    code = cli(["track", "--calibration", str(board_cal), "--source", "sim", "--duration",
                "0.5", "--fast", "--json", "--quiet", "--no-igtl"])
    out, err = capsys.readouterr()
    assert code == 0, err
    d = json.loads(out)
    assert d["n_samples"] == 749
    assert d["status_counts"]["converged"] >= 0.99 * d["n_samples"]
    assert d["truth"]["position_error_mm_rms"] < 1.0
    assert d["truth"]["position_error_mm_max"] < 1.0


def test_board_tracker_file_log_and_replay(cli, capsys, tmp_path):
    import h5py

    tracker = example_tracker("anser")
    code = cli(["track", "--tracker", str(tracker), "--duration", "0.2", "--fast", "--no-igtl",
                "--log", str(tmp_path / "log.h5"), "--save-raw", str(tmp_path / "raw.h5"),
                "--json", "--quiet"])
    d = json.loads(capsys.readouterr().out)
    assert code == 0 and d["status_counts"] == converged_only(d["n_samples"])
    assert d["truth"]["position_error_mm_rms"] < 1.0
    with h5py.File(tmp_path / "log.h5") as f:
        poses = f["poses"][()]
        assert f["couplings"].shape == (d["n_samples"], 8, 1)
    # the pose's z axis is the sensor axis; its rotation is the smallest one taking z there
        times = f["times"][()]
    truth = board_trajectory(times)
    cos = np.einsum("ni,ni->n", poses[:, :3, 2], truth[:, :3, 2])
    assert np.all(cos > np.cos(np.radians(0.05)))
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, poses[:, :3, 2])
    np.testing.assert_allclose(np.einsum("nij,nj->ni", poses[:, :3, :3], axis), axis,
                               atol=1e-9)                         # turned about z x u only
    nominal = str(tracker.parent / "anser-nominal.json")
    for args in (["--tracker", str(tracker)], ["--calibration", nominal]):   # file or layout
        code = cli(["track", *args, "--source", "replay", str(tmp_path / "raw.h5"), "--fast",
                    "--no-igtl", "--json", "--quiet", "--log", str(tmp_path / "replay.h5")])
        r = json.loads(capsys.readouterr().out)
        assert code == 0 and r["n_samples"] == d["n_samples"]
        assert r["status_counts"] == d["status_counts"]
        assert r["truth"]["position_error_mm_rms"] < 1.0      # against the recorded truth
        with h5py.File(tmp_path / "replay.h5") as f:           # the same samples, same poses
            np.testing.assert_allclose(f["poses"][()], poses, rtol=0, atol=1e-12)


def test_board_calibration_refusals(cli, capsys, board_cal, tmp_path):
    # a board calibration on a tri-axial sensor's channels
    text = example_tracker("simulated").read_text().replace(
        'calibration = "concentric.json"', f'calibration = "{board_cal.as_posix()}"')
    t = tmp_path / "t.toml"
    t.write_text(text)
    code = cli(["track", "--tracker", str(t), "--fast", "--no-igtl", "--duration", "0.1"])
    err = capsys.readouterr().err
    assert code == 2 and "one channel per coil" in err and err.count("\n") == 1
    code = cli(["track", "--calibration", str(board_cal), "--preset", "concentric",
                "--no-igtl", "--duration", "0.1"])
    err = capsys.readouterr().err
    assert code == 2 and "--preset" in err and err.count("\n") == 1


def test_board_solver_recovers_after_a_jump():
    model = BoardModel.from_board("anser")
    solve = board_solver(model)
    poses = board_trajectory(np.array([0.0, 0.5, 0.5, 0.5]))
    poses[2:, :3, 3] += [0.06, -0.05, 0.04]                  # the sensor jumps 9 cm
    C = model.coupling(poses)
    first = solve(C[:1], "kim18")                             # acquiring: cold
    assert first.status[0] == Status.CONVERGED
    res = solve(C[1:], np.tile(first.pose_vectors[0], (3, 1)))
    assert np.all(res.status == Status.CONVERGED)
    np.testing.assert_allclose(res.poses[:, :3, 3], poses[1:, :3, 3], atol=1e-8)


def test_board_sensor_streams_to_a_pyigtl_client(board_cal):
    spec = board_default_spec(board_cal, "Needle")
    # a second of signal: the viewer polls every 10 ms and keeps only new messages, so a loaded
    # machine that delays its thread still sees more than 10
    backend = tracker_backend(spec, "sim", realtime=True, duration=1.0)
    assert spec.sensors[0].device_name == "NeedleToTracker"       # <sensor>ToTracker
    with IgtlServer(port=0, device_name="Other") as srv:
        viewer = Listener(srv.port, ["NeedleToTracker"])
        try:
            assert srv.wait_for_client(3.0)
            backend.restart_clock()
            s = TrackingPipeline(backend, sensors=tracker_sensors(spec), igtl=srv,
                                 output_rate=spec.output_rate).run()
            time.sleep(0.1)
        finally:
            viewer.stop()
        received = viewer.got["NeedleToTracker"]
        assert s.igtl["sent"] > 0
    assert len(received) >= 10
    t = np.array([r[0] for r in received]) - backend.t0_epoch
    M = np.stack([r[1] for r in received])
    truth = board_trajectory(t)
    np.testing.assert_allclose(M[:, :3, 3], 1000.0 * truth[:, :3, 3], atol=0.05)   # mm
    np.testing.assert_allclose(M[:, :3, 2], truth[:, :3, 2], atol=1e-3)        # sensor axis


def test_planar_live_bench_small():
    from openemt.bench._planar_speed import planar_live_speed

    out = planar_live_speed(seconds=0.2)
    assert out["planar_live_status_counts"] == converged_only(299)
    assert out["planar_live_realtime_factor"] > 0 and out["planar_live_latency_ms_p50"] > 0
    assert out["planar_live_position_error_mm_rms"] < 0.1


def test_default_board_tracker_says_what_compiles_before_its_gain_fit(board_cal, monkeypatch):
    """The default board tracker fits its sensor gain with the board's compiled coupling: the
    compile notice comes first, with the board's kernels (they compiled before any notice)."""
    import openemt.live._board as board_mod
    from openemt._compile_notice import PLANAR_KERNELS

    events = []
    real_fit = board_mod.fit_sensor_gain
    monkeypatch.setattr(board_mod, "fit_sensor_gain",
                        lambda *a, **k: events.append("fit") or real_fit(*a, **k))
    board_default_spec(board_cal, "Needle", compiling=lambda k: events.append(tuple(k)))
    assert events == [PLANAR_KERNELS, "fit"]
