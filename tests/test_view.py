"""The live view: the numbers it computes from a session (against the simulator's truth and
the session's own log), and the page in headless Chromium (values shown = values logged,
>= 10 updates per second, no request off the machine, pause)."""

from __future__ import annotations

import os
import re
import socket
import threading
import time
import urllib.request
from dataclasses import replace

import numpy as np
import pytest
from _cdp import Browser, chromium_path, source_data

from openemt.cli import main
from openemt.geometry import pose_from_vector
from openemt.live import (
    SimulatedBackend,
    TrackingSession,
    TrackOptions,
    read_track_log,
)
from openemt.signal import RawSignalConfig, frame_window
from openemt.simulate import get_preset
from openemt.view import (
    LiveFeed,
    ViewProcess,
    ViewRecordingOptions,
    carrier_levels,
    coupling_snr_db,
    view_recording,
)

needs_chromium = pytest.mark.skipif(chromium_path() is None, reason="headless Chromium (Debian "
                                    "package chromium, which .ci/run installs) is not here")


def _session(feed, tmp_path, *, seconds, fast, backend=None, name="log.h5"):
    opts = TrackOptions(duration=seconds, igtl=False, quiet=True, fast=fast,
                        log=tmp_path / name)
    with TrackingSession.from_tracker(None, opts, observer=feed, backend=backend) as s:
        return s.run()


def test_levels_and_snr_match_the_simulated_noise(tmp_path):
    """A static sensor at 200 mm: the drive and sensor levels are the simulator's, and the SNR
    from the couplings alone is the one its white noise gives, within 1 dB."""
    model = get_preset("concentric").dipole
    pose = pose_from_vector(np.array([0.2, 0.0, 0.0, 0.1, -0.2, 0.3]))
    cfg = RawSignalConfig()
    feed = LiveFeed()
    backend = SimulatedBackend(model, pose, cfg, seed=3, duration=0.4, chunk=640)
    _session(feed, tmp_path, seconds=0.4, fast=True, backend=backend)
    snap = feed.snapshot()
    C = model.coupling(pose[None])[0]                                # (n_so, n_se)
    c = snap["carriers"]
    assert np.allclose(c["reference_level"], cfg.drive_amplitude, rtol=1e-4)
    want = cfg.drive_amplitude * np.sqrt(np.mean(C ** 2, axis=1))    # V rms over the coils
    assert np.allclose(c["sensor_level"], want, rtol=2e-3)
    w = frame_window("hann", 128)
    sigma = cfg.noise_rms * np.sqrt(2 * np.sum(w ** 2)) / np.sum(w) / cfg.drive_amplitude
    snr = 20 * np.log10(np.linalg.norm(C, axis=1) / (sigma * np.sqrt(C.shape[1])))
    assert np.all(np.abs(c["snr_db"] - snr) < 1.0), (c["snr_db"], snr)
    assert np.all(c["quadrature"] < 1e-3)                            # no conductor


def test_the_helpers_on_known_signals():
    fs, n = 96000.0, 4096
    t = np.arange(n) / fs
    x = np.stack([0.3 * np.cos(2 * np.pi * 7500 * t + 0.4), 0.02 * np.sin(2 * np.pi * 10500 * t)],
                 axis=1)
    lv = carrier_levels(x, [7500.0, 10500.0], fs)
    assert np.allclose(lv, [[0.3, 0.0], [0.0, 0.02]], atol=1e-6)
    rng = np.random.default_rng(0)
    C = np.ones((2000, 1, 2)) + 1e-3 * rng.standard_normal((2000, 1, 2))
    snr, sigma = coupling_snr_db(C)
    assert np.allclose(sigma, 1e-3, rtol=0.05) and abs(snr[0] - 60.0) < 0.5
    C_moving = C + np.linspace(0, 1, 2000)[:, None, None] ** 2     # smooth motion: no noise
    assert abs(coupling_snr_db(C_moving)[1] - sigma).max() < 1e-5


