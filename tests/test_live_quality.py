"""Pose quality on the OpenIGTLink stream: version-2 metadata on every TRANSFORM, stream-state
STRING messages on change (lost, distorted, stale, recovered) with a wall-clock watchdog,
reference-relative streams (<Tool>ToReference) and one TDATA message per sample."""

from __future__ import annotations

import json
import socket
import time

import numpy as np
import pyigtl
import pytest
from _igtl_decode import RawReader, decode, tdata_tools
from _igtl_listener import Listener
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from openemt._errors import InputError
from openemt.live import (
    IgtlServer,
    SimulatedBackend,
    TrackingPipeline,
    TrackLog,
    default_model,
    example_tracker,
    read_tracker,
    tracker_from_dict,
)
from openemt.live._igtl import pack_transforms
from openemt.live._pipeline import state_device_name
from openemt.live._session import tracker_backend, tracker_sensors
from openemt.live._tdata import pack_tdata
from openemt.signal import RawSignalConfig

MODEL = default_model()


def test_v2_metadata_bytes_equal_pyigtl():
    from openemt.geometry import pose_from_vector

    rng = np.random.default_rng(3)
    P = pose_from_vector(rng.normal(size=(12, 6)))
    P[:, :3, 3] *= 200.0
    ts = rng.uniform(0, 4e9, 12)
    status = ["OK", "DISTORTED"] * 6
    resid, dist = rng.uniform(1e-9, 1e-2, 12), rng.uniform(0.0, 1e-2, 12)
    dist[3] = 0.0
    for name in ("S", "x" * 20):
        want = []
        for i in range(12):
            m = pyigtl.TransformMessage(P[i], timestamp=ts[i], device_name=name)
            m.header_version = 2
            m.metadata = {"Status": status[i], "RelativeResidual": f"{resid[i]:.3e}",
                          "Distortion": f"{dist[i]:.3e}"}
            want.append(m.pack())
        got = pack_transforms(P, ts, name, {"Status": status, "RelativeResidual": resid,
                                             "Distortion": dist})
        assert got == b"".join(want)
    # equal-length values: joined below _VECTOR_BODIES messages, arrays from there on; both
    # byte for byte pyigtl's
    from openemt.live._igtl import _VECTOR_BODIES

    for n in (1, _VECTOR_BODIES - 1, _VECTOR_BODIES, 12):
        want = []
        for i in range(n):
            m = pyigtl.TransformMessage(P[i], timestamp=ts[i], device_name="S")
            m.header_version = 2
            m.metadata = {"Status": "OK", "RelativeResidual": f"{resid[i]:.3e}",
                          "Distortion": f"{dist[i]:.3e}"}
            want.append(m.pack())
        assert pack_transforms(P[:n], ts[:n], "S", {"Status": ["OK"] * n,
                                                    "RelativeResidual": resid[:n],
                                                    "Distortion": dist[:n]}) == b"".join(want)
    meta = {"Status": ["OK"] * 12, "RelativeResidual": resid, "Distortion": dist}
    one = decode(pack_transforms(P, ts, "S", meta))
    assert [m["metadata"]["Status"] for m in one] == ["OK"] * 12
    assert [float(m["metadata"]["Distortion"]) for m in one] == pytest.approx(dist, rel=1e-3)
    with pytest.raises(InputError, match="12 values"):
        pack_transforms(P, ts, "S", {"Status": ["OK"]})


