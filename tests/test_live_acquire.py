"""Serial and network acquisition: the ADC framing, the reference emitter, a real
pseudo-terminal pair opened by pyserial and a loopback TCP connection; lost, corrupted and
restarted streams counted and never bridged; the acquisition time of every pose."""

from __future__ import annotations

import os
import socket

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from openemt._errors import InputError
from openemt.live import TrackingSession, TrackOptions
from openemt.live._acquire import SerialBackend, TcpBackend, parse_source
from openemt.live._framing import FLAG_START, FrameDecoder, pack_frame
from openemt.live.emitter import Emitter, EmitterThread, open_pty


def _frames(k, n=8, ch=3, start=0, flags0=FLAG_START):
    rng = np.random.default_rng(0)
    x = rng.integers(-1000, 1000, size=(k, n, ch))
    return x, [pack_frame(x[i], start + i * n, 1000.0, fmt="int16", scale=0.5,
                          flags=flags0 if i == 0 else 0) for i in range(k)]


def test_frames_decode_in_any_pieces_and_damage_is_counted():
    x, frames = _frames(6)
    stream = b"".join(frames)
    d = FrameDecoder(3, 1000.0)
    got = []
    for i in range(0, len(stream), 7):                # cut anywhere, sync words included
        got += d.feed(stream[i:i + 7])
    assert [g[0] for g in got] == [0, 8, 16, 24, 32, 40]
    assert got[0][1] == FLAG_START and got[1][1] == 0
    np.testing.assert_array_equal(np.stack([g[2] for g in got]), 0.5 * x)
    assert (d.frames, d.crc_errors, d.bytes_skipped) == (6, 0, 0)

    bad = bytearray(frames[1])
    bad[40] ^= 0x10                                   # a bit flip in the payload
    cut = frames[3][:20] + frames[3][27:]             # 7 bytes dropped in the header
    d = FrameDecoder(3, 1000.0)
    got = d.feed(b"noise" + frames[0] + bytes(bad) + frames[2] + cut + frames[4])
    assert [g[0] for g in got] == [0, 16, 32]
    assert d.crc_errors >= 1 and d.bytes_skipped >= 5 + len(bad)


def test_a_frame_of_another_adc_is_a_wiring_error():
    _, frames = _frames(1)
    with pytest.raises(InputError, match="expected ADC frames of 6 channels at 1000 Hz"):
        FrameDecoder(6, 1000.0).feed(frames[0])


def test_source_forms():
    assert parse_source("serial:/dev/ttyACM0") == ("serial", ("/dev/ttyACM0", 921600))
    assert parse_source("serial:COM3@115200") == ("serial", ("COM3", 115200))
    assert parse_source("tcp://10.0.0.5:5000") == ("tcp", ("10.0.0.5", 5000))
    for bad in ("serial:", "tcp://host", "tcp://h:0", "usb", "serial:/dev/x@fast"):
        with pytest.raises(InputError, match="expected --source sim, replay, sound"):
            parse_source(bad)
    with pytest.raises(InputError, match="--source"):
        TrackOptions(source="bogus").check()


def _run(backend, emitter, fd, seconds, **opts):
    """Track ``seconds`` from ``backend`` while ``emitter`` writes to ``fd`` (a pty master;
    None: the emitter thread ``emitter`` serving TCP) from a thread started once the port is
    open."""
    o = TrackOptions(igtl=False, quiet=True, duration=seconds, stall_timeout=20, **opts)
    et = emitter if fd is None else EmitterThread([emitter], fd)
    with TrackingSession.from_tracker(None, o, backend=backend) as s, et:
        result = s.run()
        pipe = s.pipeline
    assert et.error is None
    return result, pipe


def _sim(seconds, **opts):
    o = TrackOptions(igtl=False, quiet=True, duration=seconds, fast=True, **opts)
    with TrackingSession.from_tracker(None, o) as s:
        return s.run()


@pytest.fixture
def pty_pair():
    master, slave, path = open_pty()
    yield master, path
    for fd in (master, slave):
        try:
            os.close(fd)
        except OSError:
            pass


