"""Live sessions on disk: --log and --save-raw are appended while the session runs, a killed
session's files are readable (marked incomplete), outputs are checked before acquisition,
signals end the session with 143/130 after writing, a full disk is one error line, and a
stalled source is reported instead of taken as the end."""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import threading
import time
import types

import h5py
import numpy as np
import pytest

from openemt._atomic import check_outputs
from openemt.io._stream import CsvStream, DiskFullError, H5Stream
from openemt.live import (
    SimulatedBackend,
    TrackingPipeline,
    TrackLogWriter,
    example_tracker,
    read_track_log,
)
from openemt.signal import read_raw

# ------------------------------------------------------------------ the stream primitives

def test_h5_stream_appears_with_its_first_rows_and_commits_rows(tmp_path):
    path = tmp_path / "s.h5"
    path.write_bytes(b"old")                       # an existing file, kept until rows arrive
    s = H5Stream(path, {"format": "x"}, flush_seconds=0.0)
    s.append("/", {"a": np.arange(3.0), "b": np.ones((3, 2))})
    assert path.read_bytes() == b"old"             # buffered, not yet flushed
    s.maybe_flush()
    with h5py.File(path, "r") as f:                # a reader sees the committed rows
        assert f.attrs["rows"] == 3 and not f.attrs["complete"]
        assert f["b"].shape == (3, 2)
    s.append("/", {"a": np.arange(2.0), "b": np.zeros((2, 2))})
    s.close()
    with h5py.File(path, "r") as f:
        assert f.attrs["rows"] == 5 and f.attrs["complete"]
        np.testing.assert_array_equal(f["a"][()], [0, 1, 2, 0, 1])
    assert not [p for p in os.listdir(tmp_path) if p.startswith(".")]


def test_stream_stopped_before_rows_keeps_the_existing_file(tmp_path):
    for cls, args in ((H5Stream, ({},)), (CsvStream, ("h",))):
        path = tmp_path / ("s.h5" if cls is H5Stream else "s.csv")
        path.write_bytes(b"precious")
        s = cls(path, *args)
        s.close(keep_empty=False)                  # stopped with nothing written
        assert path.read_bytes() == b"precious"
        s = cls(path, *args)
        s.abort()
        assert path.read_bytes() == b"precious"
    assert not [p for p in os.listdir(tmp_path) if p.startswith(".")]


def test_stream_full_disk_by_free_space(tmp_path, monkeypatch):
    path = tmp_path / "s.h5"
    s = H5Stream(path, {}, flush_seconds=0.0)
    s.append("/", {"a": np.arange(100.0)})
    s.flush()
    real = os.statvfs(tmp_path)
    full = types.SimpleNamespace(f_bavail=10, f_frsize=real.f_frsize)
    monkeypatch.setattr("openemt.io._stream.os.statvfs", lambda p: full)
    s.append("/", {"a": np.arange(100.0)})
    with pytest.raises(DiskFullError, match=r"disk full writing .*s\.h5.*100 rows"):
        s.flush()
    s.abort()
    with h5py.File(path, "r") as f:                # the rows before stay readable
        assert f.attrs["rows"] == 100 and not f.attrs["complete"]


def test_stream_full_disk_inside_hdf5_does_not_crash(tmp_path, monkeypatch):
    from openemt.io import _h5write

    path = tmp_path / "s.h5"
    s = H5Stream(path, {}, flush_seconds=0.0)
    s.append("/", {"a": np.arange(5000.0)})
    s.flush()

    def pwrite(fd, data, offset):                  # the disk fills up now
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(_h5write.os, "pwrite", pwrite)
    s.append("/", {"a": np.arange(5000.0)})
    with pytest.raises(DiskFullError, match="disk full writing"):
        s.flush()
    s.abort()                                      # closing writes nothing more
    monkeypatch.undo()
    with h5py.File(path, "r") as f:
        n = int(f.attrs["rows"])
        np.testing.assert_array_equal(f["a"][:n], np.arange(5000.0))