def test_v2_packing_of_the_pipeline_metadata_equals_pyigtl():
    """The live stream's metadata (bytes arrays, numbers, per-message device names) packed in
    one compiled pass, byte for byte what pyigtl packs; values of one key with different
    lengths (a NUL-padded bytes array among them) take the general path, with the same
    result."""
    from openemt.geometry import pose_from_vector
    from openemt.live._igtl_meta import transform_metadata
    from openemt.live._igtl_wire import pack_transforms_v2

    rng = np.random.default_rng(5)
    P = pose_from_vector(rng.normal(size=(9, 6)))
    P[:, :3, 3] *= 150.0
    ts = rng.uniform(0, 4e9, 9)
    resid, quad = rng.uniform(1e-9, 1e-2, 9), rng.uniform(0.0, 1e-2, 9)

    def want(names, meta):
        out = []
        for i, name in enumerate(names):
            m = pyigtl.TransformMessage(P[i], timestamp=ts[i], device_name=name)
            m.header_version = 2
            m.metadata = {k: (v[i].decode() if isinstance(v[i], bytes)
                              else v[i] if isinstance(v[i], str) else f"{v[i]:.3e}")
                          for k, v in meta.items()}
            out.append(m.pack())
        return b"".join(out)

    for n in (1, 2, 9):
        names = [("S0", "Probe", "x" * 20)[i % 3] for i in range(n)]
        for distorted in (np.zeros(n, bool), np.arange(n) % 2 == 1):
            meta = transform_metadata(distorted, resid[:n], quad[:n],
                                      distortion_threshold=1e-3,
                                      level=np.arange(n, dtype=np.uint8) * 30)
            assert pack_transforms_v2(P[:n], ts[:n], names, meta) == want(names, meta)
            assert pack_transforms_v2(P[:n], ts[:n], "S0", meta) == want(["S0"] * n, meta)
    ragged = {"Status": np.array([b"OK", b"INVALID", b"OK"]), "Level": np.array([b"7"] * 3)}
    assert pack_transforms_v2(P[:3], ts[:3], "S", ragged) == want(["S"] * 3, ragged)
    assert pack_transforms_v2(P[:3], ts[:3], "S", {}) == want(["S"] * 3, {})
    nan = {"RelativeResidual": np.array([1e-3, np.nan, 2e-3])}      # "nan": ragged
    assert pack_transforms_v2(P[:3], ts[:3], "S", nan) == want(["S"] * 3, nan)
    with pytest.raises(InputError, match="3 device names"):
        pack_transforms_v2(P[:3], ts[:3], ["a", "b"], ragged)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_track_sim_stream_carries_metadata_and_relative_poses(tmp_path, capsys):
    """`openemt track --source sim` with the shipped two-sensor tracker (reference sensor
    "Reference"): a pyigtl client sees Status, RelativeResidual and Distortion on every
    TRANSFORM, also on ProbeToReference."""
    import openemt.cli as cli_mod

    port = _free_port()
    devices = ["ProbeToTracker", "ReferenceToTracker", "ProbeToReference"]
    viewer = Listener(port, devices + [state_device_name("ProbeToTracker")], whole=True,
                      announce=True)
    try:
        # version 2 from the first message: this test is about the metadata and the relative
        # stream (the negotiation is tested in test_live_igtl*.py); a viewer that connects
        # late in the 1 s session could otherwise announce itself after the last block
        code = cli_mod.main(["track", "--tracker", str(example_tracker("simulated-2")),
                             "--source", "sim", "--duration", "1.0", "--igtl-port", str(port),
                             "--header-version", "2", "--json", "--quiet"])
        time.sleep(0.1)
    finally:
        viewer.stop()
    d = json.loads(capsys.readouterr().out)
    assert code == 0 and d["reference"] == "Reference"
    assert d["relative_devices"] == ["ProbeToReference"]
    assert d["events"]["tracking"] == 2 and d["events"]["lost"] == 0
    for dev in devices:
        got = viewer.got[dev]
        assert len(got) >= 5, (dev, len(got))
        for m in got:
            assert m.header_version == 2
            assert m.metadata["TransformStatus"] == "OK"
            assert m.metadata["TransformValid"] == "true"
            assert 0 <= float(m.metadata["RelativeResidual"]) < 1e-3
            assert 0 <= float(m.metadata["QuadratureRatio"]) < 1e-3      # the default threshold
            level = int(m.metadata["DistortionLevel"])
            assert level == min(255, round(128 * max(
                float(m.metadata["QuadratureRatio"]) / 1e-3,
                float(m.metadata["RelativeResidual"]) / 1e-2))) or abs(level - round(128 * max(
                    float(m.metadata["QuadratureRatio"]) / 1e-3,
                    float(m.metadata["RelativeResidual"]) / 1e-2))) <= 1   # values to 4 digits
    state = viewer.got["ProbeState"]            # <From>State: whole names within 20 bytes
    assert [m.string for m in state] == ["TRACKING ProbeToTracker"]   # once, not per frame


