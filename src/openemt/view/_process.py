"""The live view's server in a process of its own, away from the session's interpreter.

A Bokeh server in the session's process competes with the acquisition for the interpreter
lock: every websocket write, every acknowledgement read and every message serialised is a
hand-over of the lock, and on a busy machine the thread that takes it may wait for a core
while the acquisition waits for it. :class:`ViewProcess` runs the :class:`ViewServer` in a
child process (a fresh interpreter, ``python -m openemt.view._child``, talking over two
socket pairs); the session's process keeps only the
:class:`LiveFeed` and one thread that, when a page asks (at most the view rate, per open
page), gathers the inputs of a snapshot (``LiveFeed.gather``: the recent arrays) and sends them
down a pipe, the child computes the panels from them: one short hand-over per update instead
of dozens, and no Bokeh code in the session's interpreter.
"""

from __future__ import annotations

import threading

from .._errors import InputError

__all__ = ["ViewProcess"]


class _RemoteFeed:
    """The child's feed: each :meth:`snapshot` asks the session's process for fresh inputs
    (:meth:`LiveFeed.gather`) and computes the snapshot from them here (the last one again
    when none arrives within ``timeout``)."""

    def __init__(self, conn, timeout: float = 1.0):
        self.conn, self.timeout = conn, float(timeout)
        self.last = None
        self.layout, self.names = None, ()

    @property
    def version(self):
        return None if self.last is None else self.last["version"]

    def snapshot(self) -> dict:
        try:
            self.conn.send(self.version)              # the version it has: None if unchanged
            if self.conn.poll(self.timeout):
                inputs = self.conn.recv()
                if inputs is not None:
                    from ._feed import compute_snapshot

                    self.layout, self.names = inputs["layout"], inputs["names"]
                    self.last = dict(compute_snapshot(inputs), layout=self.layout,
                                     names=self.names)
        except (EOFError, OSError):        # the session ended: keep showing the last state
            pass
        if self.last is None:
            return {"version": -1, "sensors": [], "frequencies": None, "source": None}
        return self.last


def _stats(msg) -> dict:
    """The child's ``("stats", pushed, pages, rate, applied)`` as :meth:`ViewProcess.stats`
    gives it (None: every value None)."""
    keys = ("updates_pushed", "pages_opened", "updates_per_s", "updates_applied")
    return dict(zip(keys, msg[1:] if msg is not None else (None,) * len(keys)))


class ViewProcess:
    """Serve the live view of ``feed`` from a child process (see the module docstring); the
    same interface as :class:`ViewServer`: :attr:`url`, :meth:`stats` (updates pushed, pages
    opened), use as a context manager."""

    def __init__(self, feed, *, port: int = 0, rate_hz: float = 12.0, panels=None):
        if not 0 <= int(port) <= 65535:
            raise InputError(f"expected a view port in 0..65535, got {port}")
        if not 1.0 <= float(rate_hz) <= 60.0:
            raise InputError(f"expected a view rate in 1..60 Hz, got {rate_hz}")
        self.feed, self.requested_port, self.rate_hz = feed, int(port), float(rate_hz)
        self.panels = None if panels is None else tuple(panels)
        self.port = None
        self._proc = self._thread = None
        self._ctl_lock = threading.Lock()
        self._final = None

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}/"

    def start(self) -> ViewProcess:
        import socket
        import subprocess
        import sys
        from multiprocessing.connection import Connection

        snap, snap_child = socket.socketpair()
        ctl, ctl_child = socket.socketpair()
        fds = (snap_child.fileno(), ctl_child.fileno())
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "openemt.view._child", *map(str, fds),
             str(self.requested_port), repr(self.rate_hz), ",".join(self.panels or ())],
            pass_fds=fds,
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL)
        snap_child.close()
        ctl_child.close()
        self._snap, self._ctl = Connection(snap.detach()), Connection(ctl.detach())
        try:
            ready = self._ctl.poll(120.0)
            msg = self._ctl.recv() if ready else None
        except (EOFError, OSError):
            msg = ("error", "it exited", False)
        if msg is None or msg[0] == "error":
            self.close()
            if msg is not None and msg[2]:
                raise InputError(msg[1].split(": ", 1)[1])
            raise OSError(f"expected the live view's server process to start, got "
                          f"{'no answer in 120 s' if msg is None else msg[1]}")
        self.port = msg[1]
        self._thread = threading.Thread(target=self._publish, name="openemt-view-feed",
                                        daemon=True)
        self._thread.start()
        return self

    def _publish(self) -> None:
        """Answer the child's requests with the feed's inputs of a snapshot (blocked in
        ``recv`` otherwise): gathered here, computed in the child."""
        conn = self._snap
        try:
            while True:
                have = conn.recv()
                if have is not None and have == self.feed.version:
                    conn.send(None)                   # nothing new
                    continue
                conn.send(self.feed.gather())
        except (EOFError, OSError):
            return

    def stats(self) -> dict:
        """Updates pushed to the pages, pages opened, the recent update rate and the updates
        the pages say they have applied."""
        if self._final is not None:
            return self._final
        with self._ctl_lock:
            try:
                self._ctl.send("stats")
                return _stats(self._ctl.recv())
            except (EOFError, OSError):
                return _stats(None)

    def close(self) -> None:
        proc, self._proc = self._proc, None
        if proc is None:
            return
        if self.port is not None and proc.poll() is None:
            with self._ctl_lock:
                try:
                    self._ctl.send("close")
                    if self._ctl.poll(10.0):
                        self._final = _stats(self._ctl.recv())
                except (EOFError, OSError):
                    pass
        try:
            proc.wait(10.0)
        except Exception:  # noqa: BLE001 - subprocess.TimeoutExpired
            proc.terminate()
            proc.wait(5.0)
        for conn in (self._snap, self._ctl):
            conn.close()
        if self._thread is not None:
            self._thread.join(5.0)

    def __enter__(self) -> ViewProcess:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()
