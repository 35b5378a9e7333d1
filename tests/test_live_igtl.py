"""OpenIGTLink server on loopback with real pyigtl clients (free ports, bounded waits)."""

from __future__ import annotations

import socket
import threading
import time

import numpy as np
import pyigtl
import pytest

from openemt.geometry import pose_from_vector
from openemt.live import IgtlServer

NAME = "TestSensor"


def _wait(cond, timeout=3.0):
    end = time.monotonic() + timeout
    while not cond() and time.monotonic() < end:
        time.sleep(0.005)
    return cond()


@pytest.fixture
def server():
    srv = IgtlServer(port=0, device_name=NAME, max_queue=8, send_timeout=0.3)
    yield srv
    srv.close()
    assert srv.closed


def _client(port):
    return pyigtl.OpenIGTLinkClient(host="127.0.0.1", port=port)


def test_transform_in_millimetres_and_timestamp(server):
    cl = _client(server.port)
    try:
        assert server.wait_for_client(3.0)
        P = pose_from_vector(np.array([0.2012, -0.0345, 0.0171, 0.3, -0.2, 1.1]))
        assert server.send_pose(P, timestamp=1234.5678)
        msg = cl.wait_for_message(NAME, timeout=3.0)
        assert msg is not None and msg.device_name == NAME
        expected = P.copy()
        expected[:3, 3] *= 1000.0
        np.testing.assert_allclose(msg.matrix, expected, rtol=0, atol=2e-5 * 250)
        assert abs(msg.timestamp - 1234.5678) < 1e-6
    finally:
        cl.stop()


def test_no_client_nothing_queued(server):
    assert not server.send_pose(np.eye(4))
    assert server.queue_length == 0 and server.stats()["no_client"] == 1
    with pytest.raises(ValueError, match="shape"):
        server.send_pose(np.eye(3))


def test_client_disconnect_and_reconnect(server):
    P = np.eye(4)
    for round_ in range(3):
        cl = _client(server.port)
        try:
            assert server.wait_for_client(3.0)
            P[0, 3] = 0.1 * (round_ + 1)
            got = None
            for _ in range(100):          # bounded: resend until this client has the pose
                server.send_pose(P, timestamp=float(round_))
                got = cl.wait_for_message(NAME, timeout=0.05)
                if got is not None:
                    break
            assert got is not None
            assert got.matrix[0, 3] == pytest.approx(100.0 * (round_ + 1))
        finally:
            cl.stop()
        assert _wait(lambda: not server.connected), "server did not notice the disconnect"
    assert server.stats()["connections"] == 3


def test_slow_client_queue_stays_bounded(server):
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1024)
    sock.connect(("127.0.0.1", server.port))     # connects and never reads
    try:
        assert server.wait_for_client(3.0)
        peak = 0
        P = np.eye(4)
        for k in range(30000):
            server.send_pose(P, timestamp=float(k))
            if k % 100 == 0:
                peak = max(peak, server.queue_length)
        st = server.stats()
        assert peak <= 8 and server.queue_length <= 8
        # once the socket buffers are full, poses are shed instead of buffered
        assert st["dropped"] > 1000
        assert st["sent"] + st["dropped"] <= st["queued"] + st["no_client"] <= 30000
    finally:
        sock.close()
    # the slow client leaving is noticed and the next client is served
    assert _wait(lambda: server.send_pose(P) is False, timeout=5.0)
    cl = _client(server.port)
    try:
        assert server.wait_for_client(3.0)
        got = None
        for _ in range(100):
            server.send_pose(P, timestamp=1.0)
            got = cl.wait_for_message(NAME, timeout=0.05)
            if got is not None:
                break
        assert got is not None
    finally:
        cl.stop()


