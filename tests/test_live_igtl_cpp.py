"""The stream read by independent OpenIGTLink implementations at once: a client built here on
the OpenIGTLink C++ library (Debian's libopenigtlink-dev 1.11, header version 1; source
tests/cpp/igtl_client.cxx) and a version-2 client (the hand-written decoder of
tests/_igtl_decode.py, announcing version 2 with a GET_STATUS as pyigtl packs it). Every
TRANSFORM, STRING, STATUS and TDATA message reaches both with the values sent, compared by
time stamp with the pipeline's log.

Skipped, with the reason, where no C++ compiler or no OpenIGTLink library is found
(`.ci/run` installs libopenigtlink-dev)."""

from __future__ import annotations

import subprocess
import time

import numpy as np
import pytest
from _igtl_cpp import build_cpp
from _igtl_decode import RawReader

from openemt.live import IgtlServer, TrackingPipeline, TrackLog, example_tracker, read_tracker
from openemt.live._session import tracker_backend, tracker_sensors


@pytest.fixture(scope="module")
def cpp_client(tmp_path_factory):
    """The C++ client, compiled against the OpenIGTLink library found on this machine."""
    return build_cpp("igtl_client", tmp_path_factory.mktemp("cpp"))


class CppClient:
    """The C++ client as a subprocess writing its lines to a file."""

    def __init__(self, exe, port, seconds, tmp_path, stt_ms=None, name="cpp"):
        self.out = tmp_path / f"{name}.txt"
        args = [str(exe), "127.0.0.1", str(port), str(seconds)]
        if stt_ms is not None:
            args.append(str(stt_ms))
        self._f = open(self.out, "w")
        self.proc = subprocess.Popen(args, stdout=self._f, stderr=subprocess.STDOUT)

    def lines(self) -> list[list[str]]:
        return [ln.split() for ln in self.out.read_text().splitlines() if ln.strip()]

    def wait_for(self, kind, timeout=10.0) -> bool:
        end = time.monotonic() + timeout
        while True:
            if any(ln and ln[0] == kind for ln in self.lines()):
                return True
            if time.monotonic() >= end:
                return False
            time.sleep(0.02)

    def stop(self):
        self.proc.terminate()
        try:
            self.proc.wait(timeout=5.0)
        except subprocess.TimeoutExpired:  # pragma: no cover
            self.proc.kill()
            self.proc.wait(timeout=5.0)
        self._f.close()


def _stamp(sec, frac) -> float:
    return int(sec) + int(frac) / 2.0 ** 32


def _matrix(values) -> np.ndarray:
    M = np.eye(4)
    M[:3, :] = np.asarray(values, dtype=np.float64).reshape(3, 4)
    return M


def _cpp_messages(lines) -> list[dict]:
    out = []
    for ln in lines:
        kind = ln[0]
        if kind in ("CONNECTED",):
            continue
        assert kind not in ("CRCFAIL", "OTHER"), ln
        m = {"type": kind, "device": ln[1], "timestamp": _stamp(ln[2], ln[3])}
        if kind == "TRANSFORM":
            m["matrix"] = _matrix([float(x) for x in ln[4:16]])
        elif kind == "STRING":
            m["text"] = " ".join(ln[4:])
        elif kind == "STATUS":
            m["code"], m["text"] = int(ln[4]), " ".join(ln[6:])
        elif kind == "TDATA":
            n, o, tools = int(ln[4]), 5, []
            for _ in range(n):
                tools.append((ln[o], int(ln[o + 1]), _matrix([float(x) for x in
                                                              ln[o + 2:o + 14]])))
                o += 14
            m["tools"] = tools
        elif kind == "RTS_TDATA":
            m["status"] = int(ln[4])
        out.append(m)
    return out


def _run_with_both(cpp_client, tmp_path, tdata):
    """The two-sensor simulated tracker through the pipeline, with the C++ client and a
    version-2 client connected at once; returns both clients' messages, the log and more."""
    spec = read_tracker(example_tracker("simulated-2"))
    backend = tracker_backend(spec, "sim", realtime=True, duration=0.6)
    log = TrackLog()
    with IgtlServer(port=0, max_queue=4096) as srv:
        cpp = CppClient(cpp_client, srv.port, 30, tmp_path, name=f"cpp{int(tdata)}")
        v2 = None
        try:
            assert cpp.wait_for("STATUS"), cpp.lines()
            v2 = RawReader(srv.port, announce=True)
            assert srv.wait_for_client(5.0, count=2)
            versions = sorted(c["header_version"] for c in srv.clients())
            assert versions == [1, 2]
            backend.restart_clock()
            s = TrackingPipeline(backend, sensors=tracker_sensors(spec), igtl=srv, log=log,
                                 reference=spec.reference, tdata=tdata).run()
            end = time.monotonic() + 10.0
            while time.monotonic() < end and srv.queue_length:
                time.sleep(0.05)
            time.sleep(0.5)
            stats = srv.stats()
        finally:
            if v2 is not None:
                v2.close()
            cpp.stop()
    return _cpp_messages(cpp.lines()), v2.messages(), log, backend, s, stats


def _by_device(msgs, kind):
    out = {}
    for m in msgs:
        if m["type"] == kind:
            out.setdefault(m["device"], []).append(m)
    return out


