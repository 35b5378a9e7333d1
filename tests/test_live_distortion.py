"""The distortion flag does what docs/live.md says: a sample whose quadrature ratio exceeds the
threshold is flagged, logged and not sent, and its solve skips the extra starts (so a
distorted session keeps its cost); and the status line of ``openemt track``."""

from __future__ import annotations

import io
import sys
import types

import numpy as np
import pytest

import openemt.solve._prepared as prepared
from openemt._constants import SIMULATED_MAINS_AMPLITUDES_V
from openemt.live import SimulatedBackend, TrackingPipeline, TrackLog
from openemt.signal import RawSignalConfig


class _Sink:
    """Stands in for the OpenIGTLink server: counts the poses sent."""

    device_name = "openemt"
    port = 0
    n_clients = 0

    def __init__(self):
        self.sent = 0

    def send_poses(self, poses, stamps, t_ready=None, device_name=None):
        self.sent += len(poses)

    def send_message(self, message, t_ready=None, *, retain=None):
        pass

    def stats(self):
        return {"sent": self.sent}

    def latencies(self):
        return np.empty(0)


def _run(eddy, monkeypatch=None, **kw):
    cfg = RawSignalConfig(mains_amplitudes=SIMULATED_MAINS_AMPLITUDES_V, eddy_strength=eddy)
    b = SimulatedBackend(config=cfg, duration=0.1)
    sink, log = _Sink(), TrackLog()
    s = TrackingPipeline(b, b.model, igtl=sink, log=log, **kw).run()
    return s, sink, log


@pytest.fixture
def multistarts(monkeypatch):
    calls = {"n": 0}
    orig = prepared._multistart_init

    def counted(*a, **k):
        calls["n"] += 1
        return orig(*a, **k)

    monkeypatch.setattr(prepared, "_multistart_init", counted)
    return calls


def test_distorted_samples_are_flagged_logged_and_not_sent(multistarts):
    s, sink, log = _run(0.05)
    n = s.n_samples
    assert n == 149 and s.distorted_fraction == 1.0
    assert sink.sent == 0                                   # nothing distorted is sent
    assert s.extra["not_sent_distorted"] == s.status_counts["converged"] > 0
    a = log.arrays()
    assert a["distorted"].all() and (a["distortion"] > 1e-3).all()
    assert multistarts["n"] == 0                            # no extra starts: bounded cost


def test_send_distorted_sends_them_with_the_full_solve(multistarts):
    s, sink, _ = _run(0.05, send_distorted=True)
    assert sink.sent == s.status_counts["converged"] > 0
    assert s.extra["not_sent_distorted"] == 0
    assert multistarts["n"] > 0                             # the residual asks for more starts


def test_clean_and_threshold(multistarts):
    s, sink, _ = _run(0.0)
    assert s.distorted_fraction == 0.0 and sink.sent == s.n_samples == 149
    s, sink, _ = _run(0.005, distortion_threshold=0.01)     # below a raised threshold: sent
    assert s.distorted_fraction == 0.0 and sink.sent == 149
    assert multistarts["n"] == 0


def test_status_line_on_a_terminal_and_not(monkeypatch):
    from openemt.live._session import _Console

    b = SimulatedBackend(duration=0.05)
    pipe = TrackingPipeline(b, b.model)
    pipe.run()
    for tty in (True, False):
        err = io.StringIO()
        err.isatty = lambda tty=tty: tty
        monkeypatch.setattr("sys.stderr", err)
        sess = _Console(quiet=False)
        assert sess.period == (1.0 if tty else 5.0)
        sess._previous = {"armed": None}                   # no signal handlers in a test
        sess(pipe)                                          # starts the clock
        sess._last -= sess.period                           # a period later
        sess(pipe)
        sess.end_line()
        text = err.getvalue()
        assert "samples/s" in text and "converged 74" in text and "latency" in text
        assert text.startswith("\rtracking 0.0 s") if tty else text.startswith("tracking ")
        assert text.endswith("\n")