def test_clean_shutdown_and_port_reuse():
    before = {t.ident for t in threading.enumerate()}
    srv = IgtlServer(port=0, device_name=NAME, send_timeout=0.3)
    port = srv.port
    stalled = socket.create_connection(("127.0.0.1", port))
    try:
        assert srv.wait_for_client(3.0)
        t = time.perf_counter()
        srv.close()
        assert time.perf_counter() - t < 2.0
        assert srv.closed
        srv.close()                                   # idempotent
        assert not srv.send_pose(np.eye(4))
    finally:
        stalled.close()
    assert {t.ident for t in threading.enumerate() if t.is_alive()} <= before | set()
    again = IgtlServer(port=port, device_name=NAME)   # the port is free again at once
    again.close()


def test_port_in_use_is_a_one_line_oserror():
    with IgtlServer(port=0) as srv, pytest.raises(OSError, match="free TCP port"):
        IgtlServer(port=srv.port)


def test_bad_arguments():
    with pytest.raises(ValueError, match="device_name"):
        IgtlServer(port=0, device_name="")
    with pytest.raises(ValueError, match="max_queue"):
        IgtlServer(port=0, max_queue=0)


def test_flooded_stream_stays_well_formed_and_ordered(server):
    """Poses are dropped under back-pressure, but every byte that arrives belongs to a whole,
    valid message, in sending order (partial non-blocking sends are completed first)."""
    from pyigtl.messages import MessageBase

    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 2048)
    sock.connect(("127.0.0.1", server.port))
    data = bytearray()
    try:
        assert server.wait_for_client(3.0)
        P = np.eye(4)
        sock.settimeout(0.0)
        for k in range(20000):
            P[0, 3] = k * 1e-6
            server.send_pose(P, timestamp=float(k + 1))
            if k % 500 == 0:                      # a slow reader
                try:
                    data += sock.recv(4096)
                except BlockingIOError:
                    pass
        sock.settimeout(0.5)
        while True:                               # drain what is still in flight
            try:
                chunk = sock.recv(1 << 16)
            except TimeoutError:
                break
            if not chunk:
                break
            data += chunk
    finally:
        sock.close()
    H = MessageBase.IGTL_HEADER_SIZE
    stamps, pos = [], 0
    while pos + H <= len(data):
        head = MessageBase.parse_header(bytes(data[pos:pos + H]))
        assert head["message_type"] == "TRANSFORM" and head["device_name"] == NAME
        assert head["body_size"] == 48
        pos += H + head["body_size"]
        stamps.append(head["timestamp"])
    assert len(data) - pos < H + 48                  # at most one message still incomplete
    assert len(stamps) > 100
    assert np.all(np.diff(stamps) > 0)               # in order, no duplicates
    assert set(np.round(stamps)) <= set(range(1, 20001))


def test_send_poses_block_arrives_as_separate_transforms(server):
    from pyigtl.messages import MessageBase

    sock = socket.create_connection(("127.0.0.1", server.port))
    try:
        assert server.wait_for_client(3.0)
        P = np.stack([pose_from_vector(np.array([0.1 * k, 0.0, 0.01, 0.0, 0.0, 0.2 * k]))
                      for k in (1, 2, 3)])
        assert server.send_poses(P, [10.0, 11.0, 12.0], t_ready=time.perf_counter())
        H = MessageBase.IGTL_HEADER_SIZE
        need, data = 3 * (H + 48), b""
        sock.settimeout(3.0)
        while len(data) < need:
            data += sock.recv(need - len(data))
    finally:
        sock.close()
    for k in range(3):
        head = MessageBase.parse_header(data[k * (H + 48):k * (H + 48) + H])
        msg = pyigtl.TransformMessage()
        msg.unpack(head, data[k * (H + 48) + H:(k + 1) * (H + 48)])
        assert head["timestamp"] == pytest.approx(10.0 + k)
        np.testing.assert_allclose(msg.matrix[:3, 3], 1000 * P[k, :3, 3], atol=1e-3)
        np.testing.assert_allclose(msg.matrix[:3, :3], P[k, :3, :3], atol=1e-6)
    assert server.stats()["sent"] == 3 and len(server.latencies()) == 3
    with pytest.raises(ValueError, match="timestamps"):
        server.send_poses(P, [1.0])


