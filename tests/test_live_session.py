"""The tracking session workflow (openemt.live.TrackingSession): one assembly for the command
and the library, FromTo device names, the tool tip as its own device, a registration into the
image frame, what a session says it streams, and options refused before anything starts."""

import json
import shutil

import numpy as np
import pytest

from openemt._errors import InputError
from openemt._result import Result
from openemt.geometry import pose_from_vector
from openemt.live import (
    FilterSpec,
    SensorSetup,
    SimulatedBackend,
    TrackingPipeline,
    TrackingSession,
    TrackLog,
    TrackOptions,
    TrackResult,
    example_tracker,
    read_tracker,
    tracker_backend,
    tracker_sensors,
)
from openemt.navigate import TOOL_FORMAT

QUIET = dict(fast=True, igtl=False, quiet=True)


class _Sink:
    """Stands in for the OpenIGTLink server: keeps every pose sent, by device."""

    device_name = "Server"
    port = 0
    n_clients = 0

    def __init__(self):
        self.got: dict = {}
        self.strings: list = []

    def send_poses(self, poses, stamps, t_ready=None, device_name=None):
        names = [device_name] * len(poses) if isinstance(device_name, str) else device_name
        for name, pose in zip(names, poses):
            self.got.setdefault(name, []).append(pose)

    def send_message(self, message, t_ready=None, *, retain=None):
        self.strings.append(message.device_name)

    def stats(self):
        return {"sent": sum(len(v) for v in self.got.values())}

    def latencies(self):
        return np.empty(0)


def _tracker(tmp_path, extra_sensor_line="", tail="", device=None):
    """The shipped two-sensor tracker with a line added to the probe, ``tail`` appended, the
    probe's device name ``device`` and the reference's left to its default."""
    src = example_tracker("simulated-2")
    shutil.copy(src.parent / "concentric.json", tmp_path / "concentric.json")
    text = src.read_text().replace('name = "Probe"\n', f'name = "Probe"\n{extra_sensor_line}\n',
                                   1) + tail
    text = text.replace('device_name = "ReferenceToTracker"\n', "")
    if device is not None:
        text = text.replace('device_name = "ProbeToTracker"', f'device_name = "{device}"')
    (tmp_path / "t.toml").write_text(text)
    return tmp_path / "t.toml"


def _tip(tmp_path):
    T = np.eye(4)
    T[:3, 3] = [0.0, 0.01, 0.15]
    (tmp_path / "tip.json").write_text(json.dumps(
        {"format": TOOL_FORMAT, "version": 1, "kind": "pivot", "tip_transform": T.tolist()}))
    return T


def _registration(tmp_path, T, name="reg.json"):
    (tmp_path / name).write_text(json.dumps(
        {"format": "openemt.registration", "version": 1, "transform": T.tolist()}))
    return tmp_path / name


REG = pose_from_vector(np.array([0.05, -0.02, 0.3, 0.2, -0.1, 1.2]))


def test_session_is_the_workflow_of_track(tmp_path):
    """A session from the shipped two-sensor tracker: a Result whose dict is what `track
    --json` prints, with the streams it served."""
    opts = TrackOptions(duration=0.1, log=tmp_path / "log.h5", **QUIET)
    with TrackingSession.from_tracker(example_tracker("simulated-2"), opts) as session:
        result = session.run()
    assert isinstance(result, TrackResult) and isinstance(result, Result)
    d = result.to_dict()
    assert d["n_samples"] == 149 and d["status_counts"]["converged"] == 298
    assert d["log"] == str(tmp_path / "log.h5") and d["log_rows"] == 149
    assert d["frame"] == "Tracker" and d["registration"] is None and result.exit_code == 0
    assert [(s["device"], s["kind"], s["frame"], s["units"]) for s in d["streams"]] == [
        ("ProbeToTracker", "tool", "Tracker", "mm"),
        ("ReferenceToTracker", "tool", "Tracker", "mm"),
        ("ProbeToReference", "relative", "Reference", "mm")]
    assert [s["state_device"] for s in d["streams"][:2]] == ["ProbeState", "ReferenceState"]


def test_default_device_names_are_from_to(tmp_path):
    spec = read_tracker(_tracker(tmp_path, device="Needle"))
    assert [s.device_name for s in spec.sensors] == ["Needle", "ReferenceToTracker"]
    assert [s.device_given for s in spec.sensors] == [True, False]
    one = read_tracker(example_tracker("simulated")).sensors[0]
    assert (one.device_name, one.device_given) == ("SensorToTracker", False)
    # state and status devices: whole names, distinct, within the protocol's 20 bytes (they
    # were cut to ReferenceToTracState / ReferenceToTrackerSt)
    streams = read_tracker(example_tracker("simulated-2")).streams()
    names = [n for s in streams for n in (s.state_device, s.status_device) if n]
    assert names == ["ProbeState", "ProbeStatus", "ReferenceState", "ReferenceStatus"]