@pytest.mark.parametrize("filtered", [False, True])
def test_track_announces_the_compile_before_tracking(monkeypatch, capsys, filtered):
    """``track`` calls the shared compile notice (openemt._compile_notice) with the solver and
    live kernels before its first chunk, less those it never runs (the check of complex
    couplings; the filter's kernel without a filter); a stand-in module records the call."""
    import openemt.cli as cli_mod

    calls = []

    def announce_compile(out=None, what="solver kernels", *, kernels=(), seconds=30):
        calls.append((what, tuple(kernels)))
        print(f"compiling {what} (first run only, about {seconds:g} s)", file=sys.stderr)
        return True

    def dipole_kernels(cold_start_table=False, complex_couplings=True):
        # the real one's rule on this module's names: solver s:k, complex check x:k, cold c:k
        kernels = ("s:k", "x:k") + (("c:k",) if cold_start_table else ())
        return kernels if complex_couplings else tuple(k for k in kernels if k != "x:k")

    fake = types.SimpleNamespace(LIVE_KERNELS=("f:k", "l:k"), FILTER_KERNELS=("f:k",),
                                 dipole_kernels=dipole_kernels,
                                 model_kernels=lambda model: ("b:k",),
                                 announce_compile=announce_compile)
    monkeypatch.setitem(sys.modules, "openemt._compile_notice", fake)
    assert cli_mod.main(["track", "--source", "sim", "--no-igtl", "--duration", "0.05",
                         "--fast"] + (["--filter", "kalman"] if filtered else [])) == 0
    err = capsys.readouterr().err.splitlines()
    expected = ("s:k", "c:k", "f:k", "l:k") if filtered else ("s:k", "c:k", "l:k")
    assert calls == [("solver kernels", expected)]
    i = err.index("compiling solver kernels (first run only, about 30 s)")
    assert err[i + 1].startswith("tracking 1 sensor(s)")
    assert err[i + 2].startswith("tracked 74 samples")


def test_distortion_level_is_logged_and_summarised(tmp_path):
    """The 0-255 level of every sample: in the log (memory, .h5 and .csv) and the summary;
    a distorted session sits at or above 128, a clean one below; a CSV log written before the
    level (without its column) still reads."""
    from openemt.live import read_track_log

    s, _, log = _run(0.05)
    lv = log.arrays()["distortion_level"]
    assert lv.dtype == np.uint8 and len(lv) == s.n_samples and (lv >= 128).all()
    d = s.to_dict()["distortion_level"]                  # the --json summary
    assert d["fraction_at_or_above_128"] == 1.0 and d["max"] == int(lv.max())
    assert d["median"] == int(np.median(lv))
    clean, _, clog = _run(0.0)
    assert (clog.arrays()["distortion_level"] < 128).all()
    assert clean.to_dict()["distortion_level"]["fraction_at_or_above_128"] == 0.0
    for suffix in (".h5", ".csv"):
        path = tmp_path / f"log{suffix}"
        log.write(path)
        back = read_track_log(path).arrays["openemt"]
        np.testing.assert_array_equal(back["distortion_level"], lv)
    text = (tmp_path / "log.csv").read_text().splitlines()
    # a log as written before the level and the time columns: the first 11 columns
    old = [",".join(ln.split(",")[:11]) for ln in text]
    assert old[0].endswith(",distorted")
    (tmp_path / "old.csv").write_text("\n".join(old) + "\n")
    back = read_track_log(tmp_path / "old.csv").arrays["openemt"]
    assert len(back["times"]) == len(lv) and back["distortion_level"].size == 0


def test_tracker_file_names_witness_sensors(tmp_path):
    import re
    import shutil

    from openemt._errors import InputError
    from openemt.live import example_tracker, read_tracker

    shutil.copy(example_tracker("simulated").parent / "concentric.json", tmp_path)
    text = example_tracker("simulated-2").read_text()
    p = tmp_path / "t.toml"
    p.write_text(text + '\n[[witness]]\nsensor = "Reference"\n'
                        'pose = [0.25, 0.05, 0.0, 0.0, 0.1, 0.0]\n')
    spec = read_tracker(p)
    assert spec.witnesses == (("Reference", (0.25, 0.05, 0.0, 0.0, 0.1, 0.0)),)
    for bad, what in (('sensor = "Nobody"\npose = [0, 0, 0, 0, 0, 0]', "witness[0].sensor"),
                      ('sensor = "Probe"\npose = [0, 0, 0]', "witness[0].pose")):
        p.write_text(text + f"\n[[witness]]\n{bad}\n")
        with pytest.raises(InputError, match=re.escape(f"`{what}`")):
            read_tracker(p)