def test_the_feed_holds_the_logged_values(tmp_path):
    """What the view shows of each sensor is the last row the session logged; the trail ends
    at the last converged position."""
    feed = LiveFeed()
    r = _session(feed, tmp_path, seconds=0.5, fast=True)
    log = read_track_log(tmp_path / "log.h5")
    a = log.arrays[log.sensors[0]]
    s = feed.snapshot()["sensors"][0]
    assert s["n_samples"] == log.rows == r.summary.n_samples
    assert np.array_equal(s["pose_vector"], a["pose_vectors"][-1])
    assert s["residual"] == a["residual"][-1] and s["distortion"] == a["distortion"][-1]
    assert s["time"] == a["times"][-1]
    assert np.array_equal(s["couplings"], a["couplings"][-1])
    ok = a["status"] == 0
    assert np.array_equal(s["trail"][-1], a["pose_vectors"][ok][-1, :3])


class _Block:
    """A processed block as the feed reads it (two outputs), ending at time ``t``."""

    def __init__(self, t, rng):
        self.times = np.array([t - 1e-3, t])
        self.pose_vectors = rng.standard_normal((2, 6))
        self.status = rng.choice(np.array([0, 0, 0, 3], dtype=np.int8), 2)
        self.residual = self.distortion = rng.random(2)
        self.distorted = np.zeros(2, dtype=bool)
        self.couplings = None

    def __len__(self):
        return 2


