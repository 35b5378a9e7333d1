"""The live view's web server: a Bokeh server on the local machine, in a thread (of the
process :class:`~openemt.view.ViewProcess` starts for it, or of any process).

The server thread runs its own event loop; each browser tab gets a document whose periodic
callback reads :meth:`openemt.view.LiveFeed.snapshot` (never the session itself). BokehJS is
inlined into the page (no request leaves the machine: no CDN, not even the server's own
static route for the library), and websocket connections are accepted only from pages served
by this server (``127.0.0.1:PORT`` / ``localhost:PORT``).
"""

from __future__ import annotations

import threading
import time

from .._errors import InputError

__all__ = ["ViewServer"]

HOST = "127.0.0.1"


class _Rate:
    """Updates pushed to the browsers: count and the rate over the last seconds."""

    def __init__(self):
        self.count = 0
        self.times: list = []
        self._lock = threading.Lock()
        self._applied: dict = {}         # page -> updates it says it has applied

    def applied(self, page, n: int) -> None:
        """Page ``page`` has applied ``n`` updates (its acknowledgement)."""
        with self._lock:
            self._applied[page] = max(int(n), self._applied.get(page, 0))

    @property
    def n_applied(self) -> int:
        """Updates the pages have applied, counted by the pages themselves."""
        with self._lock:
            return sum(self._applied.values())

    def tick(self) -> None:
        now = time.monotonic()
        with self._lock:
            self.count += 1
            self.times.append(now)
            if len(self.times) > 600:
                del self.times[:300]

    def per_second(self, seconds: float = 2.0) -> float:
        """Updates per second over the last ``seconds`` (0 when none)."""
        now = time.monotonic()
        with self._lock:
            k = sum(1 for t in self.times if t > now - seconds)
        return k / seconds


class ViewServer:
    """Serve the live view of ``feed`` on ``http://127.0.0.1:PORT/`` (``port`` 0: a free one)
    in a thread; refresh each open tab ``rate_hz`` times per second; ``panels``: the panels
    a page shows unless its address names some (default: those of a tracking session).

    Use as a context manager (or :meth:`start` / :meth:`close`); :attr:`url` is the page.
    """

    def __init__(self, feed, *, port: int = 0, rate_hz: float = 12.0, panels=None):
        if not 0 <= int(port) <= 65535:
            raise InputError(f"expected a view port in 0..65535, got {port}")
        if not 1.0 <= float(rate_hz) <= 60.0:
            raise InputError(f"expected a view rate in 1..60 Hz, got {rate_hz}")
        self.feed = feed
        self.panels = None if panels is None else tuple(panels)
        self.requested_port = int(port)
        self.rate_hz = float(rate_hz)
        self.port = None
        self.stats = _Rate()
        self.pages = 0
        self._thread = None
        self._ready = threading.Event()
        self._error = None
        self._loop = self._server = None

    @property
    def url(self) -> str:
        return f"http://{HOST}:{self.port}/"

    def _make_doc(self, doc) -> None:
        from ._page import ALL_PANELS, PANELS, Page

        args = doc.session_context.request.arguments if doc.session_context else {}
        want = [a.decode() for a in args.get("panel", [])]
        panels = tuple(p for p in ALL_PANELS if p in want) or self.panels or PANELS
        self.pages += 1
        Page(doc, self.feed, period_ms=1000.0 / self.rate_hz, stats=self.stats,
             panels=panels)

    def _run(self) -> None:
        import asyncio

        try:
            from bokeh.application import Application
            from bokeh.application.handlers.function import FunctionHandler
            from bokeh.resources import Resources
            from bokeh.server.server import BaseServer
            from bokeh.server.tornado import BokehTornado
            from tornado.httpserver import HTTPServer
            from tornado.ioloop import IOLoop
            from tornado.netutil import bind_sockets

            class _Inline(BokehTornado):
                def resources(self, absolute_url=None):
                    return Resources(mode="inline")

            asyncio.set_event_loop(asyncio.new_event_loop())
            loop = IOLoop.current()
            sockets = bind_sockets(self.requested_port, address=HOST)
            self.port = sockets[0].getsockname()[1]
            origins = [f"{HOST}:{self.port}", f"localhost:{self.port}"]
            app = _Inline({"/": Application(FunctionHandler(self._make_doc))},
                          extra_websocket_origins=origins, absolute_url=self.url,
                          stats_log_frequency_milliseconds=3_600_000,
                          mem_log_frequency_milliseconds=0)
            http = HTTPServer(app)
            http.add_sockets(sockets)
            self._server = BaseServer(loop, app, http)
            self._server.start()
            self._loop = loop
        except BaseException as exc:        # reported by start() in the caller's thread
            self._error = exc
            self._ready.set()
            return
        self._ready.set()
        loop.start()
        loop.close(all_fds=True)

    def start(self) -> ViewServer:
        self._thread = threading.Thread(target=self._run, name="openemt-view", daemon=True)
        self._thread.start()
        self._ready.wait(60.0)
        if self._error is not None:
            if isinstance(self._error, OSError):
                raise InputError(f"expected a free view port on {HOST}, got "
                                 f"{self.requested_port}: {self._error.strerror or self._error}"
                                 ) from None
            raise self._error
        return self

    def close(self) -> None:
        loop, server = self._loop, self._server
        if loop is None:
            return
        self._loop = None

        def stop():
            try:
                server.stop(wait=False)
                server.unlisten()
            finally:
                loop.stop()

        loop.add_callback(stop)
        self._thread.join(10.0)

    def __enter__(self) -> ViewServer:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()
