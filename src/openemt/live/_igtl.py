"""OpenIGTLink output: a TRANSFORM server that 3D Slicer's OpenIGTLinkIF module connects to.

Poses are metres inside openemt; OpenIGTLink transforms for Slicer are in **millimetres**
(Slicer's convention), so :meth:`IgtlServer.send_pose` scales the translation by 1000 at this
edge and nowhere else. The message transports the 4x4 pose as float32 (about 1e-5 mm and
1e-7 rad of rounding at 200 mm).

The server is pyigtl's ``OpenIGTLinkServer`` (message packing, socket server) with its own
connection handler so that it

- never grows memory: poses wait in a bounded queue (``max_queue``, oldest dropped first, a
  tracker wants the newest pose) and nothing is queued while no client is connected;
- notices a client that disconnects and accepts the next one (Slicer reconnecting);
- drops a client whose socket stays blocked longer than ``send_timeout`` (a stalled viewer
  cannot stall the tracker);
- shuts down within about ``poll`` seconds and leaves no thread behind.
"""

from __future__ import annotations

import collections
import logging
import select
import socket
import socketserver
import threading
import time

import numpy as np
import pyigtl
from pyigtl.comm import OpenIGTLinkBase

from .._errors import InputError

__all__ = ["DEFAULT_IGTL_PORT", "IgtlServer"]

#: The OpenIGTLink port 3D Slicer's client connector uses by default.
DEFAULT_IGTL_PORT = 18944

logger = logging.getLogger(__name__)


class _Handler(socketserver.BaseRequestHandler):
    """One connected client: send queued transforms until it leaves or the server stops."""

    def handle(self):
        srv: _Server = self.server
        owner = srv.owner
        sock = self.request
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.settimeout(owner.send_timeout)
        owner._attach(sock)
        try:
            while not srv.communication_thread_stop_requested:
                owner._wait(owner.poll)
                readable, _, _ = select.select([sock], [], [], 0)
                # a client message (ignored) or the client closing
                if readable and not sock.recv(65536):
                    logger.info("OpenIGTLink client disconnected")
                    break
                with owner._send_lock:          # taken before the batch: keeps the order
                    for data, count, t_ready in owner._take():
                        sock.sendall(data)
                        owner._sent(count, t_ready)
        except OSError as exc:  # includes socket.timeout: stalled or vanished client
            logger.warning("OpenIGTLink client dropped: %s", exc)
        finally:
            owner._detach()


class _Server(pyigtl.OpenIGTLinkServer):
    """pyigtl's server with our handler, no process signal handlers, explicit lifetime."""

    allow_reuse_address = True

    def __init__(self, owner, host: str, port: int):
        OpenIGTLinkBase.__init__(self)
        self.owner = owner
        self.host = host
        socketserver.TCPServer.__init__(self, (host, port), _Handler)
        self.port = self.server_address[1]