def test_a_witness_pose_error_raises_the_distortion_level():
    """A sensor held still at a known pose: its error there enters the level of the samples
    (128 at 1 mm); at the right pose the level stays that of a clean sample."""
    from openemt.geometry import pose_from_vector

    v = np.array([0.3, 0.05, 0.02, 0.2, -0.1, 0.3])
    P = pose_from_vector(v)

    def still(times):
        return np.broadcast_to(P, (len(np.atleast_1d(times)), 4, 4)).copy()

    def run(pose):
        b = SimulatedBackend(trajectory=still, duration=0.1)
        log = TrackLog()
        TrackingPipeline(b, b.model, log=log, witnesses=(("openemt", tuple(pose)),)).run()
        return log.arrays()["distortion_level"]

    assert (run(v) < 128).all()
    off = v.copy()
    off[0] += 0.005                                          # 5 mm from where it is
    assert (run(off) == 255).all()
    with pytest.raises(Exception, match="witnesses among the sensors"):
        b = SimulatedBackend(trajectory=still, duration=0.05)
        TrackingPipeline(b, b.model, witnesses=(("nobody", tuple(v)),))


def test_witnesses_reestimate_the_metal_while_tracking():
    """Three witness sensors held still beside a tool near a steel sphere (simulated raw
    signals): the pipeline re-estimates an induced dipole from them in every chunk and the
    tool's poses, refined under it, lose the metal's error; the level still reports it."""
    from openemt.geometry import pose_from_vector
    from openemt.live import tracker_from_dict
    from openemt.live._session import tracker_backend, tracker_sensors

    v = np.array([0.25, 0.0, 0.0, 0.2, -0.1, 0.3])
    P = pose_from_vector(v)
    offs = [[0, 0, 0], [0.04, 0.05, 0.04], [0.04, -0.05, -0.04], [-0.03, 0.05, -0.04]]
    spec = tracker_from_dict({
        "format": "openemt-tracker", "version": 1,
        "adc": {"sample_rate": 96000.0, "channels": 15},
        "source": {"frequencies": [7500.0, 10500.0, 13500.0],
                   "reference_channels": [12, 13, 14]},
        "demodulation": {"output_rate": 1500.0},
        "sensors": [{"name": f"S{i}", "channels": [3 * i, 3 * i + 1, 3 * i + 2],
                     "simulation_offset": o} for i, o in enumerate(offs)],
        "simulation": {"preset": "concentric", "seed": 0, "metal": {"object": [
            {"kind": "sphere", "material": "carbon_steel", "position": [0.33, 0.0, 0.1],
             "radius": 0.05}]}}})

    def still(t):
        return np.broadcast_to(P, (len(np.atleast_1d(t)), 4, 4)).copy()

    def tool(witnesses):
        b = tracker_backend(spec, "sim", trajectory=still, duration=0.1)
        log = TrackLog()
        TrackingPipeline(b, tracker_sensors(spec), log=log, witnesses=witnesses).run()
        a = log.arrays("S0")
        e = np.linalg.norm(a["poses"][:, :3, 3] - P[:3, 3], axis=1)
        return np.sqrt(np.mean(e ** 2)), a["distortion_level"]

    plain, _ = tool(())
    known = tuple((f"S{i}", tuple(np.r_[v[:3] + offs[i], v[3:]])) for i in (1, 2, 3))
    refit, level = tool(known)
    assert plain > 1e-3                                      # the sphere moves it by mm
    assert refit < 0.05 * plain
    assert (level == 255).all()                              # the witnesses see the metal


def test_stream_metadata_carries_the_pipelines_level():
    """The level sent in the metadata is the one the pipeline logs (witnesses included), not
    one recomputed without them."""
    from openemt.live._igtl_meta import transform_metadata

    q, r = np.array([1e-4, 1e-4]), np.array([1e-5, 1e-5])
    own = transform_metadata(np.zeros(2, bool), r, q, distortion_threshold=0.05)
    given = transform_metadata(np.zeros(2, bool), r, q, distortion_threshold=0.05,
                               level=np.array([200, 7], np.uint8))
    assert own["DistortionLevel"].tolist() == [b"000", b"000"]
    assert given["DistortionLevel"].tolist() == [b"200", b"007"]
