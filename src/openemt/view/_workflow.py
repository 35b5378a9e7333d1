"""The live view's workflows: ``openemt track --view`` (:func:`track_with_view`),
``openemt collect --view`` (:func:`collect_with_view`) and ``openemt view`` (:func:`view_recording`: a session log replayed, or a raw recording tracked
again, into the view)."""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .._errors import InputError
from .._options import option as _opt
from .._result import Result

__all__ = ["ViewOptions", "ViewRecordingOptions", "ViewResult", "collect_with_view",
           "replay_log", "track_with_view", "view_recording"]


@dataclass(frozen=True)
class ViewOptions:
    """The live view of ``openemt track`` (off unless ``view``)."""

    view: bool = _opt(False, "serve a live view of the session in the browser on this "
                      "machine (http://127.0.0.1:PORT/, printed on stderr; "
                      "docs/live.md#live-view); it only reads the session")
    view_port: int = _opt(0, "port of the live view (default 0: a free one)")
    view_rate: float = _opt(12.0, "live view updates per second per open page (default 12)",
                            metavar="HZ")

    def check(self) -> None:
        if not 0 <= self.view_port <= 65535:
            raise InputError(f"expected --view-port in 0..65535, got {self.view_port}")
        if not 1.0 <= self.view_rate <= 60.0:
            raise InputError(f"expected --view-rate in 1..60 Hz, got {self.view_rate}")


@dataclass(frozen=True)
class ViewRecordingOptions:
    """``openemt view``: a session log (``track --log``) replayed into the live view, or a
    raw recording (``--raw``, ``track --save-raw``) tracked again with the view open."""

    log: Path | None = _opt(None, "session log from 'openemt track --log' (.h5 or .csv)",
                            positional=True, optional=True)
    raw: Path | None = _opt(None, "raw HDF5 recording ('track --save-raw') to track again "
                            "with the view open (as 'track --source replay FILE --view "
                            "--no-igtl')", metavar="FILE")
    tracker: Path | None = _opt(None, "(with --raw) tracker description file whose channel "
                                "layout the recording has (default: the simulated tracker)")
    speed: float = _opt(1.0, "(LOG) replay speed, x real time (default 1)")
    hold: float | None = _opt(None, "seconds to keep serving the last state after the end "
                              "(default: until Ctrl-C)")
    view_port: int = _opt(0, "port of the live view (default 0: a free one)")
    view_rate: float = _opt(12.0, "live view updates per second per open page (default 12)",
                            metavar="HZ")
    quiet: bool = _opt(False, "", cli=False)

    def check(self) -> None:
        if (self.log is None) == (self.raw is None):
            raise InputError(f"expected either a session LOG or --raw FILE, got "
                             f"{'both' if self.log is not None else 'neither'}")
        if self.tracker is not None and self.raw is None:
            raise InputError("expected --tracker only with --raw, got it with a LOG")
        if not 0 < self.speed < math.inf:
            raise InputError(f"expected a positive, finite --speed, got {self.speed}")
        if self.raw is not None and self.speed != 1.0:
            raise InputError(f"expected --speed only with a LOG (a raw recording is tracked "
                             f"at its sample rate), got --speed {self.speed:g} with --raw")
        if self.hold is not None and not 0 <= self.hold < math.inf:
            raise InputError(f"expected a finite --hold >= 0 in seconds, got {self.hold}")
        ViewOptions(True, self.view_port, self.view_rate).check()


@dataclass(frozen=True)
class ViewResult(Result):
    """What ``openemt view`` served: the page, the recording, the samples shown and the
    updates pushed to the browsers."""

    url: str
    recording: str
    kind: str
    sensors: list
    rows: int
    samples_shown: int
    pages_opened: int
    updates_pushed: int
    seconds: float
    track: dict | None = None

    def human(self) -> list:
        return [f"viewed {self.rows} samples of {len(self.sensors)} sensor(s) from "
                f"{self.recording} on {self.url}: {self.pages_opened} page(s) opened, "
                f"{self.updates_pushed} updates pushed in {self.seconds:.1f} s"]


