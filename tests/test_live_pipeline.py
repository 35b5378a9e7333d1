"""The live pipeline: simulated device / replay -> demodulation -> LM -> IGTL, log, CLI."""

from __future__ import annotations

import json
import time

import h5py
import numpy as np
import pytest
from _counts import converged_only
from _igtl_listener import Listener

from openemt._errors import InputError
from openemt.geometry import vector_from_pose
from openemt.live import (
    IgtlServer,
    ReplayBackend,
    SensorSetup,
    SimulatedBackend,
    TrackingPipeline,
    TrackLog,
    default_model,
    default_trajectory,
)
from openemt.signal import RawSignalConfig, simulate_raw, write_raw

MODEL = default_model()


def _pipeline(duration=0.2, config=None, seed=0, solver=None, correction=None, **kw):
    b = SimulatedBackend(MODEL, config=config, seed=seed, duration=duration)
    sensor = SensorSetup(model=MODEL, solver=solver, correction=correction)
    return b, TrackingPipeline(b, sensor, **kw)


def test_simulated_run_tracks_truth():
    _, p = _pipeline(0.3)
    log = TrackLog()
    p.log = log
    s = p.run()
    assert s.n_samples == len(log.arrays()["times"]) > 400
    assert s.status_counts == converged_only(s.n_samples)
    assert s.distorted_fraction == 0.0
    a = log.arrays()
    truth = default_trajectory(a["times"])
    err = np.linalg.norm(a["poses"][:, :3, 3] - truth[:, :3, 3], axis=1)
    # default noise gives a few micrometres at 200 mm; 50 um leaves room but catches a bias
    assert np.sqrt(np.mean(err ** 2)) < 50e-6
    R_err = np.einsum("kji,kjl->kil", a["poses"][:, :3, :3], truth[:, :3, :3])
    ang = np.arccos(np.clip((np.trace(R_err, axis1=1, axis2=2) - 1) / 2, -1, 1))
    assert ang.max() < 1e-3
    assert s.truth["position_error_mm_rms"] == pytest.approx(1e3 * np.sqrt(np.mean(err ** 2)))


def test_batch_solver_injection_and_warm_start():
    calls, results = [], []

    def solver(C, initial):
        from openemt.solve import solve_lm
        calls.append(initial if isinstance(initial, str) else np.array(initial))
        res = solve_lm(C, MODEL, initial=initial, hemisphere="+x")
        results.append(res)
        return res

    _, p = _pipeline(0.05, solver=solver)
    p.run()
    assert len(calls) > 3
    assert calls[0] == "kim18"                          # acquisition
    for k in range(1, len(calls)):                      # then warm starts from the last pose
        np.testing.assert_array_equal(calls[k], np.broadcast_to(
            results[k - 1].pose_vectors[-1], calls[k].shape))


def test_distortion_flag_from_eddy_currents():
    _, p = _pipeline(0.05, config=RawSignalConfig(eddy_strength=0.05))
    assert p.run().distorted_fraction == 1.0
    _, p = _pipeline(0.05)
    assert p.run().distorted_fraction == 0.0


def test_linear_correction_is_applied():
    L = np.eye(4)
    L[:3, 3] = [0.001, -0.002, 0.0005]
    logs = []
    for corr in (None, L):
        _, p = _pipeline(0.03, seed=2, correction=corr, log=TrackLog())
        p.run()
        logs.append(p.log.arrays())
    d = logs[1]["poses"][:, :3, 3] - logs[0]["poses"][:, :3, 3]
    np.testing.assert_allclose(d, np.broadcast_to(L[:3, 3], d.shape), atol=1e-12)
    np.testing.assert_allclose(logs[1]["pose_vectors"], vector_from_pose(logs[1]["poses"]))


def test_replay_of_recording(tmp_path):
    raw = simulate_raw(MODEL, default_trajectory, 0.2, RawSignalConfig(), seed=3)
    path = tmp_path / "rec.h5"
    write_raw(raw, path)
    b = ReplayBackend(path)
    s = TrackingPipeline(b, MODEL).run()
    assert s.n_samples == 299 and s.status_counts == converged_only(299)
    assert s.truth["position_error_mm_rms"] < 0.05


