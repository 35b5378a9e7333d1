"""Several sensors in one pipeline pass, streamed to several OpenIGTLink clients at once, and a
client that never reads (skipped, then dropped) next to clients that do."""

from __future__ import annotations

import socket
import time

import numpy as np
import pytest
from _counts import converged_only
from _igtl_listener import Listener

from openemt.live import IgtlServer, TrackingPipeline, example_tracker, read_tracker
from openemt.live._session import tracker_backend, tracker_sensors


def test_two_sensors_streamed_to_two_clients():
    spec = read_tracker(example_tracker("simulated-2"))
    devices = [s.device_name for s in spec.sensors]
    backend = tracker_backend(spec, "sim", realtime=True, duration=0.5)
    with IgtlServer(port=0, device_name=devices[0], send_timeout=2.0) as srv:
        listeners = [Listener(srv.port, devices + ["ProbeStatus"]) for _ in range(2)]
        try:
            assert srv.wait_for_client(5.0, count=2)
            backend.restart_clock()
            s = TrackingPipeline(backend, sensors=tracker_sensors(spec), igtl=srv,
                                 status_every=100).run()
            time.sleep(0.2)
        finally:
            for li in listeners:
                li.stop()
        stats = srv.stats()
    assert stats["clients_max"] == 2 and stats["messages_skipped"] == 0
    assert s.status_counts == converged_only(2 * s.n_samples)
    for li in listeners:                               # each client gets both sensors
        for k, dev in enumerate(devices):
            got = li.got[dev]
            assert len(got) >= 5, (dev, len(got))
            t = np.array([g[0] for g in got]) - backend.t0_epoch
            M = np.stack([g[1] for g in got])
            truth = backend.truth_poses(t)[:, k]
            np.testing.assert_allclose(M[:, :3, 3], 1000 * truth[:, :3, 3], atol=0.05)  # mm
        # each sensor's own status on <device name>Status
        assert li.got["ProbeStatus"]                 # <From>Status of ProbeToTracker
        assert li.got["ProbeStatus"][-1][1].startswith("CONVERGED distorted=0")
    # the sensors are 30 mm apart in x and 50 mm in z (the file's simulation_offset)
    a, b = (np.stack([g[1] for g in listeners[0].got[d]])[-1] for d in devices)
    assert abs((b[2, 3] - a[2, 3]) - 50.0) < 0.5


def _slow_socket(port):
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1024)
    sock.connect(("127.0.0.1", port))                  # connects and never reads
    return sock


def _feed(srv, n_blocks, block=20, pace=0.0, start=0):
    P = np.repeat(np.eye(4)[None], block, axis=0)
    for k in range(start, start + n_blocks):
        P[:, 0, 3] = (k + 1) * 1e-4
        srv.send_poses(P, np.full(block, float(k + 1)))
        if pace:
            time.sleep(pace)
    return P[-1]


def _slow_skipped(srv):
    return max((c["skipped"] for c in srv.clients()), default=0)


def test_slow_client_is_skipped_without_holding_up_the_others():
    with IgtlServer(port=0, device_name="Sensor", max_queue=4, send_timeout=30.0) as srv:
        good = [Listener(srv.port, ["Sensor"]) for _ in range(2)]
        slow = _slow_socket(srv.port)
        try:
            assert srv.wait_for_client(5.0, count=3)
            # feed blocks until the never-reading client's socket buffers are full and its
            # backlog is being skipped (bounded: at most 60000 poses, ~6 MB per client)
            rounds = 0
            while _slow_skipped(srv) <= 1000 and rounds < 30:
                last = _feed(srv, 100, pace=0.0002, start=100 * rounds)
                rounds += 1
            total = 100 * rounds
            end = time.monotonic() + 5.0
            while time.monotonic() < end and not all(
                    li.got["Sensor"] and li.got["Sensor"][-1][0] == total for li in good):
                time.sleep(0.01)
            clients = sorted(srv.clients(), key=lambda c: c["skipped"])
            stats = srv.stats()
        finally:
            for li in good:
                li.stop()
            slow.close()
    assert stats["clients_max"] == 3 and stats["clients_dropped"] == 0
    for li in good:                                   # the newest pose reached both viewers
        assert li.got["Sensor"][-1][0] == total
        np.testing.assert_allclose(li.got["Sensor"][-1][1][0, 3], 1000 * last[0, 3])
    # the two readers lost nothing; the one that never reads had its backlog skipped
    assert [c["skipped"] for c in clients[:2]] == [0, 0]
    assert [c["sent"] for c in clients[:2]] == [20 * total, 20 * total]
    assert clients[2]["skipped"] > 1000 and clients[2]["waiting"] <= 4
    assert stats["messages_skipped"] == clients[2]["skipped"]