def test_tip_streams_as_its_own_device_beside_the_tool(tmp_path):
    T = _tip(tmp_path)
    spec = read_tracker(_tracker(tmp_path, 'tip = "tip.json"'))
    assert [(s.device, s.kind, s.frame) for s in spec.streams()] == [
        ("ProbeToTracker", "tool", "Tracker"), ("ReferenceToTracker", "tool", "Tracker"),
        ("ProbeTipToTracker", "tip", "Tracker"), ("ProbeToReference", "relative", "Reference"),
        ("ProbeTipToReference", "tip-relative", "Reference")]
    sink, log = _Sink(), TrackLog()
    p = TrackingPipeline(tracker_backend(spec, "sim", realtime=False, duration=0.05),
                         tracker_sensors(spec), reference=spec.reference, igtl=sink, log=log)
    p.run()
    assert p.devices == [s.device for s in spec.streams()]
    tool, tip = np.stack(sink.got["ProbeToTracker"]), np.stack(sink.got["ProbeTipToTracker"])
    assert len(tool) == len(tip) > 50
    np.testing.assert_allclose(tip, tool @ T, atol=1e-12)
    ref = np.stack(sink.got["ReferenceToTracker"])
    rel_tip = np.stack(sink.got["ProbeTipToReference"])
    np.testing.assert_allclose(rel_tip, np.linalg.inv(ref) @ tool @ T, atol=1e-9)
    # the log keeps the tip (what the tool measures)
    np.testing.assert_allclose(log.arrays("Probe")["poses"][:len(tip)], tip, atol=1e-12)


def test_registration_streams_in_the_image_frame(tmp_path, capsys):
    import openemt.cli as cli_mod

    reg = _registration(tmp_path, REG)
    logs = {}
    for name, extra in (("plain", []), ("image", ["--registration", str(reg)])):
        logs[name] = tmp_path / f"{name}.h5"
        assert cli_mod.main(["track", "--duration", "0.1", "--fast", "--no-igtl", "--json",
                             "--quiet", "--log", str(logs[name]), *extra]) == 0
        d = json.loads(capsys.readouterr().out)
        if name == "image":
            assert d["frame"] == "Image" and d["registration"] == str(reg)
            assert [s["device"] for s in d["streams"]] == ["SensorToImage"]
            # scored against the truth mapped by the same registration
            assert d["truth"]["position_error_mm_rms"] < 0.05
    from openemt.live import read_track_log

    a = read_track_log(logs["plain"]).arrays["openemt"]["poses"]
    b = read_track_log(logs["image"]).arrays["openemt"]["poses"]
    np.testing.assert_allclose(b, REG @ a, atol=1e-12)


def test_registration_key_of_the_tracker_file(tmp_path):
    _registration(tmp_path, REG)
    spec = read_tracker(_tracker(tmp_path, "", '\n[navigation]\nregistration = "reg.json"\n',
                                 device="Needle"))
    np.testing.assert_array_equal(spec.registration, REG)
    assert spec.frame == "Image"
    # a device name the file gives stays; the default one follows the frame
    assert [s.device for s in spec.streams()] == ["Needle", "ReferenceToImage",
                                                  "ProbeToReference"]
    # so does a given <X>ToTracker (the shipped file's ProbeToTracker): it would name the
    # wrong frame
    given = read_tracker(example_tracker("simulated-2")).with_registration(tmp_path / "reg.json")
    assert [s.device_name for s in given.sensors] == ["ProbeToImage", "ReferenceToImage"]
    scaled = REG.copy()
    scaled[:3, :3] *= 1.5                                     # a similarity registration
    _registration(tmp_path, scaled, "scaled.json")
    with pytest.raises(InputError, match="rigid 4x4"):
        read_tracker(_tracker(tmp_path, "", '\n[navigation]\nregistration = "scaled.json"\n'))


def test_track_says_what_it_streams(tmp_path, capsys):
    import openemt.cli as cli_mod

    _tip(tmp_path)
    t = _tracker(tmp_path, 'tip = "tip.json"')
    assert cli_mod.main(["track", "--tracker", str(t), "--duration", "0.05", "--fast",
                         "--igtl-port", "0"]) == 0
    err = capsys.readouterr().err
    line = next(x for x in err.splitlines() if x.startswith("OpenIGTLink: serving"))
    assert line.startswith(
        "OpenIGTLink: serving TRANSFORM 'ProbeToTracker' (Probe in Tracker, mm), "
        "'ReferenceToTracker' (Reference in Tracker, mm), 'ProbeTipToTracker' (tip of Probe "
        "in Tracker, mm), 'ProbeToReference' (Probe in Reference, mm), 'ProbeTipToReference' "
        "(tip of Probe in Reference, mm) on 127.0.0.1:")