class _LogStep:
    """A block of a log, shaped like the :class:`~openemt.live.TrackStep` the feed gets."""

    __slots__ = ("times", "couplings", "poses", "pose_vectors", "status", "residual",
                 "distortion", "distorted", "relative_residual")

    def __init__(self, arrays: dict, a: int, b: int):
        for k in self.__slots__:
            v = arrays.get(k)
            setattr(self, k, None if v is None else v[a:b])

    def __len__(self) -> int:
        return len(self.times)


def _log_arrays(a: dict) -> dict:
    from ..geometry import vector_from_pose

    out = dict(a)
    n = len(out["times"])
    if "pose_vectors" not in out or len(out["pose_vectors"]) != n:
        if "poses" in out and len(out["poses"]) == n:
            out["pose_vectors"] = vector_from_pose(out["poses"])
        else:
            out["pose_vectors"] = np.full((n, 6), np.nan)
    for k in ("residual", "distortion"):
        if k not in out or len(out[k]) != n:
            out[k] = np.full(n, np.nan)
    if "distorted" not in out or len(out["distorted"]) != n:
        out["distorted"] = np.zeros(n, bool)
    c = out.get("couplings")
    if c is not None and (np.ndim(c) != 3 or len(c) != n):
        out.pop("couplings")
    return out


def replay_log(feed, log, *, speed: float = 1.0, block: int = 10, stop=None) -> int:
    """Publish the rows of ``log`` (a :class:`~openemt.live.TrackLogData`) to ``feed`` in
    blocks of ``block`` samples, paced by the logged times at ``speed`` x real time; the
    samples published (``stop()`` returning True ends it early)."""
    names = tuple(log.sensors)
    arrays = [_log_arrays(log.arrays[n]) for n in names]
    feed.sensors(names)
    n = log.rows
    if not n:
        return 0
    t_log0 = float(arrays[0]["times"][0])
    t0 = time.monotonic()
    done = 0
    for a in range(0, n, block):
        if stop is not None and stop():
            break
        b = min(n, a + block)
        wait = (float(arrays[0]["times"][b - 1]) - t_log0) / speed - (time.monotonic() - t0)
        if wait > 0:
            time.sleep(wait)
        for k, arr in enumerate(arrays):
            feed.step(_LogStep(arr, a, b), k)
        done = b
    return done


def track_with_view(options, view: ViewOptions, *, say=None, tracker=None):
    """``openemt track`` with the live view: the :class:`~openemt.live.TrackingSession` of
    ``options`` (a :class:`~openemt.live.TrackOptions`) publishing to a :class:`LiveFeed`
    served by a :class:`ViewProcess` while it runs; the session's
    :class:`~openemt.live.TrackResult` with a ``view`` key (page, pages opened, updates
    pushed and their rate)."""
    from ..live import TrackingSession
    from ._feed import LiveFeed

    view.check()
    options.check()
    say = say or (lambda text: None if options.quiet else print(text, file=sys.stderr,
                                                               flush=True))
    feed = LiveFeed()
    feed.source = f"track --source {options.source}"

    def run():
        with TrackingSession.from_tracker(options.tracker if tracker is None else tracker,
                                          options, observer=feed) as session:
            return session.run()

    result, info = _served(feed, view, run, say)
    return replace(result, session={**result.session, "view": info})


def _served(feed, view: ViewOptions, run, say, panels=None):
    """``run()`` while a :class:`ViewProcess` serves ``feed`` (its address said first): its
    result and the view's summary (page, pages opened, updates pushed and their rate)."""
    from ._process import ViewProcess

    with ViewProcess(feed, port=view.view_port, rate_hz=view.view_rate,
                     panels=panels) as server:
        say(f"live view: {server.url} (open it in a browser on this machine)")
        t0 = time.monotonic()
        result = run()
        seconds = time.monotonic() - t0
        stats = server.stats()
        n = stats["updates_pushed"]
        info = {"url": server.url, "pages_opened": stats["pages_opened"],
                "updates_pushed": n,
                "updates_per_s": n / seconds if n is not None and seconds > 0 else None}
    return result, info