def _trail_over_every_block(blocks, seconds, most):
    """The trail as defined (docs/live.md), from every block held."""
    t_end = blocks[-1].times[-1] - seconds
    recent = [b for b in blocks if b.times[-1] >= t_end]
    stride = max(1, -(-len(recent) // most))
    pick = [b.pose_vectors[-1, :3] for b in recent[::-1][::stride] if b.status[-1] == 0]
    return np.array(pick[::-1]).reshape(-1, 3)


def test_the_trail_is_the_trail_of_the_last_blocks_published():
    """The trail ring, written as each block is published, gives the trail computed from the
    sensor's last ``history_blocks`` blocks (40 here), whatever the bursts between snapshots
    (1 to 90 blocks), a new session, two sensors."""
    rng = np.random.default_rng(4)
    feed = LiveFeed(history_seconds=0.25, history_blocks=40, window_samples=8,
                    trail_points=7)
    t = 0.0
    for names in (("a",), ("a", "b")):
        feed.sensors(names)
        published = [[] for _ in names]
        for burst in (*rng.integers(1, 30, 40), 90, 1, 41, 40, 3):
            for _ in range(burst):
                t += 0.01
                for k in range(len(names)):
                    published[k].append(_Block(t, rng))
                    feed.step(published[k][-1], k)
            snap = feed.snapshot()
            for k in range(len(names)):
                want = _trail_over_every_block(published[k][-40:], 0.25, 7)
                assert np.array_equal(snap["sensors"][k]["trail"], want)
    assert 0 < len(want) <= 7


def test_the_couplings_window_is_the_last_outputs_published():
    """The couplings window (the SNR's and quadrature's) is the last ``window_samples``
    outputs published, across blocks of any length (longer than the window too)."""
    rng = np.random.default_rng(2)
    feed = LiveFeed(window_samples=50)
    feed.sensors(("a",))
    published, t = [], 0.0
    for n in (*rng.integers(1, 12, 60), 70, 3, 49, 50, 51):
        t += 0.01
        b = _Block(t, rng)
        b.couplings = rng.standard_normal((n, 3, 2)) + 1j * rng.standard_normal((n, 3, 2))
        feed.step(b, 0)
        published.append(b.couplings)
        want = np.concatenate(published)[-50:]
        got = feed.gather()["sensors"][0]["window"]
        assert np.array_equal(got, want)
    snap = feed.snapshot()
    assert snap["carriers"]["window"] == 50
    assert np.array_equal(snap["sensors"][0]["couplings"], published[-1][-1])


def _shown_sensor(browser, rows):
    """The sensors table's values once the page shows ``rows`` samples."""
    browser.wait_for(
        f"(() => {{ const d = {_source_js('sensors')}; return d && d.n_samples && "
        f"d.n_samples[0] === {rows}; }})()", timeout=60)
    return source_data(browser, "sensors")


def _source_js(name):
    from _cdp import SOURCE_JS

    return SOURCE_JS.format(name=name)


def _check_against_log(shown, browser, a):
    v = a["pose_vectors"][-1]
    want = {"x_mm": 1e3 * v[0], "y_mm": 1e3 * v[1], "z_mm": 1e3 * v[2],
            "rx_deg": np.degrees(v[3]), "ry_deg": np.degrees(v[4]), "rz_deg": np.degrees(v[5]),
            "residual": a["residual"][-1], "distortion": a["distortion"][-1],
            "time_s": a["times"][-1]}
    for k, x in want.items():
        assert shown[k][0] == pytest.approx(x, rel=1e-12, abs=1e-12), k
    assert shown["status"][0] == ("CONVERGED" if a["status"][-1] == 0 else shown["status"][0])
    # per carrier: coupling level, quadrature ratio and SNR over the last 300 logged rows
    C = a["couplings"][-300:]
    ab = np.sqrt(np.sum(np.abs(C) ** 2, axis=2))
    carriers = source_data(browser, "carriers")
    assert np.allclose(carriers["coupling"], np.sqrt(np.mean(ab ** 2, axis=0)), rtol=1e-12)
    quad = np.mean(np.sqrt(np.sum(C.imag ** 2, axis=2)) / ab, axis=0)
    assert np.allclose(carriers["quadrature"], quad, rtol=1e-12)
    assert np.allclose(carriers["snr_db"], coupling_snr_db(C)[0], rtol=1e-12)
    # and the table the page draws says the same, to the digits it shows (the HTML is
    # written into the Div's element, not into its model: read what the page shows)
    js = ("Bokeh.index.find_one(Bokeh.documents[0].get_model_by_name('sensors_table'))"
          ".markup_el.innerHTML")
    try:
        browser.wait_for(f"{js}.includes({want['z_mm']:.3f}.toFixed(3))", timeout=10)
    except TimeoutError:
        pass                                       # the assertions below say what is shown
    html = browser.evaluate(js)
    for k in ("x_mm", "y_mm", "z_mm"):
        assert f"{want[k]:.3f}" in html, (k, html)


@needs_chromium
def test_view_of_a_simulated_session_in_chromium(tmp_path):
    feed = LiveFeed()
    with ViewProcess(feed) as server, Browser() as browser:
        html = urllib.request.urlopen(server.url, timeout=30).read().decode()
        # the page's own markup (outside the inlined BokehJS source) loads nothing by URL
        markup = re.sub(r"<script[^>]*>.*?</script>", "", html, flags=re.S)
        assert not re.search(r"""(src|href)\s*=\s*["']?https?://""", markup)
        assert re.findall(r"<script[^>]*\bsrc=", html) == []
        browser.open(server.url)
        browser.wait_for(_source_js("header"))
        result = {}
        run = threading.Thread(target=lambda: result.update(
            r=_session(feed, tmp_path, seconds=3.0, fast=False)))
        run.start()
        browser.wait_for(f"(() => {{ const d = {_source_js('sensors')}; "
                         f"return d && d.n_samples && d.n_samples[0] > 0; }})()")
        time.sleep(0.5)
        h0, t0 = source_data(browser, "header")["n_updates"][0], time.monotonic()
        time.sleep(1.5)
        h1, t1 = source_data(browser, "header")["n_updates"][0], time.monotonic()
        run.join()
        rate = (h1 - h0) / (t1 - t0)                 # updates the page applied per second
        assert rate > 0
        # >= 10 per second wherever the browser gets its share of a core (the server waits
        # for the page to apply an update before sending more than two)
        if os.getloadavg()[0] < (os.cpu_count() or 1):
            assert rate >= 10.0, rate
        log = read_track_log(tmp_path / "log.h5")
        shown = _shown_sensor(browser, log.rows)
        _check_against_log(shown, browser, log.arrays[log.sensors[0]])
        # the trail: a line ending at the latest position and a dot there (one glyph)
        trail = source_data(browser, "trail")
        assert trail["kind"] == ["trail", "latest"] and trail["width"] == [1.0, 10.0]
        latest = [np.mean(trail[a][1]) for a in "xyz"]
        pose = [shown[f"{a}_mm"][0] for a in "xyz"]
        assert np.allclose(latest, pose, rtol=0, atol=1e-3), (latest, pose)
        assert [trail[a][0][-1] for a in "xyz"] == pytest.approx(pose, abs=1e-3)
        assert len(trail["x"][0]) > 10
        carriers = source_data(browser, "carriers")
        assert len(carriers["snr_db"]) == 3 and min(carriers["snr_db"]) > 60
        spectrum = source_data(browser, "spectrum")
        assert len(spectrum["ys"]) == 6 and len(spectrum["ys"][0]) > 100
        coupling = source_data(browser, "coupling")
        C = log.arrays[log.sensors[0]]["couplings"][-1]
        assert np.allclose(coupling["value"], C.real.ravel(), rtol=0, atol=0)
        # the pause button stops the display, not the feed
        browser.evaluate("Bokeh.documents[0].get_model_by_name('pause').active = true")
        browser.wait_for(f"{_source_js('header')}.paused[0]")
        n = source_data(browser, "header")["n_updates"][0]
        time.sleep(0.5)
        assert source_data(browser, "header")["n_updates"][0] == n
        # a plot whose range moves is laid out again (its layout check runs only then):
        # wider tick labels make the frame narrower
        plot = "Bokeh.documents[0].get_model_by_name('spectrum_plot')"
        width = browser.evaluate(f"{plot}.inner_width")
        browser.evaluate(f"{plot}.y_range.setv({{start: -1e9, end: 1e9}})")
        browser.wait_for(f"{plot}.inner_width < {width}", timeout=10)
        # nothing was requested from another machine
        hosts = {re.sub(r"^\w+://([^/:]+).*", r"\1", u) for u in browser.requests
                 if not u.startswith("data:")}
        assert hosts == {"127.0.0.1"}, hosts


@needs_chromium
def test_view_of_a_replayed_log_in_chromium(tmp_path):
    feed = LiveFeed()
    _session(feed, tmp_path, seconds=1.0, fast=True)
    log = read_track_log(tmp_path / "log.h5")
    a = log.arrays[log.sensors[0]]
    stop = threading.Event()
    out = {}
    opts = ViewRecordingOptions(log=tmp_path / "log.h5", speed=2.0, quiet=True)
    said = []

    def serve():
        out["r"] = view_recording(opts, stop=stop.is_set, say=said.append)

    th = threading.Thread(target=serve)
    th.start()
    try:
        end = time.monotonic() + 30
        while not said and time.monotonic() < end:
            time.sleep(0.02)
        url = re.search(r"http://127\.0\.0\.1:\d+/", said[0])[0]
        with Browser() as browser:
            browser.open(url)
            shown = _shown_sensor(browser, log.rows)
            _check_against_log(shown, browser, a)
            coupling = source_data(browser, "coupling")
            assert np.array_equal(coupling["value"], a["couplings"][-1].real.ravel())
            assert source_data(browser, "spectrum")["ys"] == []      # a log has no raw samples
    finally:
        stop.set()
        th.join(30)
    r = out["r"]
    assert r.rows == log.rows and r.samples_shown == log.rows and r.pages_opened >= 1


def test_view_command_refuses_bad_input(tmp_path, capsys):
    assert main(["view"]) == 2
    assert "expected either a session LOG or --raw FILE, got neither" in capsys.readouterr().err
    assert main(["view", str(tmp_path / "missing.h5"), "--hold", "0"]) == 2
    assert "expected an existing track log" in capsys.readouterr().err
    assert main(["track", "--view", "--view-port", "70000", "--duration", "0.1"]) == 2
    assert "expected --view-port in 0..65535" in capsys.readouterr().err
    assert main(["collect", "-o", str(tmp_path / "c.h5"), "--simulate-reference", "robot",
                 "--view", "--view-rate", "0.5"]) == 2
    assert "expected --view-rate in 1..60 Hz, got 0.5" in capsys.readouterr().err
    assert not (tmp_path / "c.h5").exists()
    with socket.socket() as busy:                   # a port taken: one line, exit 2
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        assert main(["track", "--view", "--view-port", str(port), "--duration", "0.1",
                     "--no-igtl"]) == 2
        err = capsys.readouterr().err
        assert f"expected a free view port on 127.0.0.1, got {port}" in err, err


def test_view_of_a_raw_recording_tracks_it_again(tmp_path):
    """``openemt view --raw``: the recording tracked again with the view open, the same
    samples as the session that recorded it."""
    opts = TrackOptions(duration=0.5, igtl=False, quiet=True, fast=True,
                        save_raw=tmp_path / "raw.h5")
    with TrackingSession.from_tracker(None, opts) as s:
        first = s.run()
    r = view_recording(ViewRecordingOptions(raw=tmp_path / "raw.h5", hold=0.0, quiet=True))
    assert r.kind == "raw" and r.rows == r.samples_shown == first.summary.n_samples > 0
    assert r.track["status_counts"] == first.summary.status_counts


@needs_chromium
def test_bench_track_view_key():
    """``bench track --view``: both factors measured with the page open and drawing."""
    from openemt.bench._track import _raw, _spec
    from openemt.bench._view import view_cost

    spec = _spec("concentric", 1)
    raw, layout = _raw(spec, 0.5, 0)
    # 8 s of signal: a run long enough (about 0.15 s of wall time here) for the browser's CPU,
    # which /proc counts in 10 ms ticks, to show; 2 s runs (40 ms) often counted none
    out = view_cost(spec, raw, layout, seconds=8.0, pairs=1)
    assert out["realtime_factor_with_view"] > 0 and out["realtime_factor_without_view"] > 0
    assert out["ratio"] == pytest.approx(out["realtime_factor_with_view"]
                                         / out["realtime_factor_without_view"])
    assert out["pages_opened"] >= 1 and out["cpu"]["browser_cores_with_view"] > 0
    # the page's own count of the updates it applied, never more than the server sent it
    # over the same runs and those it had in flight when each run began (at most two while
    # the page keeps up; one more each 0.5 s that it does not)
    assert out["updates_in_flight_at_starts"] >= 0
    assert 0 <= out["updates_applied"] <= (out["updates_pushed"]
                                           + out["updates_in_flight_at_starts"])
    assert out["cpu"]["session_thread_ratio"] == pytest.approx(
        out["cpu"]["session_thread_realtime_factor_with_view"]
        / out["cpu"]["session_thread_realtime_factor_without_view"])


def test_bench_track_view_key_without_chromium(monkeypatch):
    import shutil

    from openemt.bench._view import view_cost

    monkeypatch.setattr(shutil, "which", lambda name: None)
    out = view_cost(None, None, None)
    assert out["realtime_factor_with_view"] is None and "no chromium" in out["reason"]


def _collect_options(tmp_path, **kw):
    from openemt.collect import CollectOptions

    return CollectOptions(output=tmp_path / "c.h5", simulate_reference="robot", n_poses=4,
                          seed=2, sim_speed=4, **kw)


@needs_chromium
def test_view_of_a_simulated_collect_in_chromium(tmp_path):
    """``collect --view``: the collect panel shows the dwell count (against the target and
    the minimum calibrate needs) and the coverage the collection's result reports."""
    from openemt.calibrate import MIN_REFERENCE_POSES
    from openemt.collect import collect
    from openemt.view._page import COLLECT_PANELS

    feed = LiveFeed()
    with ViewProcess(feed, panels=COLLECT_PANELS) as server, Browser() as browser:
        browser.open(server.url)
        browser.wait_for(_source_js("header"))
        r = collect(_collect_options(tmp_path), observer=feed)
        browser.wait_for(f"(() => {{ const d = {_source_js('collect')}; return d && d.state "
                         f"&& d.state[0].startsWith('ended'); }})()", timeout=30)
        shown = source_data(browser, "collect")
        js = ("Bokeh.index.find_one(Bokeh.documents[0].get_model_by_name('collect_table'))"
              ".markup_el.innerHTML")
        browser.wait_for(f"{js}.includes('ended')", timeout=10)
        html = browser.evaluate(js)
        dwells = source_data(browser, "dwells")
        carriers = source_data(browser, "carriers")
    assert r.n_poses == 4 and shown["state"] == [f"ended: {r.ended_by}"]
    assert shown["n_dwells"] == [r.n_poses] and shown["n_target"] == [4]
    assert shown["n_min"] == [MIN_REFERENCE_POSES]
    cov = r.coverage
    for k in ("volume_coverage_pct", "outside", "orientation_spread_deg",
              "rotation_second_axis_deg"):
        assert shown[k][0] == pytest.approx(cov[k], rel=1e-12, abs=1e-12), k
    assert shown["rotation_diversity"] == ["ok" if cov["rotation_diversity_ok"] else "NOT yet"]
    assert shown["time_offset_ms"][0] == pytest.approx(r.time_offset_ms, rel=1e-12)
    assert len(dwells["x"]) == r.n_poses == len(dwells["azimuth"])
    # the table the page draws says the same, to the digits it shows
    for text in (f"<td>{r.n_poses}</td>", f"{cov['volume_coverage_pct']:.1f}",
                 f"{cov['orientation_spread_deg']:.1f}", f"<td>{MIN_REFERENCE_POSES}</td>"):
        assert text in html.replace('<td style="padding: 2px 10px">', "<td>"), (text, html)
    # the carriers panel has the raw samples' drive levels (a collect solves no sample)
    assert len(carriers["reference_v"]) == 3 and min(carriers["reference_v"]) > 0


def test_collect_with_view_reports_the_view(tmp_path):
    """The workflow of ``collect --view``: the same collection, the page's address and its
    counts in the result (``view``), and no ``view`` key without it."""
    from openemt.view import ViewOptions, collect_with_view

    r = collect_with_view(_collect_options(tmp_path), ViewOptions(view=True))
    d = r.to_dict()
    assert r.n_poses == 4 and d["view"]["url"].startswith("http://127.0.0.1:")
    assert d["view"]["pages_opened"] == 0 and d["view"]["updates_pushed"] == 0
    assert "view" not in replace(r, view=None).to_dict()


def test_a_ring_reader_overtaken_by_the_writer_reads_again():
    """The couplings ring's reader copies again when the session's thread appended more rows
    than the ring's spare half between the reader's count and its copy (a lapped copy would
    mix old and new rows)."""
    from openemt.view._feed import _Rows

    ring = _Rows(4)
    for k in range(6):
        ring.append(np.full((1, 2), float(k)))

    class Overtaking(np.ndarray):
        laps = 0

        def __getitem__(self, idx):
            out = np.ndarray.__getitem__(self, idx)
            if Overtaking.laps == 0:             # the writer runs during the first copy
                Overtaking.laps += 1
                for k in range(6, 12):
                    ring.append(np.full((1, 2), float(k)))
            return out

    ring.rows = ring.rows.view(Overtaking)
    assert np.asarray(ring.last())[:, 0].tolist() == [8.0, 9.0, 10.0, 11.0]