def _two_sensor_run(tdata, duration=0.2, **kw):
    spec = read_tracker(example_tracker("simulated-2"))
    backend = tracker_backend(spec, "sim", realtime=False, duration=duration)
    log = TrackLog()
    with IgtlServer(port=0, max_queue=4096) as srv:
        reader = RawReader(srv.port, announce=not tdata)    # a version-2 client for metadata
        try:
            assert srv.wait_for_client(5.0)
            s = TrackingPipeline(backend, sensors=tracker_sensors(spec), igtl=srv, log=log,
                                 reference=spec.reference, tdata=tdata, **kw).run()
            time.sleep(0.3)
        finally:
            reader.close()
    return s, log, reader.messages(), backend


def test_tool_to_reference_is_inv_reference_at_tool():
    s, log, msgs, backend = _two_sensor_run(tdata=False)
    assert s.igtl["messages_skipped"] == 0
    by = {}
    for m in msgs:
        if m["type"] == "TRANSFORM":
            by.setdefault(m["device"], {})[round(m["timestamp"], 6)] = m["matrix"]
    tool, ref, rel = by["ProbeToTracker"], by["ReferenceToTracker"], by["ProbeToReference"]
    common = sorted(set(tool) & set(ref) & set(rel))
    assert len(common) == s.n_samples == len(rel)
    for t in common:
        want = np.linalg.inv(ref[t]) @ tool[t]              # from the two sent transforms
        np.testing.assert_allclose(rel[t][:3, :3], want[:3, :3], atol=1e-5)
        np.testing.assert_allclose(rel[t][:3, 3], want[:3, 3], atol=1e-3)       # mm, float32
    # RelativeResidual is ||C_model(pose) - C||_F / ||C||_F of the sent pose; a relative
    # stream carries the larger of its two sensors' (and so does its QuadratureRatio)
    spec = read_tracker(example_tracker("simulated-2"))
    model = tracker_sensors(spec)[0].model
    meta = {m["device"]: {} for m in msgs}
    for m in msgs:
        if m["type"] == "TRANSFORM":
            meta[m["device"]][round(m["timestamp"], 6)] = m["metadata"]
    a, b = log.arrays("Probe"), log.arrays("Reference")
    C = a["couplings"].real
    want = (np.linalg.norm((model.coupling(a["poses"]) - C).reshape(len(C), -1), axis=1)
            / np.linalg.norm(C.reshape(len(C), -1), axis=1))
    got = np.array([float(meta["ProbeToTracker"][t]["RelativeResidual"]) for t in common])
    np.testing.assert_allclose(got, want, rtol=2e-3)
    for k, t in enumerate(common):
        r = meta["ProbeToReference"][t]
        assert r["TransformStatus"] == "OK" and r["TransformValid"] == "true"
        assert float(r["RelativeResidual"]) == max(
            float(meta["ProbeToTracker"][t]["RelativeResidual"]),
            float(meta["ReferenceToTracker"][t]["RelativeResidual"]))
        assert float(r["QuadratureRatio"]) == pytest.approx(max(a["distortion"][k],
                                                           b["distortion"][k]), rel=1e-3)
    # and against the simulated truth: the probe rides 30 mm in x and 50 mm in z below it
    t = np.array(common) - backend.t0_epoch
    truth = backend.truth_poses(t)
    want = np.linalg.inv(truth[:, 1]) @ truth[:, 0]
    got = np.stack([rel[k] for k in common])
    np.testing.assert_allclose(got[:, :3, 3], 1000 * want[:, :3, 3], atol=0.05)


