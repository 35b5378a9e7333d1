"""``openemt bench track --view``: what the live view costs the acquisition.

The realtime factor of ``bench track`` (seconds of signal per second of wall time, as fast as
possible, raw samples held in memory) measured with and without the live view, in the same
process and with the same page open: the view's server (:class:`openemt.view.ViewProcess`,
as ``track --view`` runs it) and headless Chromium showing its page throughout. Runs alternate (without, with, with,
without, ...); a run *with* the view publishes every block to the view's
:class:`~openemt.view.LiveFeed` (which the page then shows at its rate), a run *without* it
does not (the open page then has nothing new to draw and nothing is sent). Each run
processes ``--view-seconds`` of signal (the ``--rate-seconds`` recording, repeated).

Keys: ``realtime_factor_with_view`` and ``realtime_factor_without_view`` (medians),
``ratio`` (with / without; the target is >= 0.9), every run's factor, ``cpu`` (where the time
went: the session thread's own realtime factor per CPU second with and without the view and
``session_thread_ratio``, with / without, the CPU-based figure; the cores used by the
process's other threads, by the view's server process and by the browser),
``updates_per_s`` (updates the server sent the page per second during the runs with the
view; it waits for the page's acknowledgement before sending more than two ahead),
``updates_in_flight_at_starts`` (sent but not yet acknowledged when each run with the view
began, summed: the page may apply those during the run), ``updates_applied`` and
``updates_applied_per_s`` (the updates the page itself counted as
applied over those runs, from its acknowledgements: what the browser drew), ``browser`` (the
Chromium used, or the reason there was none: then the factors are not measured).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
import time

import numpy as np

__all__ = ["view_cost"]


def _tree_cpu(pid: int) -> float:
    """CPU seconds used so far by process ``pid`` and its descendants (Linux /proc; 0 where
    it cannot be read)."""
    tick = os.sysconf("SC_CLK_TCK")
    used, children = {}, {}
    for name in os.listdir("/proc"):
        if not name.isdigit():
            continue
        try:
            with open(f"/proc/{name}/stat") as f:
                st = f.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        used[int(name)] = int(st[11]) + int(st[12])
        children.setdefault(int(st[1]), []).append(int(name))
    total, todo = 0, [pid]
    while todo:
        p = todo.pop()
        total += used.get(p, 0)
        todo.extend(children.get(p, []))
    return total / tick

_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
          "--disable-background-networking", "--disable-component-update", "--disable-sync",
          "--disable-extensions", "--mute-audio", "--window-size=1300,1400"]



def view_cost(spec, raw, layout, *, chunk: int = 640, seconds: float = 30.0,
              pairs: int = 5) -> dict:
    """The realtime factor of ``spec`` on ``raw`` with and without the live view open (see
    the module docstring)."""
    from ..live import TrackingSession, TrackOptions, tracker_sensors
    from ..view import LiveFeed, ViewProcess
    from ._memory import Memory

    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    out = {"what": "realtime factor with the live view open in headless Chromium against "
                   "the same without publishing to it, alternating runs in one process",
           "view_seconds": seconds, "pairs": pairs, "browser": chromium}
    if chromium is None:
        out.update(realtime_factor_with_view=None, realtime_factor_without_view=None,
                   ratio=None, reason="no chromium on this machine (Debian package chromium)")
        return out
    n = int(seconds * layout.sample_rate)
    sensors = tracker_sensors(spec)
    opts = TrackOptions(igtl=False, quiet=True)

    cpu = {True: [], False: []}

    def run(feed):
        with TrackingSession(spec, opts, sensors=sensors, observer=feed,
                             backend=Memory(raw, layout, chunk, n)) as session:
            t0, c0, p0 = time.perf_counter(), time.thread_time(), time.process_time()
            b0 = _tree_cpu(browser.pid) if feed is not None else 0.0
            v0 = _tree_cpu(server._proc.pid) if feed is not None else 0.0
            s = session.run().summary
            wall = time.perf_counter() - t0
            cpu[feed is not None].append(
                (s.signal_seconds / (time.thread_time() - c0),
                 (time.process_time() - p0 - (time.thread_time() - c0)) / wall,
                 (_tree_cpu(browser.pid) - b0) / wall if feed is not None else 0.0,
                 (_tree_cpu(server._proc.pid) - v0) / wall if feed is not None else 0.0))
            return s.signal_seconds / wall

    feed = LiveFeed()
    out["load_average_start"] = list(os.getloadavg())
    # Chromium's helper processes may still write into the profile as it exits
    with ViewProcess(feed) as server, \
            tempfile.TemporaryDirectory(ignore_cleanup_errors=True) as profile:
        browser = subprocess.Popen([chromium, *_FLAGS, f"--user-data-dir={profile}",
                                    server.url], stdout=subprocess.DEVNULL,
                                   stderr=subprocess.DEVNULL)
        try:
            end = time.monotonic() + 60.0
            run(None)                                    # warm: kernels, caches
            run(feed)                                    # until the page shows updates
            while server.stats()["updates_pushed"] < 3 and time.monotonic() < end:
                run(feed)
            if server.stats()["updates_pushed"] < 3:
                raise OSError("expected the live view page to open in headless Chromium, "
                              "got no update applied in 60 s")
            cpu[True].clear()
            cpu[False].clear()
            with_, without, updates, applied, wall = [], [], 0, 0, 0.0
            in_flight = 0
            for k in range(pairs):
                order = (False, True) if k % 2 == 0 else (True, False)
                for on in order:
                    if on:
                        s0, t0 = server.stats(), time.perf_counter()
                        with_.append(run(feed))
                        s1 = server.stats()
                        updates += s1["updates_pushed"] - s0["updates_pushed"]
                        applied += s1["updates_applied"] - s0["updates_applied"]
                        in_flight += s0["updates_pushed"] - s0["updates_applied"]
                        wall += time.perf_counter() - t0
                    else:
                        without.append(run(None))
            pages = server.stats()["pages_opened"]
        finally:
            browser.terminate()
            try:
                browser.wait(10)
            except subprocess.TimeoutExpired:  # pragma: no cover
                browser.kill()
                browser.wait(10)
    w, wo = float(np.median(with_)), float(np.median(without))

    def med(on, k):
        return float(np.median([c[k] for c in cpu[on]]))

    # where the time went: the session thread's own CPU per second of signal (a slower
    # acquisition code path would show here), the other threads of this process (the view's
    # server) and the browser, in cores while the runs lasted
    out["cpu"] = {"session_thread_realtime_factor_with_view": med(True, 0),
                  "session_thread_realtime_factor_without_view": med(False, 0),
                  "session_thread_ratio": med(True, 0) / med(False, 0),
                  "other_threads_cores_with_view": med(True, 1),
                  "other_threads_cores_without_view": med(False, 1),
                  "browser_cores_with_view": med(True, 2),
                  "view_server_process_cores_with_view": med(True, 3)}
    out.update(realtime_factor_with_view=w, realtime_factor_without_view=wo, ratio=w / wo,
               ratio_target=0.9, with_view_runs=with_, without_view_runs=without,
               updates_per_s=updates / wall if wall > 0 else None,
               updates_applied_per_s=applied / wall if wall > 0 else None,
               updates_pushed=updates, updates_applied=applied,
               updates_in_flight_at_starts=in_flight, pages_opened=pages,
               view_rate_hz=server.rate_hz, load_average=list(os.getloadavg()),
               cpu_count=os.cpu_count())
    return out