@pytest.mark.parametrize("argv, match", [
    (["--filter", "kalman", "--process-noise", "1e308"], r"process_noise` in \[1e-09, 10000\]"),
    (["--filter", "kalman", "--measurement-noise", "0"], r"measurement_noise` in \[1e-12, 1\]"),
    (["--filter", "kalman", "--rotation-process-noise", "inf"], "rotation_process_noise"),
    (["--rate", "0"], r"--rate: expected a stream rate in \(0, 100000\] Hz"),
    (["--rate", "nan"], "stream rate"),
    (["--stale-after", "inf"], "finite --stale-after"),
    (["--distortion-threshold", "inf"], "finite --distortion-threshold"),
    (["--noise", "-1"], "finite --noise"),
    (["--igtl-port", "70000"], "--igtl-port in 0..65535"),
    (["--registration", "nowhere.json"], "nowhere.json"),
])
def test_options_refused_with_one_line(argv, match, capsys, tmp_path, monkeypatch):
    import openemt.cli as cli_mod

    monkeypatch.chdir(tmp_path)
    code = cli_mod.main(["track", "--duration", "0.05", "--fast", "--no-igtl", *argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("error: ")
    import re

    assert re.search(match, err[0]), err[0]


def test_a_filter_driven_beyond_its_range_never_gives_a_converged_nan():
    """A filter record built past the option checks (process noise 1e308): its non-finite
    poses are marked OUT_OF_VOLUME, never converged."""
    b = SimulatedBackend(duration=0.1, seed=3)
    huge = FilterSpec(kind="kalman", process_noise=1e308)
    log = TrackLog()
    s = TrackingPipeline(b, SensorSetup(model=b.model, filter=huge), log=log).run()
    a = log.arrays()
    ok = a["status"] == 0
    assert np.all(np.isfinite(a["poses"][ok]))
    assert s.status_counts["out_of_volume"] > 0          # the filter did overflow here


def test_igtl_options_reach_the_server_only_when_given(monkeypatch, tmp_path):
    import openemt.live._igtl as igtl_mod

    seen = []

    class Server(igtl_mod.IgtlServer):
        def __init__(self, *a, header_version=None, rate=None, **kw):
            seen.append({k: v for k, v in (("header_version", header_version),
                                           ("rate", rate)) if v is not None})
            super().__init__(*a, **kw)

    monkeypatch.setattr(igtl_mod, "IgtlServer", Server)
    base = dict(duration=0.02, fast=True, igtl_port=0, quiet=True)
    for opts in (TrackOptions(**base), TrackOptions(header_version="1", rate=30.0, **base)):
        with TrackingSession.from_tracker(None, opts) as session:
            session.run()
    t = _tracker(tmp_path, "", "").read_text().replace(
        "[igtl]", '[igtl]\nheader_version = "auto"\nrate = 20.0')
    (tmp_path / "t.toml").write_text(t)
    with TrackingSession.from_tracker(tmp_path / "t.toml", TrackOptions(**base)) as session:
        session.run()
    assert seen == [{}, {"header_version": 1, "rate": 30.0},
                    {"header_version": "auto", "rate": 20.0}]


def test_a_session_left_without_running_leaves_no_file(tmp_path):
    opts = TrackOptions(duration=0.05, log=tmp_path / "log.csv", **QUIET)
    with TrackingSession.from_tracker(None, opts) as session:
        assert session.pipeline is not None and session.streams[0].device == "SensorToTracker"
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(RuntimeError, match="boom"):
        with TrackingSession.from_tracker(None, opts) as session:
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


def test_the_documented_example_runs(tmp_path, monkeypatch, capsys):
    """docs/live.md's TrackingSession example, verbatim."""
    from pathlib import Path

    text = (Path(__file__).parents[1] / "docs" / "live.md").read_text()
    start = text.index("```python\n  from openemt.live import TrackingSession")
    block = text[start + len("```python\n"):text.index("  ```", start + 10)]
    code = "\n".join(line[2:] for line in block.splitlines())
    monkeypatch.chdir(tmp_path)
    exec(compile(code, "docs/live.md", "exec"), {})
    assert "'device': 'ProbeToTracker'" in capsys.readouterr().out
    assert (tmp_path / "probe.h5").is_file()


def test_every_corner_of_the_filter_ranges_gives_finite_poses():
    """The accepted filter ranges (openemt.live._tracker_file.FILTER_LIMITS) are ones the
    filter handles: at each corner of the box every converged pose is finite and none is
    lost to the overflow guard."""
    import itertools

    from openemt.live._tracker_file import FILTER_LIMITS

    keys = ("process_noise", "measurement_noise", "rotation_process_noise",
            "rotation_measurement_noise")
    for corner in itertools.product(*[FILTER_LIMITS[k][:2] for k in keys]):
        b = SimulatedBackend(duration=0.05, seed=1)
        log = TrackLog()
        f = FilterSpec(kind="kalman", **dict(zip(keys, corner)))
        s = TrackingPipeline(b, SensorSetup(model=b.model, filter=f), log=log).run()
        assert s.status_counts["converged"] == 74, corner
        assert np.all(np.isfinite(log.arrays()["pose_vectors"])), corner