def test_check_outputs_of_a_live_session(tmp_path):
    check_outputs({"--log": tmp_path / "a.h5", "--save-raw": tmp_path / "b.h5",
                          "--x": None})
    with pytest.raises(OSError, match="missing folder"):
        check_outputs({"--log": tmp_path / "no" / "a.h5"})
    with pytest.raises(ValueError, match="--log and --save-raw"):
        check_outputs({"--log": tmp_path / "a.h5", "--save-raw": tmp_path / "a.h5"})
    (tmp_path / "real.h5").write_bytes(b"")
    os.symlink(tmp_path / "real.h5", tmp_path / "link.h5")
    with pytest.raises(ValueError, match="--log and --save-raw"):
        check_outputs({"--log": tmp_path / "real.h5",
                              "--save-raw": tmp_path / "link.h5"})
    with pytest.raises(ValueError, match="folder"):
        check_outputs({"--log": tmp_path})
    with pytest.raises(ValueError, match="which is a character device"):
        check_outputs({"--log": "/dev/null"})
    if os.geteuid() != 0:                          # root writes anywhere
        ro = tmp_path / "ro"
        ro.mkdir(mode=0o555)
        with pytest.raises(ValueError, match="read-only folder"):
            check_outputs({"--log": ro / "a.h5"})


# ------------------------------------------------------------------ logs and readers

@pytest.mark.parametrize("suffix", [".h5", ".csv"])
def test_streamed_log_equals_the_in_memory_log(tmp_path, suffix):
    from openemt.live import TrackLog

    spec_path = example_tracker("simulated-2")
    from openemt.live import read_tracker
    from openemt.live._session import tracker_backend, tracker_sensors

    spec = read_tracker(spec_path)
    logs = []
    for log in (TrackLog(), TrackLogWriter(tmp_path / f"w{suffix}", flush_seconds=0.0)):
        b = tracker_backend(spec, "sim", realtime=False, duration=0.05)
        TrackingPipeline(b, sensors=tracker_sensors(spec), log=log).run()
        logs.append(log)
    logs[0].write(tmp_path / f"m{suffix}")
    logs[1].close()
    a, b = read_track_log(tmp_path / f"m{suffix}"), read_track_log(tmp_path / f"w{suffix}")
    assert a.sensors == b.sensors == ("Probe", "Reference") and a.rows == b.rows == 74
    assert b.complete is (True if suffix == ".h5" else None)
    for name in a.sensors:
        for k, v in a.arrays[name].items():
            w = b.arrays[name][k]
            if k == "acquisition_time":            # UTC of two runs: the same offsets
                v, w = v - v[0], w - w[0]
                np.testing.assert_allclose(v, w, rtol=0, atol=3e-6)   # CSV: 1 us
                continue
            np.testing.assert_array_equal(v, w)


def test_csv_reader_drops_a_torn_last_line(tmp_path):
    w = TrackLogWriter(tmp_path / "l.csv", flush_seconds=0.0)
    b = SimulatedBackend(duration=0.02)
    TrackingPipeline(b, b.model, log=w).run()
    w.close()
    full = read_track_log(tmp_path / "l.csv")
    text = (tmp_path / "l.csv").read_text()
    (tmp_path / "l.csv").write_text(text[:-7])     # killed in the middle of a line
    torn = read_track_log(tmp_path / "l.csv")
    assert torn.complete is False and torn.rows == full.rows - 1
    with pytest.raises(ValueError, match="header"):
        (tmp_path / "x.csv").write_text("a,b\n1,2\n")
        read_track_log(tmp_path / "x.csv")


# ------------------------------------------------------------------ signals, in a child

_CHILD = ("import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
          "from openemt.cli import main; sys.exit(main(sys.argv[1:]))")


def _start(tmp_path, *extra):
    args = [sys.executable, "-c", _CHILD, "track", "--source", "sim", "--no-igtl",
            "--json", "--log", str(tmp_path / "log.h5"), *extra]
    return subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=tmp_path)