def test_block_packing_equals_pyigtl_byte_for_byte():
    from openemt.live._igtl import pack_transforms

    rng = np.random.default_rng(7)
    P = pose_from_vector(rng.normal(size=(40, 6)))
    P[:, :3, 3] *= 300.0
    P[0, :3, 3] = [-1e6, 0.0, 1e-30]                   # extreme translations
    ts = np.r_[rng.uniform(0, 4e9, 36), 0.0, 0.5, 1234.999999999, 1.0e9 + 1e-9]
    for name in ("S", "ProbeToTracker", "x" * 20):
        want = b"".join(pyigtl.TransformMessage(m, timestamp=t, device_name=name).pack()
                        for m, t in zip(P, ts))
        assert pack_transforms(P, ts, name) == want
    assert pack_transforms(np.empty((0, 4, 4)), [], "S") == b""


def test_client_messages_negotiate_and_bad_input_is_survived(server):
    """A version-1 client gets version-1 TRANSFORMs (no metadata) until it sends a version-2
    message; a wrong CRC is ignored and counted, an oversized body skipped unread, and the
    client is still served."""
    import struct

    from _igtl_decode import HEADER, decode, get_status

    sock = socket.create_connection(("127.0.0.1", server.port))
    try:
        assert server.wait_for_client(3.0)
        meta = {"TransformStatus": ["OK"], "QuadratureRatio": np.array([1e-5])}
        got = b""
        sock.settimeout(3.0)
        server.send_poses(np.eye(4)[None], [5.0], metadata=meta)
        while len(got) < 106:
            got += sock.recv(1 << 16)
        (m,) = decode(got)
        assert m["version"] == 1 and m["metadata"] == {} and m["timestamp"] == 5.0
        bad = bytearray(get_status(2))
        bad[50] ^= 0xFF                                   # the CRC
        huge = HEADER.pack(2, b"GET_STATUS", b"x", 0, 0, 2 ** 62, 0)
        sock.sendall(bytes(bad) + huge + b"\0" * 1000)    # the body never comes
        assert _wait(lambda: server.stats()["bad_crc"] == 1)
        assert server.clients()[0]["header_version"] == 1
        server.send_poses(np.eye(4)[None], [6.0], metadata=meta)
        got = b""
        while len(got) < 106:
            got += sock.recv(1 << 16)
        assert decode(got)[0]["version"] == 1
    finally:
        sock.close()
    sock = socket.create_connection(("127.0.0.1", server.port))   # a fresh client announces
    try:
        sock.sendall(get_status(2))
        sock.settimeout(3.0)
        got = b""
        while not any(m["type"] == "STATUS" for m in decode(got)):
            got += sock.recv(1 << 16)
        (status,) = decode(got)
        assert status["version"] == 2
        code, subcode = struct.unpack_from(">Hq", got, 58 + 12)
        assert (code, subcode) == (1, 0)
        assert server.clients()[-1]["header_version"] == 2
        server.send_poses(np.eye(4)[None], [7.0], metadata=meta)
        got = b""
        while not decode(got):
            got += sock.recv(1 << 16)
        (m,) = decode(got)
        assert m["version"] == 2 and m["metadata"]["TransformStatus"] == "OK"
    finally:
        sock.close()


def test_header_version_and_rate_arguments():
    with pytest.raises(ValueError, match="header_version"):
        IgtlServer(port=0, header_version=3)
    for bad in (0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="rate"):
            IgtlServer(port=0, rate=bad)
    with IgtlServer(port=0, header_version="2", rate=50) as srv:
        assert srv.header_version == 2 and srv.rate == 50.0
        sock = socket.create_connection(("127.0.0.1", srv.port))
        try:
            assert srv.wait_for_client(3.0, header_version=2)
            assert srv.clients()[0]["interval"] == pytest.approx(0.02)
        finally:
            sock.close()
