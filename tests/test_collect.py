"""``openemt collect``: time offset, dwells, the OpenIGTLink reference client, and the command
on a simulated robot served over OpenIGTLink (short collections at --sim-speed 4)."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from openemt.align import (
    collect_dwells,
    coverage,
    estimate_time_offset,
    find_dwells,
)
from openemt.calibrate import reference_poses
from openemt.collect import (
    ReferenceClient,
    SimulatedReferenceServer,
    parse_reference_url,
    simulated_motion,
)
from openemt.geometry import pose_from_vector
from openemt.io import read_dataset, write_poses_csv


def _bumps(t, starts, width=0.5):
    """A motion profile: one smooth bump per move."""
    x = np.zeros_like(t)
    for i, s in enumerate(starts):
        u = np.clip((t - s) / width, 0, 1)
        x += (1 + 0.3 * (i % 3)) * np.sin(np.pi * u) ** 2
    return x


def test_time_offset_by_cross_correlation_of_motion():
    rng = np.random.default_rng(0)
    starts = np.cumsum(rng.uniform(1.2, 2.0, 12))
    ta = 1000.0 + np.arange(0, 25, 0.002)
    a = _bumps(ta - 1000.0, starts) + 0.01 * rng.standard_normal(len(ta))
    true = 0.3172
    tb = 1000.0 + true + np.arange(-1.0, 24.0, 0.002)      # its own clock and span
    b = 3.0 * _bumps(tb - 1000.0 - true, starts) + 0.02 * rng.standard_normal(len(tb))
    off, r = estimate_time_offset(ta, a, tb, b)
    assert abs(off - true) < 1e-3
    assert r > 0.9
    # a search window that excludes the truth gives its edge, with a clearly lower r
    off2, r2 = estimate_time_offset(ta, a, tb, b, max_offset=0.1)
    assert abs(off2) <= 0.1 + 1e-9 and r2 < r - 0.3


def test_dwells_are_trimmed_and_an_open_end_is_left_out():
    t = np.arange(0, 10, 0.01)
    static = (t < 2) | ((t > 3) & (t < 3.35)) | ((t > 5) & (t < 7)) | (t > 9)
    d = find_dwells(t, static, margin=0.1, min_duration=0.3)
    # [0, 2) trimmed to [0.1, 1.89]; the 0.35 s one is too short; [5, 7) kept; (9, 10] open
    assert len(d) == 2
    assert d[0] == pytest.approx([0.1, 1.89], abs=0.011)
    assert d[1] == pytest.approx([5.11, 6.89], abs=0.011)


def _streams(motion, offset, seconds, rate=250.0, move_in_hold=None, drift=2e-3):
    """(``drift``: m/s of the reference within hold ``move_in_hold``)"""
    """Noise-free couplings of a dipole model along the motion and the reference's poses."""
    from openemt.simulate import get_preset

    model = get_preset("concentric").dipole
    tt = np.arange(0, seconds, 1 / 300)
    C = model.coupling(motion.sensor_poses(tt))
    tr = np.arange(0, seconds, 1 / rate)
    B = motion.reference_poses(tr)
    if move_in_hold is not None:          # the reference drifts during one hold
        a, b = motion.hold_starts[move_in_hold], motion.hold_ends[move_in_hold]
        inside = (tr > a) & (tr < b)
        B[inside, 0, 3] += drift * (tr[inside] - a)
    return 50.0 + tt, C, 50.0 + tr + offset, B


# a drift below the static speed (2 mm/s), caught by the halves' means (0.2 mm apart at
# most), and one above the static speed
@pytest.mark.parametrize("drift", [1.5e-3, 10e-3])
def test_collect_dwells_averages_both_streams_and_drops_a_moving_reference(drift):
    m = simulated_motion("robot", 8, seed=3)
    seconds = m.hold_ends[6] + 0.2
    d = collect_dwells(*_streams(m, 0.21, seconds))
    assert abs(d.time_offset - 0.21) < 5e-3          # the requirement: within 5 ms
    assert len(d) == 7 and d.dropped["moved"] == 0
    # each averaged reference pose is the reported pose of its hold
    err = np.abs(d.reference_poses - m.reported[:7]).max()
    assert err < 1e-9
    d2 = collect_dwells(*_streams(m, 0.21, seconds, move_in_hold=3, drift=drift))
    assert len(d2) == 6 and d2.dropped == {"moved": 1, "no_reference": 0}
    assert not np.any((d2.intervals[:, 0] < m.hold_ends[3] + 50.0)
                      & (d2.intervals[:, 1] > m.hold_starts[3] + 50.0))
    # a reference that ends near the end of hold 4: its part with the reference is kept, the
    # later dwells have no reference
    tt, C, tr, B = _streams(m, 0.21, seconds)
    keep = tr < 50.21 + m.hold_ends[4] - 0.05
    d3 = collect_dwells(tt, C, tr[keep], B[keep], time_offset=0.21)
    assert len(d3) == 5 and d3.dropped == {"moved": 0, "no_reference": 2}