def _wait_for(path, proc, timeout=60.0):
    end = time.monotonic() + timeout
    while not path.exists():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < end, "the log never appeared"
        time.sleep(0.05)


@pytest.mark.parametrize(("sig", "code"), [(signal.SIGTERM, 143), (signal.SIGINT, 130),
                                           (signal.SIGKILL, -9)])
def test_signals_during_a_logged_session(tmp_path, sig, code):
    proc = _start(tmp_path, "--save-raw", str(tmp_path / "raw.h5"))
    try:
        _wait_for(tmp_path / "log.h5", proc)        # the first second is on disk
        time.sleep(0.3)
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == code, err
    log = read_track_log(tmp_path / "log.h5")
    raw = read_raw(tmp_path / "raw.h5")
    assert log.rows >= 1000                        # at least the first second
    assert raw.n_samples >= 64 * log.rows          # the raw signal behind every pose
    if sig == signal.SIGKILL:                      # lost at most the last second
        assert log.complete is False and raw.complete is False
        return
    d = json.loads(out)
    assert log.complete and raw.complete
    assert d["stopped_by"] == ("SIGTERM" if sig == signal.SIGTERM else "SIGINT")
    assert d["log_rows"] == log.rows == d["n_samples"]
    assert f"stopped by {d['stopped_by']}" in err
    r = subprocess.run([sys.executable, "-c", _CHILD, "info", "log.h5", "--json"],
                       cwd=tmp_path, capture_output=True, text=True, timeout=60, check=True)
    info = json.loads(r.stdout)
    assert info["kind"] == "track-log" and info["rows"] == log.rows and info["complete"]