def test_tdata_holds_every_tool_of_a_sample():
    s, log, msgs, backend = _two_sensor_run(tdata=True)
    tdata = [m for m in msgs if m["type"] == "TDATA"]
    strings = [m for m in msgs if m["type"] == "STRING"]     # status and state messages
    assert len(tdata) == s.n_samples and s.igtl["sent"] == s.n_samples + len(strings)
    assert len(msgs) == len(tdata) + len(strings)           # no TRANSFORM
    probe = log.arrays("Probe")
    reference = log.arrays("Reference")
    for k, m in enumerate(tdata):
        assert m["device"] == "openemt"
        assert m["timestamp"] == pytest.approx(backend.t0_epoch + probe["times"][k], abs=1e-6)
        names = [e[0] for e in m["tools"]]
        assert names == ["ProbeToTracker", "ReferenceToTracker", "ProbeToReference"]
        assert all(e[1] == 2 for e in m["tools"])            # 6D
        P, R, rel = (e[2] for e in m["tools"])
        want_p = probe["poses"][k].copy()
        want_p[:3, 3] *= 1000
        np.testing.assert_allclose(P, want_p, atol=1e-4)
        want_r = reference["poses"][k].copy()
        want_r[:3, 3] *= 1000
        np.testing.assert_allclose(R, want_r, atol=1e-4)
        np.testing.assert_allclose(rel, np.linalg.inv(want_r) @ want_p, atol=1e-3)