class IgtlServer:
    """Serve sensor poses as OpenIGTLink TRANSFORM messages.

    Parameters
    ----------
    port : int
        TCP port (default 18944, Slicer's default); 0 picks a free port (see :attr:`port`).
    host : str
        Interface to listen on ("127.0.0.1" for local viewers; "0.0.0.0" for the network).
    device_name : str
        OpenIGTLink device name = the transform node name in Slicer.
    max_queue : int
        Items (a pose, or a block of poses from :meth:`send_poses`) waiting for a slow client;
        older ones are dropped first.
    send_timeout : float
        A client whose socket blocks longer than this (s) is disconnected.
    poll : float
        Wake-up period of the sender thread (s); bounds the shutdown time.

    Examples
    --------
    >>> with IgtlServer(port=0, device_name="SensorToTracker") as srv:   # doctest: +SKIP
    ...     srv.send_pose(pose_in_metres)
    """

    def __init__(self, port: int = DEFAULT_IGTL_PORT, *, host: str = "127.0.0.1",
                 device_name: str = "openemt", max_queue: int = 16, send_timeout: float = 1.0,
                 poll: float = 0.02):
        if not isinstance(device_name, str) or not device_name or len(device_name) > 20:
            raise InputError(f"expected a `device_name` of 1-20 characters, got {device_name!r}")
        if int(max_queue) < 1:
            raise InputError(f"expected `max_queue` >= 1, got {max_queue!r}")
        port = int(port)
        if not 0 <= port <= 65535:
            raise InputError(f"expected a TCP `port` in 0..65535, got {port}")
        self.device_name = device_name
        self.send_timeout = float(send_timeout)
        self.poll = float(poll)
        self._queue: collections.deque = collections.deque()
        self._max_queue = int(max_queue)
        self._cond = threading.Condition()
        self._send_lock = threading.Lock()
        self._direct = None
        self._partial = False
        self._connected = False
        self.n_queued = 0
        self.n_sent = 0
        self.n_dropped = 0
        self.n_no_client = 0
        self.n_connections = 0
        self._latency = collections.deque(maxlen=200_000)
        self._closed = False
        try:
            self._server = _Server(self, host, port)
        except OSError as exc:
            raise OSError(f"expected a free TCP port for OpenIGTLink on {host}:{port}, got "
                          f"{exc.strerror or exc}") from None
        self._thread = threading.Thread(target=self._server.serve_forever,
                                        kwargs={"poll_interval": self.poll},
                                        name="openemt-igtl", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ state
    @property
    def port(self) -> int:
        """The TCP port actually listened on."""
        return self._server.port

    @property
    def connected(self) -> bool:
        """True while a client is connected."""
        return self._connected

    @property
    def queue_length(self) -> int:
        return len(self._queue)

    def latencies(self) -> np.ndarray:
        """Seconds from ``t_ready`` (given to :meth:`send_pose`) to the end of the socket send,
        for the most recent (up to 200 000) sent poses."""
        return np.asarray(self._latency)

    def stats(self) -> dict:
        """Counters: queued, sent, dropped (queue full), no_client (nobody listening),
        connections."""
        return {"queued": self.n_queued, "sent": self.n_sent, "dropped": self.n_dropped,
                "no_client": self.n_no_client, "connections": self.n_connections}

    def _attach(self, sock):
        direct = sock.dup()                 # non-blocking twin for the caller's fast path
        direct.setblocking(False)
        with self._cond:
            self._connected = True
            self._direct = direct
            self.n_connections += 1

    def _detach(self):
        with self._send_lock, self._cond:
            self._connected = False
            self._queue.clear()
            self._partial = False
            if self._direct is not None:
                self._direct.close()
                self._direct = None

    def _wait(self, timeout):
        with self._cond:
            if not self._queue:
                self._cond.wait(timeout)

    def _take(self):
        with self._cond:
            batch = list(self._queue)
            self._queue.clear()
            self._partial = False
        return batch

    def _sent(self, count, t_ready):
        with self._cond:
            self._count_sent(count, t_ready)

    def _count_sent(self, count, t_ready):
        self.n_sent += count
        if t_ready is not None:
            self._latency.extend([time.perf_counter() - t_ready] * count)

    # ------------------------------------------------------------------ sending
    def send_pose(self, pose, *, timestamp: float | None = None,
                  t_ready: float | None = None) -> bool:
        """Queue one pose (metres) as a TRANSFORM in millimetres.

        Parameters
        ----------
        pose : ndarray, shape (4, 4)
            Sensor pose in the source frame, translation in metres.
        timestamp : float, optional
            Acquisition time (s since the epoch) written into the message.
        t_ready : float, optional
            ``time.perf_counter()`` when the pose's couplings were available; the sender records
            the latency to the end of the socket send.

        Returns
        -------
        bool
            False when no client is connected (nothing queued) or the server is closed.
        """
        P = np.asarray(pose, dtype=np.float64)
        if P.shape != (4, 4):
            raise InputError(f"expected `pose` of shape (4, 4), got {P.shape}")
        return self.send_poses(P[None], None if timestamp is None else [timestamp],
                               t_ready=t_ready)

    def send_poses(self, poses, timestamps=None, *, t_ready: float | None = None) -> bool:
        """Queue several poses (metres) as consecutive TRANSFORMs, written to the socket in one
        piece (one system call for a block of samples).

        Parameters
        ----------
        poses : ndarray, shape (N, 4, 4)
        timestamps : array of N floats, optional
            Acquisition times (s since the epoch).
        t_ready : float, optional
            See :meth:`send_pose`; the latency is recorded for each of the N poses.
        """
        P = np.asarray(poses, dtype=np.float64)
        if P.ndim != 3 or P.shape[1:] != (4, 4):
            raise InputError(f"expected `poses` of shape (N, 4, 4), got {P.shape}")
        ts = [None] * len(P) if timestamps is None else [float(t) for t in timestamps]
        if len(ts) != len(P):
            raise InputError(f"expected {len(P)} timestamps, got {len(ts)}")
        if len(P) == 0:
            return False
        if not self._connected:                  # cheap exit before packing
            with self._cond:
                self.n_no_client += len(P)
            return False
        M = P.copy()
        M[:, :3, 3] *= 1000.0                    # metres -> millimetres (Slicer convention)
        data = b"".join(pyigtl.TransformMessage(m, timestamp=t, device_name=self.device_name)
                        .pack() for m, t in zip(M, ts))
        return self._enqueue(data, len(P), t_ready)

    def send_message(self, message, t_ready: float | None = None) -> bool:
        """Queue any pyigtl message (e.g. a ``StringMessage`` with the tracking status)."""
        return self._enqueue(message.pack(), 1, t_ready)

    def _enqueue(self, data: bytes, count: int, t_ready):
        with self._cond:
            if self._closed:
                return False
            if not self._connected:
                self.n_no_client += count
                return False
            self.n_queued += count
            # fast path: nothing waiting and the sender idle -> non-blocking send right here
            # (no thread hand-over, so no wait for the interpreter to switch threads)
            if (not self._queue and self._direct is not None
                    and self._send_lock.acquire(blocking=False)):
                try:
                    n = self._direct.send(data)
                except OSError:                 # would block, or the client is gone
                    n = 0
                finally:
                    self._send_lock.release()
                if n == len(data):
                    self._count_sent(count, t_ready)
                    return True
                if n:                           # the rest must go out next, never dropped
                    self._queue.append((data[n:], count, t_ready))
                    self._partial = True
                    self._cond.notify()
                    return True
            if len(self._queue) >= self._max_queue:
                # drop the oldest whole item (a partly sent head must be completed)
                if not self._partial:
                    self.n_dropped += self._queue.popleft()[1]
                elif len(self._queue) > 1:
                    self.n_dropped += self._queue[1][1]
                    del self._queue[1]
            self._queue.append((data, count, t_ready))
            self._cond.notify()
        return True

    def wait_for_client(self, timeout: float) -> bool:
        """Block until a client is connected or ``timeout`` seconds pass."""
        end = time.monotonic() + float(timeout)
        while not self._connected and time.monotonic() < end:
            time.sleep(0.005)
        return self._connected

    # ------------------------------------------------------------------ lifetime
    def close(self) -> None:
        """Stop serving, disconnect the client and join the server thread (idempotent)."""
        with self._cond:
            if self._closed:
                return
            self._closed = True
            self._server.communication_thread_stop_requested = True
            self._cond.notify_all()
        self._server.shutdown()
        self._server.server_close()
        self._thread.join(timeout=self.send_timeout + 5 * self.poll + 1.0)

    @property
    def closed(self) -> bool:
        return self._closed and not self._thread.is_alive()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