def test_version_1_cpp_and_version_2_clients_read_every_transform_and_string(cpp_client,
                                                                             tmp_path):
    cpp, v2, log, backend, s, stats = _run_with_both(cpp_client, tmp_path, tdata=False)
    assert stats["messages_skipped"] == 0 and stats["bad_crc"] == 0
    assert cpp[0]["type"] == "STATUS" and cpp[0]["code"] == 1      # the GET_STATUS answer
    spec = read_tracker(example_tracker("simulated-2"))
    for st in spec.sensors:
        a = log.arrays(st.name)
        ok = a["status"] == 0
        stamps = backend.t0_epoch + a["times"][ok]
        want = a["poses"][ok].copy()
        want[:, :3, 3] *= 1000.0
        for who, msgs in (("cpp", cpp), ("v2", v2)):
            got = _by_device(msgs, "TRANSFORM")[st.device_name]
            t = np.array([m["timestamp"] for m in got])
            assert len(got) == len(stamps), (who, st.name, len(got), len(stamps))
            np.testing.assert_allclose(t, stamps, rtol=0, atol=1e-6)
            M = np.stack([m["matrix"] for m in got])
            np.testing.assert_allclose(M[:, :3, :3], want[:, :3, :3], atol=1e-6)
            np.testing.assert_allclose(M[:, :3, 3], want[:, :3, 3], atol=1e-3)   # float32 mm
            if who == "v2":                  # metadata only for the version-2 client
                assert all(m["version"] == 2 and m["metadata"]["TransformStatus"] == "OK"
                           and m["metadata"]["TransformValid"] == "true" for m in got)
    # the relative stream: the same messages to both
    rel_c = _by_device(cpp, "TRANSFORM")["ProbeToReference"]
    rel_2 = _by_device(v2, "TRANSFORM")["ProbeToReference"]
    both = (log.arrays("Probe")["status"] == 0) & (log.arrays("Reference")["status"] == 0)
    assert len(rel_c) == len(rel_2) == int(both.sum())
    for a, b in zip(rel_c, rel_2):
        assert a["timestamp"] == pytest.approx(b["timestamp"], abs=1e-9)
        np.testing.assert_allclose(a["matrix"], b["matrix"], atol=1e-4)
    # STRING: the state and status messages, the same texts and time stamps for both
    strings_c = [(m["device"], m["text"]) for m in cpp if m["type"] == "STRING"]
    strings_2 = [(m["device"], m["text"]) for m in v2 if m["type"] == "STRING"]
    assert strings_c == strings_2 and len(strings_c) >= 2
    assert ("ProbeState", "TRACKING ProbeToTracker") in strings_c


def test_both_clients_read_every_tdata(cpp_client, tmp_path):
    cpp, v2, log, backend, s, stats = _run_with_both(cpp_client, tmp_path, tdata=True)
    assert stats["messages_skipped"] == 0
    probe = log.arrays("Probe")
    stamps = backend.t0_epoch + probe["times"][probe["status"] == 0]
    for who, msgs in (("cpp", cpp), ("v2", v2)):
        td = [m for m in msgs if m["type"] == "TDATA"]
        assert len(td) == s.n_samples, who
        np.testing.assert_allclose([m["timestamp"] for m in td], stamps, rtol=0, atol=1e-6)
        for k, m in enumerate(td):
            assert [e[0] for e in m["tools"]] == ["ProbeToTracker", "ReferenceToTracker",
                                                  "ProbeToReference"]
            want = probe["poses"][k].copy()
            want[:3, 3] *= 1000
            np.testing.assert_allclose(m["tools"][0][2], want, atol=1e-3)


def test_stt_tdata_from_the_cpp_library_sets_the_rate(cpp_client, tmp_path):
    """STT_TDATA (resolution 50 ms) sent by the C++ library: answered by RTS_TDATA (0 =
    success), then TDATA at most every 50 ms, each the newest sample, and no TRANSFORM."""
    with IgtlServer(port=0, device_name="Probe") as srv:
        cpp = CppClient(cpp_client, srv.port, 30, tmp_path, stt_ms=50)
        try:
            assert cpp.wait_for("RTS_TDATA"), cpp.lines()
            assert srv.clients()[0]["stream"] == "tdata"
            P = np.repeat(np.eye(4)[None], 2, axis=0)
            t0, sent, first, k = time.time(), [], None, 0
            # 1.5 s from the first TDATA on (the first send loads its compiled code)
            while time.time() < (t0 + 15.0 if first is None else first + 1.5):
                t = time.time()
                P[:, 0, 3] = [t - t0, -(t - t0)]
                srv.send_poses(P, [t, t], device_name=["AToTracker", "BToTracker"])
                sent.append(t)
                time.sleep(0.002)
                k += 1
                if first is None and k % 10 == 0 and cpp.wait_for("TDATA", timeout=0.0):
                    first = time.time()
            time.sleep(0.3)
        finally:
            cpp.stop()
    msgs = _cpp_messages(cpp.lines())
    assert [m["type"] for m in msgs[:2]] == ["STATUS", "RTS_TDATA"] and msgs[1]["status"] == 0
    td = [m for m in msgs[2:]]
    assert {m["type"] for m in td} == {"TDATA"}
    t = np.array([m["timestamp"] for m in td])
    assert 20 <= len(td) <= 36                           # about 20 per second for 1.5 s
    # released at least 50 ms apart (the time stamps are those of the newest sample then,
    # which a loaded machine may have fed late: their spacing varies, their mean does not)
    assert (t[-1] - t[0]) / (len(t) - 1) > 0.045
    sent = np.array(sent)
    for m in td:
        assert np.abs(sent - m["timestamp"]).min() < 1e-6   # a sample that was sent, whole
        assert [e[0] for e in m["tools"]] == ["AToTracker", "BToTracker"]
        x = m["tools"][0][2][0, 3]
        assert x == pytest.approx(1000 * (m["timestamp"] - t0), abs=1e-2)