def test_killed_log_is_reported_by_info(cli, tmp_path, capsys):
    w = TrackLogWriter(tmp_path / "log.h5", flush_seconds=0.0)
    b = SimulatedBackend(duration=0.05)
    TrackingPipeline(b, b.model, log=w).run()
    w._stream._f.flush()                            # as a SIGKILL leaves it: not closed
    assert cli(["info", str(tmp_path / "log.h5"), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert {k: d[k] for k in ("kind", "format", "rows", "complete", "path")} == {
        "kind": "track-log", "format": "hdf5", "rows": 74, "complete": False,
        "path": str(tmp_path / "log.h5")}
    assert list(d["sensors"]) == ["openemt"] and d["sensors"]["openemt"]["n_samples"] == 74
    w.abort()


# ------------------------------------------------------------------ bad outputs, in-process

def _one_error(capsys):
    cap = capsys.readouterr()
    lines = cap.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), cap.err
    return lines[0]


def test_bad_outputs_refused_before_anything_runs(cli, capsys, tmp_path):
    base = ["track", "--source", "sim", "--no-igtl", "--duration", "0.05", "--fast"]
    assert cli(base + ["--log", str(tmp_path / "x.h5"), "--save-raw",
                       str(tmp_path / "x.h5")]) == 2
    assert "--log and --save-raw" in _one_error(capsys)
    assert cli(base + ["--log", str(tmp_path / "missing" / "x.h5")]) == 2
    assert "missing folder" in _one_error(capsys)
    (tmp_path / "d.h5").mkdir()
    assert cli(base + ["--save-raw", str(tmp_path / "d.h5")]) == 2
    assert "a folder" in _one_error(capsys)
    os.symlink(os.devnull, tmp_path / "n.h5")      # a device behind an .h5 name
    assert cli(base + ["--log", str(tmp_path / "n.h5")]) == 2
    assert "which is a character device" in _one_error(capsys)
    assert sorted(os.listdir(tmp_path)) == ["d.h5", "n.h5"]


def test_full_disk_while_streaming_is_one_error_line(cli, capsys, tmp_path, monkeypatch):
    real = os.statvfs
    calls = {"n": 0}

    def statvfs(p):                                # full from the third flush on
        calls["n"] += 1
        st = real(p)
        if calls["n"] < 3:
            return st
        return types.SimpleNamespace(f_bavail=0, f_frsize=st.f_frsize)

    monkeypatch.setattr("openemt.io._stream.os.statvfs", statvfs)
    monkeypatch.setattr("openemt.io._stream._Stream.maybe_flush",
                        lambda self: self.flush())  # a flush per chunk: quick
    log = tmp_path / "log.h5"
    code = cli(["track", "--source", "sim", "--no-igtl", "--duration", "0.2", "--fast",
                "--log", str(log), "--quiet"])
    assert code == 2
    line = _one_error(capsys)
    assert line.startswith("error: disk full writing") and "log.h5" in line
    d = read_track_log(log)
    assert d.rows == 19 and d.complete is False       # two chunks: 9 + 10 samples


# ------------------------------------------------------------------ stalled sources

def _slow_sounddevice(first_delay, n_blocks, streams):
    """A stand-in ``sounddevice`` whose stream delivers its first block after
    ``first_delay`` s (None: never), then ``n_blocks`` blocks of a simulated tracker."""
    sim = SimulatedBackend(chunk=960, duration=None)
    blocks = [sim.read() for _ in range(n_blocks)]        # simulated up front

    class InputStream:
        def __init__(self, samplerate, channels, dtype, blocksize, device, callback):
            self.callback, self.channels = callback, channels
            self._stop = threading.Event()
            self._thread = threading.Thread(target=self._run, daemon=True)
            streams.append(self)

        def _run(self):
            if first_delay is None or self._stop.wait(first_delay):
                return
            for x in blocks:
                if self._stop.is_set():
                    return
                block = np.zeros((len(x), self.channels), np.float32)
                block[:, :x.shape[1]] = x
                self.callback(block, len(x), None, None)
                time.sleep(0.002)

        def start(self):
            self._thread.start()

        def stop(self):
            self._stop.set()
            self._thread.join(timeout=5.0)

        def close(self):
            pass

    return types.SimpleNamespace(InputStream=InputStream)


def _sound(tmp_path, *extra):
    return ["track", "--tracker", str(example_tracker("simulated")), "--source", "sound",
            "--no-igtl", "--json", "--log", str(tmp_path / "log.h5"), *extra]


def test_slow_first_block_is_not_the_end(cli, capsys, tmp_path, monkeypatch):
    streams: list = []
    monkeypatch.setitem(sys.modules, "sounddevice", _slow_sounddevice(1.6, 100, streams))
    code = cli(_sound(tmp_path, "--duration", "0.2", "--stall-warn", "0.5"))
    cap = capsys.readouterr()
    assert code == 0, cap.err
    d = json.loads(cap.out)
    assert d["n_samples"] >= 300 and d["stalls"] == 1 and d["longest_silence_s"] > 1.0
    assert "warning: no samples from the source since it started" in cap.err
    assert read_track_log(tmp_path / "log.h5").complete


def test_source_that_never_starts_is_an_error(cli, capsys, tmp_path, monkeypatch):
    (tmp_path / "log.h5").write_bytes(b"an earlier session")
    monkeypatch.setitem(sys.modules, "sounddevice", _slow_sounddevice(None, 0, []))
    t = time.monotonic()
    code = cli(_sound(tmp_path, "--stall-warn", "0.3", "--stall-timeout", "1.2", "--quiet"))
    assert code == 2 and time.monotonic() - t < 10
    line = _one_error(capsys)
    assert "got none for" in line and "never started" in line
    assert (tmp_path / "log.h5").read_bytes() == b"an earlier session"


def test_source_that_stops_is_an_error_and_the_log_is_kept(cli, capsys, tmp_path,
                                                          monkeypatch):
    monkeypatch.setitem(sys.modules, "sounddevice", _slow_sounddevice(0.0, 30, []))
    code = cli(_sound(tmp_path, "--stall-timeout", "1.5", "--quiet"))
    assert code == 2
    assert "stopped delivering" in _one_error(capsys)
    d = read_track_log(tmp_path / "log.h5")
    assert d.rows == 30 * 15 - 1 and d.complete is False