def test_coverage_counts_cells_and_rotation_diversity():
    box = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
    p = np.array([[0.1, 0.1, 0.1], [0.12, 0.1, 0.1], [0.9, 0.9, 0.9], [2.0, 0.0, 0.0]])
    one_axis = pose_from_vector(np.column_stack([np.zeros((4, 5)), np.linspace(0, 1, 4)]))
    c = coverage(p, one_axis, box, cells=2)
    assert c["volume_coverage_pct"] == pytest.approx(100 * 2 / 8)
    assert c["outside"] == 1
    assert not c["rotation_diversity_ok"]
    rv = np.random.default_rng(1).normal(scale=0.5, size=(4, 3))
    assert coverage(p, pose_from_vector(np.column_stack([np.zeros((4, 3)), rv])), box)[
        "rotation_diversity_ok"]


@pytest.mark.parametrize("url", ["igtl://127.0.0.1/Robot", "http://h:1/D", "igtl://h:1/",
                                 "igtl://h:99999/D", "igtl://h:1/a/b"])
def test_bad_reference_url(url):
    with pytest.raises(ValueError, match="igtl://HOST:PORT/DEVICE"):
        parse_reference_url(url)


def test_reference_client_keeps_every_transform_of_its_device():
    """Two local pyigtl endpoints: a pyigtl server sends; the client keeps every message of
    its device (pyigtl's own client keeps only the latest), in metres, with the time stamps."""
    import pyigtl

    server = pyigtl.OpenIGTLinkServer(port=0, local_server=True)
    signal.signal(signal.SIGINT, signal.default_int_handler)    # pyigtl installs its own
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    client = ReferenceClient("127.0.0.1", server.server_address[1], "RobotToBase")
    try:
        end = time.monotonic() + 5
        while not server.is_connected():
            assert time.monotonic() < end
            time.sleep(0.01)
        for i in range(40):
            M = np.eye(4)
            M[:3, 3] = [i, 2.0 * i, 100.0]                         # mm
            server.send_message(pyigtl.TransformMessage(M, timestamp=1000.0 + 0.01 * i,
                                                        device_name="RobotToBase"), wait=True)
            server.send_message(pyigtl.TransformMessage(M, timestamp=5.0,
                                                        device_name="Other"), wait=True)
        end = time.monotonic() + 5
        while client.n_messages < 40:
            assert time.monotonic() < end, client.n_messages
            time.sleep(0.01)
        t, B = client.take()
    finally:
        server.stop()
        client.close()
    assert len(t) == 40
    assert t == pytest.approx(1000.0 + 0.01 * np.arange(40), abs=1e-6)
    assert B[:, :3, 3] == pytest.approx(np.column_stack([np.arange(40), 2 * np.arange(40),
                                                         np.full(40, 100.0)]) * 1e-3)
    assert client.n_other == 40
    end = time.monotonic() + 5
    while not client.closed:                     # the server went away: the client says so
        assert time.monotonic() < end
        time.sleep(0.01)


def _collect(run_cli, tmp_path, *extra, n=4):
    out = tmp_path / "col.h5"
    code, stdout, err = run_cli("collect", "--source", "sim", "--n-poses", n, "--seed", 2,
                            "--sim-speed", 4, "-o", out, "--json", *extra)
    return code, (json.loads(stdout) if stdout else None), err, out


def test_collect_announces_the_kernels_it_compiles(run_cli, tmp_path, monkeypatch):
    """The compile step names the cold start's kernel, which collect's first solve runs (it
    compiled after the notice before), and not the check of complex couplings (the pipeline
    solves real ones)."""
    import openemt._compile_notice as notice

    calls = []
    real = notice.announce_compile

    def announce(out=None, what="solver kernels", *, kernels=(), seconds=None):
        calls.append(tuple(kernels))
        return real(out, what, kernels=kernels, seconds=seconds)

    monkeypatch.setattr(notice, "announce_compile", announce)
    code, _, err, _ = _collect(run_cli, tmp_path, "--simulate-reference", "robot")
    assert code == 0, err
    assert len(calls) == 1
    assert set(notice.COLD_START_KERNELS) <= set(calls[0])
    assert not set(notice.COMPLEX_KERNELS) & set(calls[0])
    assert set(calls[0]) == (set(notice.SOLVER_KERNELS + notice.COLD_START_KERNELS)
                             - set(notice.COMPLEX_KERNELS))