def test_serial_through_a_pty_tracks_as_the_simulator(pty_pair, tmp_path):
    from openemt.live import read_track_log

    master, path = pty_pair
    em = Emitter(realtime=False, duration=1.0)
    b = SerialBackend(path, em.spec.layout(), em.n_channels, truth=em.truth_poses, drain=False)
    r, _ = _run(b, em, master, 0.6, log=tmp_path / "serial.h5")
    sim = _sim(0.6, log=tmp_path / "sim.h5")
    k = r.to_dict()["link"]
    assert k["frames"] > 0 and k["gaps"] == k["crc_errors"] == k["restarts"] == 0
    assert r.summary.n_samples >= sim.summary.n_samples == 899
    e, e_sim = (x.summary.truth["position_error_mm_rms"] for x in (r, sim))
    assert e == pytest.approx(e_sim, rel=0.02)
    # the same samples (int32 counts of 4.7 nV on the wire): the same poses
    a, b_ = (read_track_log(tmp_path / f).arrays["openemt"] for f in ("serial.h5", "sim.h5"))
    np.testing.assert_allclose(a["times"][:899], b_["times"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(a["pose_vectors"][:899], b_["pose_vectors"], rtol=0, atol=1e-8)


def test_damaged_frames_are_counted_and_never_bridged(pty_pair):
    master, path = pty_pair
    em = Emitter(realtime=False, duration=1.2, flip_every=29, drop_every=41, skip_every=53)
    b = SerialBackend(path, em.spec.layout(), em.n_channels, truth=em.truth_poses, drain=False)
    r, pipe = _run(b, em, master, 0.8)
    k = r.to_dict()["link"]
    assert em.damaged > 0 and em.skipped > 0
    assert k["crc_errors"] >= 1 and k["bytes_skipped"] > 0
    # every damaged or left-out frame before the end is a gap of at least its samples
    assert k["gaps"] >= 20 and k["samples_lost"] >= 64 * k["gaps"]
    # a window over a gap would mix two phases of the carriers: errors of millimetres
    assert r.summary.truth["position_error_mm_max"] < 0.05
    # a new window at every gap read so far (the last runs may still wait in the backend)
    assert 20 <= pipe.demod_restarts <= k["gaps"]
    assert r.summary.status_counts["converged"] == r.summary.n_samples


def test_a_restarted_emitter_is_counted_and_tracking_goes_on(pty_pair, tmp_path):
    import json

    import h5py

    master, path = pty_pair
    em = Emitter(realtime=False, duration=1.2, restart_after=0.5)
    b = SerialBackend(path, em.spec.layout(), em.n_channels, drain=False)
    r, pipe = _run(b, em, master, 1.0, log=tmp_path / "log.h5")
    k = r.to_dict()["link"]
    assert k["restarts"] == 1 and k["gaps"] == 0 and k["clock_restarts"] == 1
    with h5py.File(tmp_path / "log.h5") as f:          # the log says so too
        assert json.loads(f.attrs["link"])["restarts"] == 1
        assert f.attrs["source"] == f"serial:{path}"
        t = f["times"][:]
    assert np.all(np.diff(t) > 0)                      # session time goes on over a restart
    assert pipe.demod_restarts == 1
    assert r.summary.status_counts["converged"] == r.summary.n_samples >= 1500


def test_tcp_tracks_and_reconnects_after_the_emitter_restarts():
    ems = [Emitter(realtime=False, duration=0.7), Emitter(realtime=False, duration=0.7)]
    et = EmitterThread(ems)
    b = TcpBackend("127.0.0.1", et.port, ems[0].spec.layout(), ems[0].n_channels, drain=False,
                   truth=ems[0].truth_poses)
    r, _ = _run(b, et, None, 1.2)
    k = r.to_dict()["link"]
    assert k["reconnects"] == 1 and k["restarts"] == 1
    assert r.summary.status_counts["converged"] == r.summary.n_samples >= 1800


def test_the_acquisition_time_is_the_sample_clock(tmp_path, pty_pair):
    """Paced emitter: the UTC of every pose (log column, OpenIGTLink timestamp) is the
    emitter's true sample time to within one output period, and the latency is logged."""
    from openemt.live import read_track_log

    master, path = pty_pair
    em = Emitter(realtime=True, clock_ppm=300)       # endless: stopped after the session
    b = SerialBackend(path, em.spec.layout(), em.n_channels, drain=False)
    log = tmp_path / "log.h5"
    r, pipe = _run(b, em, master, 2.5, log=log)
    a = read_track_log(log).arrays["openemt"]
    counter_times = b.counter_times(a["times"])          # no restart here
    true_utc = em.t0_epoch + counter_times * em.fs / em.rate_true
    # after the start-up (a reader that starts late sees every frame late: the fit needs a
    # moment of frames read on time, docs/live.md#time)
    late = a["times"] > a["times"][-1] - 1.0
    err = np.abs(a["acquisition_time"][late] - true_utc[late])
    assert err.max() < 1 / 1500
    assert np.all(np.isfinite(a["latency"])) and np.all(a["latency"] > 0)
    acq = r.to_dict()["acquisition"]
    assert 0 < acq["latency_ms_p50"] <= acq["latency_ms_p99"]
    # the emitter's clock runs 300 ppm slow: fitted from 2.5 s of arrival times
    assert acq["link"]["drift_ppm"] == pytest.approx(300, abs=150)


def test_track_command_reads_a_tcp_stream(capsys):
    import json

    from openemt.cli import main

    with EmitterThread([Emitter(realtime=False, duration=0.6)]) as et:
        assert main(["track", "--source", f"tcp://127.0.0.1:{et.port}", "--duration", "0.3",
                     "--no-igtl", "--json"]) == 0
    cap = capsys.readouterr()
    out = json.loads(cap.out)
    assert "link: " in cap.err and "bad CRC" in cap.err and "(0 samples lost" in cap.err
    assert "latency sample time -> send: p50" in cap.err
    assert out["source"] == f"tcp://127.0.0.1:{et.port}"
    assert out["link"]["frames"] > 0 and out["link"]["crc_errors"] == 0
    assert out["status_counts"]["converged"] == out["n_samples"] >= 450


# --------------------------------------------------------------------- openemt devices

def _probe_as_nobody(path):
    """probe_serial(path) in a child process that runs as user 'nobody' (root opens anything,
    so the permission reason needs another user)."""
    from openemt.live._acquire import probe_serial

    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:                                    # pragma: no cover - the child
        try:
            os.close(r)
            os.setgroups([])
            os.setgid(65534)
            os.setuid(65534)
            ok, why = probe_serial(path)
            os.write(w, f"{int(ok)} {why}".encode())
        finally:
            os._exit(0)
    os.close(w)
    with os.fdopen(r) as f:
        out = f.read()
    os.waitpid(pid, 0)
    ok, why = out.split(" ", 1)
    return ok == "1", why


def test_devices_says_why_a_port_does_not_open(tmp_path, pty_pair, capsys):
    import grp
    import json

    from openemt.cli import main
    from openemt.live._acquire import _open_serial, probe_serial

    _, path = pty_pair
    assert probe_serial(path) == (True, "opens")
    ok, why = probe_serial(str(tmp_path / "ttyACM7"))
    assert not ok and why.startswith("missing: no device at")

    held = _open_serial(path, 921600)               # exclusively, as track does
    try:
        ok, why = probe_serial(path)
        assert not ok and why.startswith(f"busy: {path} is open in another program")
    finally:
        held.close()

    os.chmod(path, 0o600)                           # only its owner may open it
    group = grp.getgrgid(os.stat(path).st_gid).gr_name
    ok, why = _probe_as_nobody(path) if os.geteuid() == 0 else probe_serial(path)
    assert not ok
    assert why == (f"no permission to open {path}: join its group '{group}' (sudo usermod "
                   f"-aG {group} $USER, then log in again)")

    os.chmod(path, 0o620)
    assert main(["devices", "--serial", path, str(tmp_path / "x"), "--json", "--quiet"]) == 0
    d = json.loads(capsys.readouterr().out)
    mine = {p["port"]: p for p in d["serial_ports"]}
    assert mine[path]["opens"] is True and mine[str(tmp_path / "x")]["opens"] is False
    assert d["needs"] == {"channels": 6, "sample_rate": 96000.0, "what": d["needs"]["what"]}


def test_devices_checks_the_tracker_files_network_source(tmp_path, capsys):
    import json

    from openemt.cli import main
    from openemt.live import example_tracker

    srv = socket.create_server(("127.0.0.1", 0))
    port = srv.getsockname()[1]
    text = example_tracker("simulated").read_text().replace(
        "channels = 6 ", f'source = "tcp://127.0.0.1:{port}"\nchannels = 6 ')
    tracker = tmp_path / "t.toml"
    tracker.write_text(text)
    (tmp_path / "concentric.json").write_bytes(
        (example_tracker("simulated").parent / "concentric.json").read_bytes())
    with srv:
        assert main(["devices", "--tracker", str(tracker), "--json", "--quiet"]) == 0
        net = json.loads(capsys.readouterr().out)["network"]
        assert net == [{"source": f"tcp://127.0.0.1:{port}", "kind": "tcp", "opens": True,
                        "reason": "accepts connections"}]
    assert main(["devices", "--tracker", str(tracker), "--json", "--quiet"]) == 0
    net = json.loads(capsys.readouterr().out)["network"]
    assert not net[0]["opens"] and net[0]["reason"].startswith("refused: nothing listens")
    # the tracker file's source is track's default source
    assert main(["track", "--tracker", str(tracker), "--no-igtl", "--quiet"]) == 2
    assert f"tcp://127.0.0.1:{port}, got refused" in capsys.readouterr().err


def test_openigtlink_messages_carry_the_acquisition_time(tmp_path):
    """Both header versions: the TRANSFORM header timestamp of every pose is its logged
    acquisition time (the ADC's sample clock mapped to UTC)."""
    import time

    from _igtl_decode import RawReader

    from openemt.live import read_track_log

    em = Emitter(realtime=False, duration=0.6)
    et = EmitterThread([em])
    b = TcpBackend("127.0.0.1", et.port, em.spec.layout(), em.n_channels, drain=False)
    o = TrackOptions(quiet=True, duration=0.3, igtl_port=0, log=tmp_path / "log.h5",
                     stall_timeout=20, header_version="auto")
    with TrackingSession.from_tracker(None, o, backend=b) as s, et:
        readers = [RawReader(s.server.port), RawReader(s.server.port, announce=True)]
        end = time.monotonic() + 10
        while s.server.n_clients < 2 and time.monotonic() < end:
            time.sleep(0.01)
        s.run()
    time.sleep(0.3)
    for r in readers:
        r.close()
    a = read_track_log(tmp_path / "log.h5").arrays["openemt"]
    for version, r in zip((1, 2), readers):
        got = [m for m in r.messages() if m["type"] == "TRANSFORM"]
        assert len(got) > 300 and {m["version"] for m in got} == {version}
        stamps = np.array([m["timestamp"] for m in got])
        gap = np.abs(stamps[:, None] - a["acquisition_time"][None, :]).min(axis=1)
        assert gap.max() < 1e-6
    assert np.all(np.diff(a["acquisition_time"]) > 0)


def test_simulated_source_times_and_latency(tmp_path):
    """--source sim, paced: the acquisition time of a pose is the simulator's sample time
    (the frame centre on its clock), and its latency is positive and about one device block."""
    from openemt.live import read_track_log

    _sim(0.05)                          # the kernels loaded: a paced start without a backlog
    o = TrackOptions(igtl=False, quiet=True, duration=0.5, log=tmp_path / "log.csv")
    with TrackingSession.from_tracker(None, o) as s:
        r = s.run()
        t0 = s.backend.t0_epoch
    a = read_track_log(tmp_path / "log.csv").arrays["openemt"]
    np.testing.assert_allclose(a["acquisition_time"] - t0, a["times"], rtol=0, atol=2e-6)
    assert np.all(a["latency"] > 0)
    acq = r.to_dict()["acquisition"]
    assert 0 < acq["latency_ms_p50"] < 100 and acq["link"] is None


@settings(max_examples=60, deadline=None)
@given(cuts=st.lists(st.integers(0, 2000), max_size=6),
       flips=st.lists(st.integers(0, 8 * 2000), max_size=6),
       junk=st.binary(max_size=64), piece=st.integers(1, 300))
def test_decoder_on_damaged_streams(cuts, flips, junk, piece):
    """Whatever is cut, flipped or inserted: no exception, and every frame the decoder accepts
    is one that was sent, whole (the CRC-32 guards it)."""
    x, frames = _frames(12, n=16, ch=3)
    data = bytearray(junk + b"".join(frames))
    for b in flips:
        if b // 8 < len(data):
            data[b // 8] ^= 1 << (b % 8)
    for c in sorted(cuts, reverse=True):
        del data[c:c + 5]
    d = FrameDecoder(3, 1000.0)
    got = []
    for i in range(0, len(data), piece):
        got += d.feed(bytes(data[i:i + piece]))
    for counter, _flags, y in got:
        k = counter // 16
        assert 0 <= k < 12 and counter == 16 * k
        np.testing.assert_array_equal(y, 0.5 * x[k])
    assert d.frames == len(got) <= 12
    # what is missing was counted, or still waits for the bytes a damaged size asks for
    assert len(got) == 12 or d.crc_errors + d.bad_headers + d.bytes_skipped + d.pending > 0


def test_the_emitter_program_through_a_pty_and_over_tcp(capsys):
    """python -m openemt.live.emitter --to pty (with frames left out), read by openemt track
    --source serial:...; and --to tcp://...: track connects, leaves, connects again and gets
    a freshly started ADC."""
    import json
    import signal
    import subprocess
    import sys

    from openemt.cli import main

    prog = [sys.executable, "-m", "openemt.live.emitter"]
    pty = subprocess.Popen(prog + ["--to", "pty", "--skip-every", "10", "--json"],
                           stdout=subprocess.PIPE, text=True)
    tcp = subprocess.Popen(prog + ["--to", "tcp://127.0.0.1:0", "--fast"],
                           stderr=subprocess.PIPE, text=True)
    try:
        path = pty.stdout.readline().strip()
        assert path.startswith("/dev/")
        assert main(["track", "--source", f"serial:{path}", "--duration", "0.4",
                     "--no-igtl", "--quiet", "--json"]) == 0
        d = json.loads(capsys.readouterr().out)
        pty.send_signal(signal.SIGINT)
        counts = json.loads(pty.stdout.readline())
        assert counts["skipped"] > 0 and counts["t0_epoch"] > 0
        k = d["link"]
        assert k["gaps"] >= 5 and k["samples_lost"] >= 64 * k["gaps"]
        assert d["status_counts"]["converged"] == d["n_samples"] >= 600

        line = tcp.stderr.readline()
        assert line.startswith("listening on 127.0.0.1:"), line
        source = "tcp://127.0.0.1:" + line.strip().rsplit(":", 1)[1]
        for _ in range(2):
            assert main(["track", "--source", source, "--duration", "0.2", "--no-igtl",
                         "--quiet", "--json"]) == 0
            d = json.loads(capsys.readouterr().out)
            assert d["source"] == source and d["link"]["restarts"] == 0
            assert d["status_counts"]["converged"] == d["n_samples"] >= 300
    finally:
        for p in (pty, tcp):
            p.send_signal(signal.SIGINT)
            p.wait(10)


def test_fuzz_section_framing():
    from openemt_fuzz._fuzzframing import fuzz_framing

    out = fuzz_framing(150, seed=5)
    assert out["findings"] == 0 and out["held"] == 150
    assert 0 < out["frames_accepted"] < out["frames_sent"]      # damage did cost frames


def test_damaged_frames_over_tcp_are_counted_and_never_bridged():
    em = Emitter(realtime=False, duration=1.0, flip_every=31, drop_every=43, skip_every=47)
    et = EmitterThread([em])
    b = TcpBackend("127.0.0.1", et.port, em.spec.layout(), em.n_channels, drain=False,
                   truth=em.truth_poses)
    r, pipe = _run(b, et, None, 0.6)
    k = r.to_dict()["link"]
    assert k["crc_errors"] >= 1 and k["gaps"] >= 10 and k["reconnects"] == 0
    assert 10 <= pipe.demod_restarts <= k["gaps"]
    assert r.summary.truth["position_error_mm_max"] < 0.05
    assert r.summary.status_counts["converged"] == r.summary.n_samples


def test_status_line_shows_the_link(capsys, monkeypatch):
    from openemt.live._session import _Console

    class Pipe:
        igtl = None

        def progress(self):
            return {"n_samples": 1500, "signal_seconds": 1.0, "status_counts": {"converged": 9},
                    "distorted": 0, "not_sent_distorted": 0, "latency_ms_p50": 0.3,
                    "link": {"gaps": 2, "samples_lost": 640, "crc_errors": 1, "restarts": 0}}

    c = _Console(quiet=False)
    monkeypatch.setattr(c, "arm", lambda: None)
    c.tty, c.period = False, 0.0
    c(Pipe())                       # the first call starts the clock
    c(Pipe())
    err = capsys.readouterr().err
    assert "link: 2 gap(s) (640 samples lost), 1 bad CRC, 0 restart(s)" in err