def collect_with_view(options, view: ViewOptions, *, progress=None,
                      handle_signals: bool = False):
    """``openemt collect`` with the live view: :func:`openemt.collect.collect` of ``options``
    (a :class:`~openemt.collect.CollectOptions`) handing its raw chunks and its state after
    every analysis to a :class:`LiveFeed` served by a :class:`ViewProcess` (the collect panel,
    the carriers and the spectra) while it runs; its
    :class:`~openemt.collect.CollectResult` with ``view`` (page, pages opened, updates pushed
    and their rate)."""
    from ..collect import collect
    from ._feed import LiveFeed
    from ._page import COLLECT_PANELS

    view.check()
    options.check()
    feed = LiveFeed()
    feed.source = f"collect --source {options.source}"
    result, info = _served(
        feed, view, lambda: collect(options, progress=progress, handle_signals=handle_signals,
                                    observer=feed),
        lambda text: None if progress is None else print(text, file=progress, flush=True),
        panels=COLLECT_PANELS)
    return replace(result, view=info)


def view_recording(options: ViewRecordingOptions, *, stop=None, say=None) -> ViewResult:
    """``openemt view``: serve the live view of a session log replayed at ``speed`` (or of a
    raw recording tracked again), then keep serving its last state for ``hold`` seconds
    (None: until ``stop()`` or Ctrl-C)."""
    from ._feed import LiveFeed
    from ._process import ViewProcess

    options.check()
    say = say or (lambda text: None if options.quiet else print(text, file=sys.stderr,
                                                               flush=True))
    feed = LiveFeed()
    t0 = time.monotonic()
    track, rows, names = None, 0, []
    kind = "log" if options.log is not None else "raw"
    recording = str(options.log if options.log is not None else options.raw)

    def stopping():
        return stop is not None and stop()

    try:
        with ViewProcess(feed, port=options.view_port, rate_hz=options.view_rate) as server:
            if options.log is not None:
                from ..live import read_track_log

                log = read_track_log(options.log)
                feed.source = f"log {options.log.name}"
                say(f"live view: {server.url} (replaying {log.rows} samples of "
                    f"{len(log.sensors)} sensor(s) from {options.log} at {options.speed:g}x)")
                names = list(log.sensors)
                rows = replay_log(feed, log, speed=options.speed, stop=stopping)
            else:
                from ..live import TrackingSession, TrackOptions

                feed.source = f"raw {options.raw.name}"
                topts = TrackOptions(tracker=options.tracker, source="replay", file=options.raw,
                                     igtl=False, quiet=True)
                say(f"live view: {server.url} (tracking {options.raw} again)")
                with TrackingSession.from_tracker(options.tracker, topts,
                                                  observer=feed) as session:
                    res = session.run(stop=stopping)
                track = res.to_dict()
                rows = res.summary.n_samples
                names = list(res.session["sensors_tracked"])
            say("the end of the recording; the view keeps its last state"
                + (" (Ctrl-C to stop)" if options.hold is None else
                   f" for {options.hold:g} s"))
            end = math.inf if options.hold is None else time.monotonic() + options.hold
            while time.monotonic() < end and not stopping():
                time.sleep(0.05)
    except KeyboardInterrupt:
        pass
    stats = server.stats()
    return ViewResult(url=server.url, recording=recording, kind=kind, sensors=names,
                      rows=rows, samples_shown=max(feed.n_samples, default=0),
                      pages_opened=stats["pages_opened"],
                      updates_pushed=stats["updates_pushed"],
                      seconds=time.monotonic() - t0, track=track)