def test_collect_simulated_robot_end_to_end(run_cli, tmp_path):
    code, s, err, out = _collect(run_cli, tmp_path, "--simulate-reference", "robot")
    assert code == 0, err
    assert s["n_poses"] == 4 and s["ended_by"] == "n_poses"
    assert abs(s["time_offset_error_ms"]) < 5.0
    ds = read_dataset(out)
    B, info = reference_poses(ds)
    assert B.shape == (4, 4, 4) and info["kind"] == "robot"
    assert info["noise_trans_m"] == pytest.approx(0.05e-3)
    assert info["time_offset_s"] == pytest.approx(s["time_offset_ms"] * 1e-3)
    # each dwell's reference pose is the pose the robot reported while it held still: that of
    # `openemt simulate --reference robot --n-poses 4 --seed 2`, up to the averaged
    # per-message noise (20 % of 0.05 mm over about 50 messages)
    from openemt.simulate import simulate_reference

    sim = simulate_reference("concentric", "robot", 4, seed=2)
    err_mm = np.linalg.norm(sim.extra["reference_poses"][:, :3, 3] - B[:, :3, 3], axis=1) * 1e3
    assert err_mm.max() < 0.01
    assert np.abs(ds.poses - sim.poses).max() < 1e-9        # the true sensor poses
    assert ds.couplings.shape == (4, 3, 3)
    assert "coverage" in err and "rotation diversity" in err or s["coverage"]["n_poses"] >= 4


def test_collect_reference_at_another_rate(run_cli, tmp_path):
    code, s, err, _ = _collect(run_cli, tmp_path, "--simulate-reference", "optical",
                               "--sim-rate", 40, "--sim-latency-ms", 80,
                               "--sim-clock-offset-ms", -1500)
    assert code == 0, err
    assert s["n_poses"] == 4
    assert abs(s["time_offset_ms"] - (80 - 1500)) < 5.0
    # 40 poses a second: a 0.8-1.4 s hold leaves 20-50 reference poses per dwell
    assert 10 <= s["dwells"]["reference_samples_mean"] <= 60


def test_collect_reference_that_stops_keeps_the_data(run_cli, tmp_path):
    code, s, err, out = _collect(run_cli, tmp_path, "--simulate-reference", "robot",
                                 "--sim-stop-after", 20, n=50)
    assert code == 0, err
    assert s["ended_by"] == "reference lost"
    assert "warning: the reference" in err and "stopped" in err
    assert 1 <= s["n_poses"] < 50
    assert read_dataset(out).n_samples == s["n_poses"]


def test_collect_from_a_reference_csv(run_cli, tmp_path):
    m = simulated_motion("robot", 4, spare=5, seed=2)    # the motion of --n-poses 4 --seed 2
    t = np.arange(0, 12, 0.01)
    csv = write_poses_csv(tmp_path / "ref.csv", m.reference_poses(t), time=t + 1.7e9)
    code, s, err, out = _collect(run_cli, tmp_path, "--reference-csv", csv)
    assert code == 0, err
    assert s["n_poses"] == 4
    # the CSV's clock starts at 1.7e9 s; the simulated tracker's at its start
    ds = read_dataset(out)
    iv = ds.extra["dwell_intervals"]
    assert ds.extra["reference_poses"][:, :3, 3] == pytest.approx(
        m.reported[:4, :3, 3], abs=1e-6)
    assert np.all(np.diff(iv[:, 0]) > 0)


def test_collect_bad_input_is_one_line(run_cli, tmp_path):
    code, _, err, out = _collect(run_cli, tmp_path, "--simulate-reference", "robot",
                                 "--sim-speed", 0)
    assert code == 2 and err.count("error:") == 1 and "--sim-speed" in err
    code, _, err = run_cli("collect", "--source", "replay", "x.h5", "--simulate-reference",
                       "robot", "-o", tmp_path / "c.h5")
    assert code == 2 and "--simulate-reference only with --source sim" in err
    code, _, err = run_cli("collect", "--reference", "igtl://nowhere", "-o", tmp_path / "c.h5")
    assert code == 2 and "igtl://HOST:PORT/DEVICE" in err
    assert not out.exists() and not (tmp_path / "c.h5").exists()


def test_collect_external_reference_server_unreachable_writes_nothing(run_cli, tmp_path):
    import socket

    with socket.socket() as s:                 # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    code, _, err, out = _collect(run_cli, tmp_path, "--reference",
                                 f"igtl://127.0.0.1:{port}/RobotToBase",
                                 "--reference-timeout", 0.5)
    assert code == 2 and "error:" in err and "no reference pose" in err
    assert not out.exists()