def test_stalled_client_is_dropped_and_the_others_keep_their_stream():
    with IgtlServer(port=0, device_name="Sensor", max_queue=4, send_timeout=0.2) as srv:
        good = Listener(srv.port, ["Sensor"])
        slow = _slow_socket(srv.port)
        try:
            assert srv.wait_for_client(5.0, count=2)
            end = time.monotonic() + 5.0
            k = 0
            while srv.stats()["clients_dropped"] == 0 and time.monotonic() < end:
                _feed(srv, 50, pace=0.0002)
                k += 1
            assert srv.stats()["clients_dropped"] == 1
            assert srv.n_clients == 1                 # the reader is still connected
            _feed(srv, 1, block=1)                    # and still served
            end = time.monotonic() + 3.0
            while time.monotonic() < end and not (
                    good.got["Sensor"] and good.got["Sensor"][-1][0] == 1.0):
                time.sleep(0.01)
            assert good.got["Sensor"][-1][0] == 1.0
            assert srv.clients()[0]["skipped"] == 0
        finally:
            good.stop()
            slow.close()


@pytest.mark.parametrize("n_clients", [3])
def test_clients_come_and_go(n_clients):
    with IgtlServer(port=0, device_name="Sensor") as srv:
        ls = [Listener(srv.port, ["Sensor"]) for _ in range(n_clients)]
        assert srv.wait_for_client(5.0, count=n_clients)
        ls[0].stop()
        end = time.monotonic() + 3.0
        while srv.n_clients != n_clients - 1 and time.monotonic() < end:
            time.sleep(0.01)
        assert srv.n_clients == n_clients - 1
        for li in ls[1:]:
            li.stop()
        assert srv.stats()["connections"] == n_clients


def test_sensors_of_one_calibration_solved_together_give_the_same_poses():
    import copy
    from dataclasses import replace

    from openemt.live import TrackLog

    spec = read_tracker(example_tracker("simulated-2"))
    shared = tracker_sensors(spec)
    assert shared[0].model is shared[1].model          # one calibration file, one model
    separate = [replace(s, model=copy.deepcopy(s.model)) for s in shared]
    logs = []
    for sensors in (shared, separate):
        log = TrackLog()
        p = TrackingPipeline(tracker_backend(spec, "sim", realtime=False, duration=0.1),
                             sensors=sensors, log=log)
        assert len(p._groups) == (1 if sensors is shared else 2)
        p.run()
        logs.append(log)
    for name in spec.sensor_names:
        a, b = logs[0].arrays(name), logs[1].arrays(name)
        np.testing.assert_array_equal(a["status"], b["status"])
        np.testing.assert_allclose(a["pose_vectors"], b["pose_vectors"], rtol=0, atol=1e-12)


def test_per_sensor_distortion_ratio_in_any_column_order():
    from openemt.live import TrackLog
    from openemt.signal import Demodulated

    spec = read_tracker(example_tracker("simulated-2"))
    a, b = tracker_sensors(spec)
    logs = {}
    for order in ((a, b), (b, a)):                      # block layout, and reversed order
        log = TrackLog()
        backend = tracker_backend(spec, "sim", realtime=False, duration=0.05,
                                  eddy_strength=0.01)
        TrackingPipeline(backend, sensors=list(order), log=log).run()
        logs[order[0].name] = log
    for log in logs.values():
        for s in (a, b):
            arr = log.arrays(s.name)
            C = arr["couplings"]
            ref = Demodulated(C, arr["times"], np.ones((len(C), 3))).distortion_ratio()
            np.testing.assert_allclose(arr["distortion"], ref, rtol=1e-12)
            assert np.all(arr["distortion"] > 1e-4)
            assert C.shape[2] == 3
    np.testing.assert_array_equal(logs["Probe"].arrays("Probe")["distortion"],
                                  logs["Reference"].arrays("Probe")["distortion"])
