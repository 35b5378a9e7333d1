"""The live view's server process (``python -m openemt.view._child SNAP_FD CTL_FD PORT
RATE PANELS``, started by :class:`openemt.view.ViewProcess`): a :class:`~openemt.view.ViewServer`
whose feed asks the session's process for snapshots over the first socket; the second one
carries its port, its statistics and the request to close."""

from __future__ import annotations

import logging
import sys

from .._errors import InputError
from ._process import _RemoteFeed


def main(snap_conn, ctl_conn, port: int, rate_hz: float, panels=None) -> None:
    from ._server import ViewServer

    try:
        server = ViewServer(_RemoteFeed(snap_conn), port=port, rate_hz=rate_hz,
                            panels=panels).start()
    except BaseException as exc:           # noqa: BLE001 - reported to the parent
        ctl_conn.send(("error", f"{type(exc).__name__}: {exc}", isinstance(exc, InputError)))
        return
    ctl_conn.send(("port", server.port))
    try:
        while True:
            msg = ctl_conn.recv()
            ctl_conn.send(("stats", server.stats.count, server.pages,
                           server.stats.per_second(), server.stats.n_applied))
            if msg == "close":
                break
    except (EOFError, OSError, KeyboardInterrupt):
        pass
    finally:
        server.close()


if __name__ == "__main__":
    import signal
    from multiprocessing.connection import Connection

    # Ctrl-C reaches the whole process group: the session stops and then closes the view (a
    # parent that dies closes the sockets, which ends this process too)
    signal.signal(signal.SIGINT, signal.SIG_IGN)

    logging.getLogger("bokeh").setLevel(logging.ERROR)    # closed pages are not errors
    main(Connection(int(sys.argv[1])), Connection(int(sys.argv[2])), int(sys.argv[3]),
         float(sys.argv[4]), tuple(p for p in sys.argv[5].split(",") if p) or None)
