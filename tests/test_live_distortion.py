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


def test_track_announces_the_compile_before_tracking(monkeypatch, capsys):
    """``track`` calls the shared compile notice (openemt._compile_notice) with the solver and
    live kernels before its first chunk; a stand-in module records the call."""
    import openemt.cli as cli_mod

    calls = []

    def announce_compile(out=None, what="solver kernels", *, kernels=(), seconds=30):
        calls.append((what, tuple(kernels)))
        print(f"compiling {what} (first run only, about {seconds:g} s)", file=sys.stderr)
        return True

    fake = types.SimpleNamespace(SOLVER_KERNELS=("s:k",), COLD_START_KERNELS=("c:k",),
                                 LIVE_KERNELS=("l:k",), PLANAR_KERNELS=("p:k",),
                                 announce_compile=announce_compile)
    monkeypatch.setitem(sys.modules, "openemt._compile_notice", fake)
    assert cli_mod.main(["track", "--source", "sim", "--no-igtl", "--duration", "0.05",
                         "--fast"]) == 0
    err = capsys.readouterr().err.splitlines()
    assert calls == [("solver kernels", ("s:k", "c:k", "l:k"))]
    i = err.index("compiling solver kernels (first run only, about 30 s)")
    assert err[i + 1].startswith("tracking 1 sensor(s)")
    assert err[i + 2].startswith("tracked 74 samples")