def test_tdata_omits_invalid_tools_and_parses_through_pyigtl(monkeypatch):
    M = np.repeat(np.eye(4)[None, None], 3, axis=0).repeat(2, axis=1)
    M[:, :, :3, 3] = [[[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]]
    valid = np.array([[True, True], [False, True], [False, False]])
    data, count = pack_tdata(M, valid, ["A", "B"], [10.0, 10.5, 11.0], "Tracker")
    msgs = decode(data)
    assert count == 2 and len(msgs) == 2 and len(data) == 2 * 58 + 3 * 70
    assert [[e[0] for e in m["tools"]] for m in msgs] == [["A", "B"], ["B"]]
    assert msgs[1]["timestamp"] == pytest.approx(10.5)
    np.testing.assert_array_equal(msgs[1]["tools"][0][2][:3, 3], [4.0, 5.0, 6.0])

    # pyigtl has no TDATA class; given one, its framing (header, CRC-checked body size)
    # reads our messages
    class TData(pyigtl.messages.MessageBase):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            self._message_type = "TDATA"

        def _unpack_content(self, content):
            self.tools = tdata_tools(content)

    monkeypatch.setitem(pyigtl.messages.message_type_to_class_constructor, "TDATA", TData)
    with IgtlServer(port=0) as srv:
        client = pyigtl.OpenIGTLinkClient(host="127.0.0.1", port=srv.port)
        try:
            assert srv.wait_for_client(5.0)
            second, _ = pack_tdata(M[1:2], valid[1:2], ["A", "B"], [10.5], "Tracker")
            srv.send_packed(second, 1)
            got = client.wait_for_message("Tracker", timeout=5.0)
        finally:
            client.stop()
    assert isinstance(got, TData) and [e[0] for e in got.tools] == ["B"]
    assert got.timestamp == pytest.approx(10.5)


class _Dropout(SimulatedBackend):
    """No drive current (reference channels zero) between ``start`` and ``stop`` s of signal:
    every sample is then invalid input (lost)."""

    def __init__(self, *a, start, stop, **k):
        super().__init__(*a, **k)
        self.window = (start, stop)

    def read(self):
        x = super().read()
        t = self._i / self.layout.sample_rate
        if x is not None and self.window[0] < t <= self.window[1]:
            x = x.copy()
            x[:, list(self.layout.reference_channels)] = 0.0
        return x


def test_lost_stale_and_recovered_are_sent_once_each():
    b = _Dropout(MODEL, duration=0.8, realtime=True, start=0.1, stop=0.5)
    with IgtlServer(port=0, device_name="Sensor") as srv:
        viewer = Listener(srv.port, ["SensorState"], whole=True)
        reader = RawReader(srv.port)
        try:
            assert srv.wait_for_client(5.0, count=2)
            b.restart_clock()
            pipe = TrackingPipeline(b, MODEL, igtl=srv, stale_after=0.2)
            s = pipe.run()
            time.sleep(0.2)
        finally:
            viewer.stop()
            reader.close()
    events = [e["event"] for e in pipe.events]
    assert events == ["tracking", "lost", "stale", "recovered"]
    assert s.to_dict()["events"] == {"tracking": 1, "lost": 1, "distorted": 0, "stale": 1,
                                      "recovered": 1}
    texts = [m["text"] for m in reader.messages() if m["device"] == "SensorState"]
    assert len(texts) == 4                                  # on change, not per frame
    assert texts[1] == "LOST Sensor: status INVALID_INPUT"
    assert texts[2].startswith("STALE Sensor: no valid pose for 0.2")
    assert texts[3].startswith("RECOVERED Sensor after 0.")
    assert [m.string.split()[0] for m in viewer.got["SensorState"]] == [
        "TRACKING", "LOST", "STALE", "RECOVERED"]
    # no TRANSFORM while lost: the stream resumes after the drop-out
    t = np.array([m["timestamp"] for m in reader.messages() if m["type"] == "TRANSFORM"])
    gap = np.diff(t - b.t0_epoch).max()
    assert 0.35 < gap < 0.45


def test_watchdog_fires_without_samples_and_distortion_is_reported():
    class Silent(SimulatedBackend):
        """Delivers nothing (empty reads, as a silent sound card) for 0.4 s of wall time
        after the first 0.1 s of signal."""

        quiet_until = None

        def read(self):
            if self._i / self.layout.sample_rate >= 0.1 and self.quiet_until is None:
                self.quiet_until = time.monotonic() + 0.4
            if self.quiet_until is not None and time.monotonic() < self.quiet_until:
                time.sleep(0.02)
                return np.empty((0, self.layout.n_channels))
            return super().read()

    pipe = TrackingPipeline(Silent(MODEL, duration=0.3), MODEL, stale_after=0.2)
    pipe.run()
    assert [e["event"] for e in pipe.events] == ["tracking", "stale", "recovered"]
    # a conductive object: every sample distorted, reported once (and not sent)
    eddy = SimulatedBackend(MODEL, duration=0.2, config=RawSignalConfig(eddy_strength=0.05))
    pipe = TrackingPipeline(eddy, MODEL)
    pipe.run()
    assert [e["event"] for e in pipe.events] == ["distorted"]
    assert pipe.events[0]["text"].startswith("DISTORTED openemt: quadrature ")


def test_tracker_file_igtl_table(tmp_path):
    base = {"format": "openemt-tracker", "version": 1,
            "adc": {"sample_rate": 96000.0, "channels": 9},
            "source": {"frequencies": [7500.0, 10500.0, 13500.0],
                       "reference_channels": [6, 7, 8]},
            "sensors": [{"name": "Probe", "channels": [0, 1, 2]},
                        {"name": "Ref", "channels": [3, 4, 5]}]}
    spec = tracker_from_dict(dict(base, igtl={"reference": "Ref", "stale_after": 0.25,
                                              "tdata": True}))
    assert (spec.reference, spec.stale_after, spec.tdata) == ("Ref", 0.25, True)
    plain = tracker_from_dict(base)
    assert (plain.reference, plain.stale_after, plain.tdata) == (None, 0.5, False)
    for igtl, msg in (({"reference": "Nope"}, "igtl.reference"),
                      ({"stale_after": 0}, "igtl.stale_after"),
                      ({"tdata": 1}, "igtl.tdata"),
                      ({"refrence": "Ref"}, "unknown key `igtl.refrence`")):
        with pytest.raises(InputError, match=msg):
            tracker_from_dict(dict(base, igtl=igtl))
    long = dict(base, sensors=[{"name": "AVeryLongToolName", "channels": [0, 1, 2],
                                "device_name": "ToolToTracker"},
                               {"name": "Ref", "channels": [3, 4, 5]}], igtl={"reference": "Ref"})
    with pytest.raises(InputError, match="AVeryLongToolNameToRef"):
        tracker_from_dict(long)
    with pytest.raises(InputError, match="reference"):
        TrackingPipeline(tracker_backend(spec, "sim", duration=0.01),
                         sensors=tracker_sensors(spec), reference="Nope")


def test_bench_many_tools_counts_what_a_pyigtl_client_decodes():
    from openemt.bench._track import _many_tools

    out = _many_tools("concentric", 2, 0.3, 0)
    for way in ("transform", "transform_v1", "tdata"):
        r = out[way]
        assert r["samples"] == 449
        received = r["frame_rate_hz"] * 0.3 * 449 / 450
        assert 0 < received <= r["samples"] + 1e-6
        assert r["messages_sent"] >= r["messages_per_s"] * 0.3 * 449 / 450 - 1e-6
    t, v1, td = out["transform"], out["transform_v1"], out["tdata"]
    assert td["messages_per_s"] == td["frame_rate_hz"]       # one message per sample
    assert t["messages_per_s"] >= 2 * t["frame_rate_hz"] - 1e-6   # one per tool and sample
    if t["messages_skipped"] == v1["messages_skipped"] == 0:
        # the same poses: metadata makes each TRANSFORM 90 bytes longer (106 -> 196)
        assert t["bytes_per_s"] > 1.7 * v1["bytes_per_s"]
    assert set(out["pack_us_per_sample"]) == {"transform", "transform_v1", "tdata"}


def test_cli_tdata_and_stale_after_options(capsys):
    import openemt.cli as cli_mod

    code = cli_mod.main(["track", "--source", "sim", "--duration", "0.1", "--fast", "--tdata",
                         "--stale-after", "0.3", "--igtl-port", "0", "--json", "--quiet"])
    d = json.loads(capsys.readouterr().out)
    assert code == 0 and d["tdata"] is True and d["stale_after"] == 0.3
    assert d["reference"] is None and d["events"]["tracking"] == 1
    assert d["metadata"] is False                       # TDATA carries no metadata
    port = _free_port()
    viewer = Listener(port, ["SensorToTracker"], whole=True)   # the default device name
    try:
        code = cli_mod.main(["track", "--source", "sim", "--duration", "0.5", "--no-metadata",
                             "--igtl-port", str(port), "--json", "--quiet"])
        time.sleep(0.1)
    finally:
        viewer.stop()
    d = json.loads(capsys.readouterr().out)
    got = viewer.got["SensorToTracker"]
    assert code == 0 and d["metadata"] is False and got
    assert all(m.header_version == 1 and not m.metadata for m in got)
    assert cli_mod.main(["track", "--source", "sim", "--stale-after", "0", "--no-igtl"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["error: expected a positive, finite --stale-after in seconds, got 0.0"]


def test_a_viewer_that_connects_late_gets_the_current_state_first():
    # the state message went out before this client connected: it is kept per device and sent
    # first to a new client, once, before the stream's frames
    import pyigtl

    from openemt.live import IgtlServer

    with IgtlServer(_free_port()) as server:
        early = Listener(server.port, ["ProbeState"], whole=True)
        assert server.wait_for_client(5.0)
        server.send_message(pyigtl.StringMessage("TRACKING Probe", device_name="ProbeState"),
                            retain="ProbeState")
        end = time.monotonic() + 5.0
        while not early.got["ProbeState"] and time.monotonic() < end:
            time.sleep(0.01)
        server.send_message(pyigtl.StringMessage("LOST Probe", device_name="ProbeState"),
                            retain="ProbeState")
        late = Listener(server.port, ["ProbeState"], whole=True)
        assert server.wait_for_client(5.0, count=2)
        time.sleep(0.3)
        early.stop()
        late.stop()
    assert [m.string for m in early.got["ProbeState"]] == ["TRACKING Probe", "LOST Probe"]
    assert [m.string for m in late.got["ProbeState"]] == ["LOST Probe"]


_meta_values = st.one_of(
    # numbers of any sign and size, NaN and infinities (written as .3e: lengths vary)
    arrays(np.float64, 5, elements=st.floats(allow_nan=True, allow_infinity=True, width=64)),
    arrays(np.int64, 5, elements=st.integers(-10 ** 6, 10 ** 6)),
    # bytes arrays: full width, or NUL-padded shorter values
    arrays(np.dtype("S4"), 5, elements=st.text(
        alphabet=st.characters(min_codepoint=33, max_codepoint=126), max_size=4).map(
        str.encode)),
    st.lists(st.text(alphabet=st.characters(min_codepoint=33, max_codepoint=126), min_size=1,
                     max_size=6), min_size=5, max_size=5),
)


@settings(max_examples=150, deadline=None)
@given(meta=st.dictionaries(st.text(alphabet="ABCDEFGHIJKLMNOPQRSTUVWXYZabcdef", min_size=1,
                                    max_size=12), _meta_values, max_size=4),
       n=st.integers(1, 5), per_message_names=st.booleans())
def test_v2_packing_equals_pyigtl_for_any_metadata(meta, n, per_message_names):
    """Whatever the metadata (numbers of any length of text form, NaN, bytes arrays with short
    values, strings, no keys), the version-2 packer gives pyigtl's bytes: the compiled pass
    where it applies, the general path elsewhere."""
    from openemt.geometry import pose_from_vector
    from openemt.live._igtl_wire import pack_transforms_v2

    rng = np.random.default_rng(n)
    P = pose_from_vector(rng.normal(size=(n, 6)))
    ts = rng.uniform(0, 4e9, n)
    meta = {k: v[:n] for k, v in meta.items()}
    names = [("S0", "Tool")[i % 2] for i in range(n)] if per_message_names else "S0"
    want = []
    for i in range(n):
        m = pyigtl.TransformMessage(P[i], timestamp=ts[i],
                                    device_name=names if isinstance(names, str) else names[i])
        m.header_version = 2
        m.metadata = {k: (v[i].decode() if isinstance(v[i], bytes) else v[i]
                          if isinstance(v[i], str) else format(v[i], ".3e"))
                      for k, v in meta.items()}
        want.append(m.pack())
    assert pack_transforms_v2(P, ts, names, meta) == b"".join(want)


def test_bench_track_pin_moves_the_viewer_and_refuses_one_cpu(monkeypatch, capsys):
    """``bench track --pin``: the viewer process is put on its own CPU; with fewer than two
    CPUs the option is refused (exit 2, one line naming what arrived)."""
    import os

    import openemt.bench._track as bt
    import openemt.cli as cli_mod

    if len(os.sched_getaffinity(0)) >= 2:
        calls, real = [], os.sched_setaffinity

        def spy(pid, cpus):
            calls.append((pid, set(cpus)))
            return real(pid, cpus)

        monkeypatch.setattr(os, "sched_setaffinity", spy)
        spec = bt._spec("concentric", 1)
        cpu = sorted(os.sched_getaffinity(0))[1]
        s, send, _, _ = bt._latency_run(spec, 0.2, 640, 0, viewer_cpu=cpu)
        assert len(send) > 0
        assert len(calls) == 1 and calls[0][0] != 0 and calls[0][1] == {cpu}
        monkeypatch.setattr(os, "sched_setaffinity", real)
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0})
    code = cli_mod.main(["bench", "track", "--pin", "--json", "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "expected 2 CPUs or more for --pin" in err and "got 1" in err