def test_log_files(tmp_path):
    _, p = _pipeline(0.03, log=TrackLog())
    p.run()
    a = p.log.arrays()
    p.log.write(tmp_path / "t.h5")
    p.log.write(tmp_path / "t.csv")
    with h5py.File(tmp_path / "t.h5") as f:
        assert f.attrs["format"] == "openemt-track"
        np.testing.assert_array_equal(f["pose_vectors"][()], a["pose_vectors"])
        np.testing.assert_array_equal(f["couplings"][()], a["couplings"])
    table = np.loadtxt(tmp_path / "t.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(table[:, 1:7], a["pose_vectors"], rtol=1e-8, atol=1e-12)
    with pytest.raises(ValueError, match="csv"):
        p.log.write(tmp_path / "t.txt")


def test_igtl_client_receives_the_trajectory():
    # the client keeps only the latest message per device and the viewer polls each device
    # every 10 ms: a second of signal gives it many chances even when a loaded machine delays
    # the polling thread
    b = SimulatedBackend(MODEL, duration=1.0, realtime=True)
    with IgtlServer(port=0, device_name="Sensor") as srv:
        viewer = Listener(srv.port, ["Sensor", "SensorStatus"])
        try:
            assert srv.wait_for_client(3.0)
            b.t0_epoch = time.time()
            s = TrackingPipeline(b, MODEL, igtl=srv).run()
            time.sleep(0.1)
        finally:
            viewer.stop()
        received = viewer.got["Sensor"]
        status = viewer.got["SensorStatus"]
        assert s.igtl["sent"] > 0
        assert status and status[-1][1].startswith("CONVERGED distorted=0")
    assert len(received) >= 10
    t = np.array([r[0] for r in received]) - b.t0_epoch
    M = np.stack([r[1] for r in received])
    truth = default_trajectory(t)
    np.testing.assert_allclose(M[:, :3, 3], 1000.0 * truth[:, :3, 3], atol=0.05)   # mm
    np.testing.assert_allclose(M[:, :3, :3], truth[:, :3, :3], atol=1e-3)


# ---------------------------------------------------------------------------- CLI

def test_cli_track_sim_json(cli, capsys, tmp_path):
    code = cli(["track", "--source", "sim", "--duration", "0.1", "--fast", "--no-igtl",
                "--log", str(tmp_path / "log.csv"), "--save-raw", str(tmp_path / "raw.h5"),
                "--json", "--quiet"])
    out = capsys.readouterr().out
    assert code == 0
    d = json.loads(out)
    assert d["n_samples"] == 149 and d["status_counts"] == converged_only(149)
    assert d["truth"]["position_error_mm_rms"] < 0.05
    code = cli(["track", "--source", "replay", str(tmp_path / "raw.h5"), "--fast",
                "--igtl-port", "0", "--json", "--quiet"])
    d2 = json.loads(capsys.readouterr().out)
    assert code == 0 and d2["n_samples"] == 149 and d2["igtl"]["sent"] == 0


def test_cli_corrupt_replay_is_one_line_error(cli, capsys, tmp_path):
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"not an hdf5 file at all" * 50)
    code = cli(["track", "--source", "replay", str(bad), "--fast", "--no-igtl", "--json"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and err[0].startswith("error: expected")
    assert cli(["track", "--source", "replay", "--no-igtl"]) == 2
    assert cli(["track", "--source", "replay", str(tmp_path / "missing.h5"), "--no-igtl"]) == 2


def test_cli_track_with_a_calibration_file(cli, capsys, tmp_path):
    from openemt.io import write_calibration
    from openemt.simulate import truth_calibration

    path = tmp_path / "cal.json"
    write_calibration(truth_calibration("concentric"), path)
    code = cli(["track", "--calibration", str(path), "--duration", "0.05", "--fast",
                "--no-igtl", "--json", "--quiet"])
    d = json.loads(capsys.readouterr().out)
    assert code == 0 and d["status_counts"] == converged_only(d["n_samples"])
    assert d["truth"]["position_error_mm_rms"] < 0.05


def test_drive_dropout_is_flagged_and_tracking_recovers():
    class Dropout(SimulatedBackend):
        def read(self):
            x = super().read()
            if x is not None and 0.05 < self._i / self.layout.sample_rate < 0.1:
                x = x.copy()
                x[:, list(self.layout.reference_channels)] = 0.0     # no drive current
            return x

    b = Dropout(MODEL, duration=0.2)
    log = TrackLog()
    s = TrackingPipeline(b, MODEL, log=log).run()
    a = log.arrays()
    assert s.status_counts["invalid_input"] >= 60
    assert np.all(a["status"][-50:] == 0)                    # re-acquired after the drop-out
    assert s.truth["position_error_mm_rms"] < 0.05


def test_simulate_ahead_hands_over_the_same_samples():
    """A simulated device whose samples are all simulated before the first read (the latency
    bench) delivers exactly what one simulating as it goes delivers; an endless one refuses."""
    def chunks(ahead):
        b = SimulatedBackend(seed=4, duration=0.03, chunk=640)
        if ahead:
            b.simulate_ahead()
        out = []
        while (x := b.read()) is not None:
            out.append(x)
        return out

    a, b = chunks(False), chunks(True)
    assert len(a) == len(b) == 5 and all(np.array_equal(x, y) for x, y in zip(a, b))
    with pytest.raises(InputError, match="finite `duration`"):
        SimulatedBackend(seed=4, chunk=640).simulate_ahead()