def test_collect_against_an_external_pyigtl_reference(run_cli, tmp_path):
    """The reference runs as its own OpenIGTLink server (as PLUS or a robot bridge would):
    the same simulated motion, started on its own clock; collect connects as a client."""
    from openemt.collect import spare_poses

    m = simulated_motion("robot", 4, spare=spare_poses(4), seed=2)
    server = SimulatedReferenceServer(m, t0=time.time() + 0.3, speed=4.0, clock_offset=0.8)
    try:
        code, s, err, out = _collect(run_cli, tmp_path, "--reference", server.url)
    finally:
        server.close()
    assert code == 0, err
    assert s["n_poses"] == 4 and s["reference"] == server.url, s
    assert read_dataset(out).meta["reference"]["kind"] == "igtl"


_CHILD = ("import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
          "from openemt.cli import main; sys.exit(main(sys.argv[1:]))")


def test_collect_ctrl_c_writes_what_it_has(tmp_path):
    out = tmp_path / "col.h5"
    proc = subprocess.Popen([sys.executable, "-c", _CHILD, "collect", "--source", "sim",
                             "--simulate-reference", "robot", "--n-poses", "500",
                             "--sim-speed", "4", "--seed", "1", "-o", str(out), "--json"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=tmp_path)
    try:
        end = time.monotonic() + 60
        line = ""
        while "collecting" not in line:        # started: the collection runs
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < end
            line = proc.stderr.readline()
        time.sleep(8.0)                         # about 30 s of simulated motion
        proc.send_signal(signal.SIGINT)
        stdout, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    s = json.loads(stdout)
    assert s["stopped_by"] == "SIGINT" and s["ended_by"] == "signal"
    assert 1 <= s["n_poses"] < 500
    assert read_dataset(out).n_samples == s["n_poses"]


def test_follow_reference_end_to_end_against_an_external_server(tmp_path):
    """An external OpenIGTLink server replays a robot's motion; the simulated tracker follows
    the poses it reports (``--follow-reference``, P = Y B X^-1 with the simulated X and Y);
    the collection calibrates with a held-out error within 1.25 times that of the simulated
    path (lower: the followed tracker sees the reported poses, so the reference's own error
    does not reach the fit)."""
    import warnings

    from openemt.calibrate import fit_reference
    from openemt.collect import CollectOptions, collect, spare_poses
    from openemt.simulate import nominal_calibration, simulate_reference

    n, seed = 16, 2
    m = simulated_motion("robot", n, spare=spare_poses(n) + 20, seed=seed)
    server = SimulatedReferenceServer(m, t0=time.time() + 1.0, speed=4.0, clock_offset=0.8)
    try:
        r = collect(CollectOptions(output=tmp_path / "f.h5", follow_reference=True,
                                   reference=server.url, n_poses=n, seed=seed, sim_speed=4,
                                   duration=120))
    finally:
        server.close()
    assert r.n_poses == n and r.ended_by == "n_poses"
    assert r.pairing["ok"] and r.pairing["angle_diff_deg_median"] < 0.1
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        f = fit_reference(read_dataset(tmp_path / "f.h5"), nominal_calibration("concentric"),
                          holdout=0.25, seed=0)
        b = fit_reference(simulate_reference("concentric", "robot", n, seed=seed),
                          nominal_calibration("concentric"), holdout=0.25, seed=0)
    assert f.holdout["trans_rms_mm"] <= 1.25 * b.holdout["trans_rms_mm"]


def test_incremental_collector_keeps_what_the_batch_analysis_keeps():
    """Fed one second at a time, the collector keeps the dwells of collect_dwells (the last
    hold, which the streams end within, by neither) with the same averages, and its work per
    second does not grow with the length of the collection."""
    from openemt.collect import Collector

    m = simulated_motion("robot", 14, seed=3)
    seconds = m.hold_ends[13] + 0.2
    tt, C, tr, B = _streams(m, 0.21, seconds)
    batch = collect_dwells(tt, C, tr, B)
    coll = Collector(None, t0=50.0)
    cost = []
    for s in np.arange(0, seconds, 1.0):
        i = slice(*np.searchsorted(tt - 50, [s, s + 1]))
        j = slice(*np.searchsorted(tr - 50.21, [s, s + 1]))
        coll.add_couplings(tt[i], C[i])
        coll.add_reference(tr[j], B[j])
        t0 = time.perf_counter()
        coll.update()
        cost.append(time.perf_counter() - t0)
    coll.update(final=True)
    d = coll.result()
    assert coll.locked and abs(d.time_offset - 0.21) < 5e-3
    assert len(d) == len(batch) == 13
    assert np.abs(d.reference_poses - m.reported[:13]).max() < 1e-9
    assert np.abs(d.couplings - batch.couplings[:13]).max() < 1e-3 * np.abs(C).max()
    assert np.median(cost[-8:]) < 5 * np.median(cost[12:20]) + 0.01
