"""OpenIGTLink output: a TRANSFORM server that 3D Slicer's OpenIGTLinkIF module connects to.

Poses are metres inside openemt; OpenIGTLink transforms for Slicer are in **millimetres**
(Slicer's convention), so :meth:`IgtlServer.send_poses` scales the translation by 1000 at this
edge and nowhere else. The message transports the 4x4 pose as float32 (about 1e-5 mm and
1e-7 rad of rounding at 200 mm). Messages are packed by :mod:`._igtl_wire`, byte for byte
what pyigtl packs.

The server serves any number of clients at once (several Slicer instances, a recorder) and

- sends from the caller's thread with non-blocking writes, one per client, so that no client
  can hold up the tracker or the other clients; what a client's socket does not take at once
  waits in that client's bounded queue (``max_queue`` items; when it is full the oldest whole
  item is skipped and counted in ``messages_skipped``, a tracker wants the newest pose);
- flushes the queues from one I/O thread that waits on all sockets with
  ``selectors.DefaultSelector`` (epoll on Linux: no limit at file descriptor 1023, cost per
  ready socket rather than per connected one), which also accepts new clients (listen backlog
  128) and notices clients that leave, e.g. Slicer reconnecting;
- serves at most ``max_clients`` clients at once: a connection beyond that is closed at once
  and logged (one warning per burst, ``clients_refused``), so a connect flood cannot take the
  descriptors or the time of the clients being served;
- drops a client whose socket has taken no byte for ``send_timeout`` seconds while data was
  waiting (``clients_dropped``), unless a rate applies to it; the others are not delayed by
  it at all;
- sends each client the header version it reads: version 1 until the client sends a
  version-2 message (``header_version="auto"``, as PLUS does), the version-1 copy of a block
  made only when such a client is connected;
- reads what clients send: ``GET_STATUS`` is answered with STATUS, ``STT_TDATA`` switches the
  client to TDATA at its resolution (answered with ``RTS_TDATA``), ``STP_TDATA`` stops its
  tracking data; with a rate (the client's or the server's ``rate``) a client gets the
  newest message per device, never a backlog;
- queues nothing while no client is connected, and shuts down within about ``poll`` seconds,
  leaving no thread behind.
"""

from __future__ import annotations

import collections
import logging
import selectors
import socket
import struct
import threading
import time

import numpy as np
import pyigtl

from .._errors import InputError
from ._igtl_wire import (  # noqa: F401 - _VECTOR_BODIES, _metadata_columns: used by the tests
    _EXT_HEADER,
    _HEADER,
    _VECTOR_BODIES,
    MM_SCALE,
    _crc64_small,
    _metadata_columns,
    _split,
    frame_messages,
    pack_message,
    pack_transforms,
    packable,
    status_content,
    to_version_1,
    transform_bodies,
)

__all__ = ["DEFAULT_IGTL_PORT", "IgtlServer", "frame_messages", "pack_message",
           "pack_transforms", "status_content", "to_version_1", "transform_bodies"]

#: The OpenIGTLink port 3D Slicer's client connector uses by default.
DEFAULT_IGTL_PORT = 18944

logger = logging.getLogger(__name__)


def _check_device_name(name) -> str:
    if not isinstance(name, str) or not name or len(name) > 20 or not name.isascii():
        raise InputError(f"expected a `device_name` of 1-20 ASCII characters, got {name!r}")
    return name


#: Largest body of a client's message that is read (larger ones are skipped unread).
_MAX_CLIENT_BODY = 1 << 16


class _Block:
    """What one send call queues: ``data`` (the messages as packed), their ``count``, whether
    they are tracking data (``stream``: TRANSFORM / TDATA, thinned by a rate) and the header
    version of the newest message in them; the version-1 copy, the per-device split and the
    TDATA form are made on demand (only for a client that needs them) and kept."""

    __slots__ = ("_parts", "_tdata", "_v1", "count", "data", "poses", "stream", "t_ready",
                 "version")

    def __init__(self, data, count, t_ready, *, stream, version=1, poses=None):
        self.data, self.count, self.t_ready = data, count, t_ready
        self.stream, self.version, self.poses = stream, version, poses
        self._v1 = self._parts = self._tdata = None

    def encoded(self, version: int) -> bytes:
        if version >= self.version:
            return self.data
        if self._v1 is None:
            M, stamps, names = self.poses if self.poses is not None else (None,) * 3
            if M is not None and np.all(np.isfinite(M)) and np.all(stamps >= 0) and \
                    np.all(stamps < 2.0 ** 32):
                # packed again from the poses, by the kernel the version-2 block used
                body, off = transform_bodies(M)
                self._v1 = frame_messages(body, off, "TRANSFORM", names, stamps)
            else:
                self._v1 = to_version_1(self.data)
        return self._v1

    def newest(self, version: int) -> dict:
        """device name -> (its newest message in this block, messages of it in the block)."""
        if self._parts is None:
            self._parts = {}
        parts = self._parts.get(version)
        if parts is None:
            data = self.encoded(version)
            buf, starts, n = _split(data)
            parts = {}
            for k in range(n):
                s, e = int(starts[k]), int(starts[k + 1])
                dev = data[s + 14:s + 34]
                got = parts.get(dev)
                parts[dev] = (data[s:e], 1 if got is None else got[1] + 1)
            self._parts[version] = parts
        return parts

    def tdata(self, device: str, newest: bool) -> list:
        """The block as TDATA messages on ``device`` (one per time stamp, every device of that
        time stamp as a tool), or only the newest one: ``[(bytes, count)]``."""
        key = (device, newest)
        if self._tdata is None:
            self._tdata = {}
        if key in self._tdata:
            return self._tdata[key]
        out = []
        if self.poses is None:                   # already TDATA (or not tracking data)
            buf, starts, n = _split(self.data)
            msgs = [(int(starts[k]), int(starts[k + 1])) for k in range(n)
                    if self.data[int(starts[k]) + 2:int(starts[k]) + 14].rstrip(b"\0")
                    == b"TDATA"]
            if newest:
                out = [(self.data[a:b], 1) for a, b in msgs[-1:]]
            elif msgs:
                out = [(self.data if len(msgs) == n else
                        b"".join(self.data[a:b] for a, b in msgs), len(msgs))]
        else:
            from ._tdata import pack_tdata

            M, stamps, names = self.poses
            if isinstance(names, str):
                names = [names] * len(M)
            order = list(dict.fromkeys(names))
            t, inv = np.unique(stamps, return_inverse=True)
            col = np.array([order.index(x) for x in names]) if len(order) > 1 else \
                np.zeros(len(M), int)
            rows = slice(len(t) - 1, len(t)) if newest else slice(None)
            A = np.repeat(np.repeat(np.eye(4)[None, None], len(t), 0), len(order), 1)
            valid = np.zeros((len(t), len(order)), bool)
            A[inv, col] = M
            valid[inv, col] = True
            data, count = pack_tdata(A[rows], valid[rows], order, t[rows], device)
            out = [(data, count)] if count else []
        self._tdata[key] = out
        return out


class _Client:
    """One connected client: its non-blocking socket, its queue of unsent items, the header
    version it is sent, the stream it asked for and, when a rate applies to it, the newest
    waiting message per device."""

    __slots__ = ("addr", "due", "inbuf", "interval", "last_progress", "mode", "n_sent",
                 "n_skipped", "partial", "pending", "queue", "skip", "sock", "tdata_device",
                 "version")

    def __init__(self, sock, addr, version=1, interval=0.0):
        self.sock = sock
        self.addr = addr
        self.n_sent = 0
        self.n_skipped = 0
        self.queue: collections.deque = collections.deque()
        self.partial = False              # the head item is partly sent: it must go out next
        self.last_progress = time.monotonic()
        self.version = version            # header version of what it is sent
        self.mode = "default"             # "default" stream, "tdata" (STT_TDATA) or "stopped"
        self.interval = interval          # least seconds between two messages of a device
        self.tdata_device = ""
        self.pending: dict = {}           # device -> (newest message, count, t_ready)
        self.due: dict = {}               # device -> monotonic time it may be sent again
        self.inbuf = bytearray()          # bytes received, not yet a whole message
        self.skip = 0                     # bytes of an oversized body still to discard

    @property
    def special(self) -> bool:
        """Whether tracking data reaches it otherwise than as queued (a rate or a request)."""
        return self.interval > 0 or self.mode != "default"


class IgtlServer:
    """Serve sensor poses as OpenIGTLink TRANSFORM messages to any number of clients.

    Parameters
    ----------
    port : int
        TCP port (default 18944, Slicer's default); 0 picks a free port (see :attr:`port`).
    host : str
        Interface to listen on ("127.0.0.1" for local viewers; "0.0.0.0" for the network).
    device_name : str
        Default OpenIGTLink device name = the transform node name in Slicer (each call of
        :meth:`send_poses` may name another device, one per sensor).
    max_queue : int
        Items (a pose, or a block of poses from :meth:`send_poses`) waiting per client for a
        slow reader; older ones are skipped first.
    send_timeout : float
        A client whose socket takes no data for this long (s) while data waits is dropped.
    poll : float
        Wake-up period of the I/O thread (s); bounds the shutdown time.
    max_clients : int
        Clients served at once; further connections are closed at once and counted
        (``clients_refused``).
    backlog : int
        Listen backlog (connections the kernel holds until accepted).
    header_version : "auto", 1 or 2
        OpenIGTLink header version of what each client is sent. ``"auto"`` (as PLUS does):
        version 1 -- no extended header, no metadata -- until that client sends a version-2
        message (3D Slicer's connector, or any message with header version 2, e.g.
        ``GET_STATUS``), version 2 from then on; 1 or 2 fixes it for every client.
    rate : float, optional
        Most tracking-data messages (TRANSFORM, TDATA) per second and device sent to each
        client; each client then gets the newest message of a device at most every
        ``1 / rate`` s (older ones waiting for it are replaced, never queued), and is never
        dropped for reading slowly. A client's own STT_TDATA resolution, if longer, applies
        to it instead.

    A client may also send ``STT_TDATA`` (resolution in ms: TDATA, every tracked device of
    one time stamp in one message, at most once per resolution, instead of its default
    stream; answered by ``RTS_TDATA``), ``STP_TDATA`` (no more tracking data to it; answered
    by ``RTS_TDATA``) and ``GET_STATUS`` (answered by a STATUS message, code 1 = OK).

    Examples
    --------
    >>> with IgtlServer(port=0, device_name="SensorToTracker") as srv:   # doctest: +SKIP
    ...     srv.send_pose(pose_in_metres)
    """

    def __init__(self, port: int = DEFAULT_IGTL_PORT, *, host: str = "127.0.0.1",
                 device_name: str = "openemt", max_queue: int = 16, send_timeout: float = 1.0,
                 poll: float = 0.02, max_clients: int = 64, backlog: int = 128,
                 header_version="auto", rate: float | None = None):
        self.device_name = _check_device_name(device_name)
        if str(header_version) not in ("auto", "1", "2"):
            raise InputError(f"expected `header_version` \"auto\", 1 or 2, got "
                             f"{header_version!r}")
        self.header_version = "auto" if str(header_version) == "auto" else int(header_version)
        if rate is not None and not (np.isfinite(float(rate)) and float(rate) > 0):
            raise InputError(f"expected a positive, finite `rate` in Hz, got {rate!r}")
        self.rate = None if rate is None else float(rate)
        if int(max_queue) < 1:
            raise InputError(f"expected `max_queue` >= 1, got {max_queue!r}")
        port = int(port)
        if not 0 <= port <= 65535:
            raise InputError(f"expected a TCP `port` in 0..65535, got {port}")
        if not float(send_timeout) > 0:
            raise InputError(f"expected a positive `send_timeout`, got {send_timeout!r}")
        if int(max_clients) < 1:
            raise InputError(f"expected `max_clients` >= 1, got {max_clients!r}")
        self.send_timeout = float(send_timeout)
        self.poll = float(poll)
        self.max_clients = int(max_clients)
        self.n_refused = 0
        self._refusing = False
        self._max_queue = int(max_queue)
        self._lock = threading.RLock()
        self._clients: list[_Client] = []
        self._retained: dict = {}          # key -> packed message a new client gets first
        self.n_queued = 0
        self.n_sent = 0
        self.n_skipped = 0
        self.n_no_client = 0
        self.n_connections = 0
        self.n_clients_dropped = 0
        self.n_thinned = 0
        self.n_bad_crc = 0
        self.clients_max = 0
        self._latency = collections.deque(maxlen=200_000)
        self._closed = False
        self._stop = False
        listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            listener.bind((host, port))
            listener.listen(max(1, int(backlog)))
        except OSError as exc:
            listener.close()
            raise OSError(f"expected a free TCP port for OpenIGTLink on {host}:{port}, got "
                          f"{exc.strerror or exc}") from None
        listener.setblocking(False)
        self._listener = listener
        self._port = listener.getsockname()[1]
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        self._sel = selectors.DefaultSelector()
        self._sel.register(listener, selectors.EVENT_READ, None)
        self._sel.register(self._wake_r, selectors.EVENT_READ, None)
        self._thread = threading.Thread(target=self._io_loop, name="openemt-igtl", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ state
    @property
    def port(self) -> int:
        """The TCP port actually listened on."""
        return self._port

    @property
    def connected(self) -> bool:
        """True while at least one client is connected."""
        return bool(self._clients)

    @property
    def n_clients(self) -> int:
        """Clients connected now."""
        return len(self._clients)

    @property
    def queue_length(self) -> int:
        """Longest client queue now (items)."""
        with self._lock:
            return max((len(c.queue) for c in self._clients), default=0)

    def latencies(self) -> np.ndarray:
        """Seconds from ``t_ready`` (given to :meth:`send_poses`) to the end of the socket send,
        per delivered message and client, for the most recent (up to 200 000) deliveries."""
        return np.asarray(self._latency)

    def stats(self) -> dict:
        """Counters, per message and client: ``queued`` (accepted for a client), ``sent``
        (written to a client's socket), ``messages_skipped`` (= ``dropped``: shed from a slow
        client's full queue), ``no_client`` (nobody listening); and ``connections`` (accepted
        so far), ``clients`` (now), ``clients_max`` (most at once), ``clients_dropped`` (cut off
        after ``send_timeout`` without progress), ``clients_refused`` (connections closed at
        once because ``max_clients`` were connected), ``messages_thinned`` (replaced by a newer
        message of the same device while a rate held it back), ``bad_crc`` (client messages
        ignored for a wrong CRC)."""
        with self._lock:
            return {"queued": self.n_queued, "sent": self.n_sent, "dropped": self.n_skipped,
                    "messages_skipped": self.n_skipped, "no_client": self.n_no_client,
                    "messages_thinned": self.n_thinned, "bad_crc": self.n_bad_crc,
                    "connections": self.n_connections, "clients": len(self._clients),
                    "clients_max": self.clients_max,
                    "clients_dropped": self.n_clients_dropped,
                    "clients_refused": self.n_refused}

    def clients(self) -> list:
        """The connected clients now: ``address`` (host, port), ``sent`` and ``skipped``
        messages, ``waiting`` (items in its queue), ``header_version`` (of what it is sent),
        ``stream`` (``"default"``, ``"tdata"`` after STT_TDATA, ``"stopped"`` after STP_TDATA)
        and ``interval`` (least seconds between two messages of a device; 0: every one)."""
        with self._lock:
            return [{"address": c.addr, "sent": c.n_sent, "skipped": c.n_skipped,
                     "waiting": len(c.queue), "header_version": c.version, "stream": c.mode,
                     "interval": c.interval} for c in self._clients]

    def _count_sent(self, c, count, t_ready):
        c.n_sent += count
        self.n_sent += count
        if t_ready is not None:
            self._latency.extend([time.perf_counter() - t_ready] * count)

    # ------------------------------------------------------------------ sending
    def send_pose(self, pose, *, timestamp: float | None = None,
                  t_ready: float | None = None, device_name: str | None = None) -> bool:
        """Queue one pose (metres) as a TRANSFORM in millimetres.

        Parameters
        ----------
        pose : ndarray, shape (4, 4)
            Sensor pose in the source frame, translation in metres.
        timestamp : float, optional
            Acquisition time (s since the epoch) written into the message.
        t_ready : float, optional
            ``time.perf_counter()`` when the pose's couplings were available; the server
            records the latency to the end of the socket send.
        device_name : str, optional
            Device name of the message (default: the server's ``device_name``).

        Returns
        -------
        bool
            False when no client is connected (nothing queued) or the server is closed.
        """
        P = np.asarray(pose, dtype=np.float64)
        if P.shape != (4, 4):
            raise InputError(f"expected `pose` of shape (4, 4), got {P.shape}")
        return self.send_poses(P[None], None if timestamp is None else [timestamp],
                               t_ready=t_ready, device_name=device_name)

    def send_poses(self, poses, timestamps=None, *, t_ready: float | None = None,
                   device_name: str | None = None, metadata: dict | None = None) -> bool:
        """Queue several poses (metres) as consecutive TRANSFORMs, written to each client's
        socket in one piece (one system call per client for a block of samples).

        Parameters
        ----------
        poses : ndarray, shape (N, 4, 4)
        timestamps : array of N floats, optional
            Acquisition times (s since the epoch).
        t_ready : float, optional
            See :meth:`send_pose`; the latency is recorded for each of the N poses.
        device_name : str or sequence of N str, optional
            See :meth:`send_pose`; a sequence names each message's device (the poses of
            several sensors in one call, written to each client in one piece).
        metadata : dict, optional
            OpenIGTLink version-2 metadata of each message: key -> N values (str, bytes
            arrays, or numbers written as ``format(x, ".3e")``), e.g.
            ``{"TransformStatus": [...], "QuadratureRatio": [...]}``; the messages then have
            header version 2 for the clients that read it (3D Slicer shows the metadata as
            attributes of the transform node), version 1 without metadata for the others.
            Without it, header version 1.
        """
        P = np.asarray(poses, dtype=np.float64)
        if P.ndim != 3 or P.shape[1:] != (4, 4):
            raise InputError(f"expected `poses` of shape (N, 4, 4), got {P.shape}")
        n = P.shape[0]
        if timestamps is not None:
            stamps = np.asarray(timestamps, dtype=np.float64)
            if stamps.shape != (n,):
                raise InputError(f"expected {n} timestamps, got {stamps.size}")
        if device_name is None or isinstance(device_name, str):
            name = self.device_name if device_name is None else _check_device_name(device_name)
            names = None
        else:                                    # one device name per message
            name = names = list(device_name)
            if len(names) != n:
                raise InputError(f"expected {n} device names, got {len(names)}")
            for d in set(names):
                _check_device_name(d)
        if n == 0:
            return False
        if not self._clients:                    # cheap exit before packing
            with self._lock:
                self.n_no_client += n
            return False
        M = P * MM_SCALE                         # metres -> millimetres (Slicer convention)
        if timestamps is None:
            stamps = np.full(n, time.time())
        if packable(M, stamps):
            if names is None:
                data = pack_transforms(M, stamps, name, metadata)
            else:
                body, off = transform_bodies(M, metadata)
                data = frame_messages(body, off, "TRANSFORM", names, stamps,
                                      header_version=1 if metadata is None else 2)
        else:                                    # unusual values: pyigtl's own checks
            keys, cols = (None, None) if metadata is None else _metadata_columns(metadata,
                                                                                   len(M))
            msgs = []
            for i, (m, t) in enumerate(zip(M, stamps)):
                msg = pyigtl.TransformMessage(m, timestamp=t,
                                              device_name=name if names is None else names[i])
                if keys is not None:
                    msg.header_version = 2
                    msg.metadata = {k.decode(): c[i].decode() for k, c in zip(keys, cols)}
                msgs.append(msg.pack())
            data = b"".join(msgs)
        return self._enqueue(_Block(data, len(P), t_ready, stream=True,
                                    version=1 if metadata is None else 2,
                                    poses=(M, stamps, name)))

    def send_message(self, message, t_ready: float | None = None, *, retain=None) -> bool:
        """Queue any pyigtl message (e.g. a ``StringMessage`` with the tracking status); a
        version-2 message reaches a version-1 client without its metadata.

        ``retain`` (a key, e.g. the message's device name): the message is also kept as that
        key's current one, and a client that connects later receives every kept message
        first -- a viewer that joins a running stream learns each sensor's state at once, not
        at its next change."""
        block = _Block(message.pack(), 1, t_ready, stream=False,
                       version=2 if getattr(message, "header_version", 1) >= 2 else 1)
        if retain is not None:
            with self._lock:            # kept and sent under one lock: a client gets it once
                self._retained[retain] = block
                return self._enqueue(block)
        return self._enqueue(block)

    def send_packed(self, data: bytes, count: int = 1, t_ready: float | None = None) -> bool:
        """Queue ``count`` tracking-data messages already packed into ``data`` (e.g. TDATA
        messages from :func:`openemt.live._tdata.pack_tdata`), written to each client in one
        piece."""
        if not self._clients:
            with self._lock:
                self.n_no_client += count
            return False
        data = bytes(data)
        return self._enqueue(_Block(data, int(count), t_ready, stream=True,
                                    version=2 if data[:2] == b"\0\2" else 1))

    def _enqueue(self, block: _Block) -> bool:
        wake = False
        count, t_ready = block.count, block.t_ready
        with self._lock:                # re-entrant: send_message(retain=) holds it already
            if self._closed:
                return False
            if not self._clients:
                self.n_no_client += count
                return False
            for c in self._clients:
                if block.stream and c.special:
                    wake |= self._offer(c, block)
                    continue
                self.n_queued += count
                data = block.data if c.version >= block.version else block.encoded(c.version)
                if not c.queue:
                    # fast path: nothing waiting -> non-blocking send right here (no thread
                    # hand-over); a client that cannot take it never blocks the others
                    try:
                        n = c.sock.send(data)
                    except OSError:                 # would block, or the client is gone
                        n = 0
                    if n == len(data):
                        self._count_sent(c, count, t_ready)
                        c.last_progress = time.monotonic()
                        continue
                    c.last_progress = time.monotonic()
                    wake = True
                    if n:                           # the rest must go out next, never skipped
                        c.queue.append((memoryview(data)[n:], count, t_ready))
                        c.partial = True
                        continue
                elif len(c.queue) >= self._max_queue:
                    # skip the oldest whole item (a partly sent head must be completed)
                    skip = 0
                    if not c.partial:
                        skip = c.queue.popleft()[1]
                    elif len(c.queue) > 1:
                        skip = c.queue[1][1]
                        del c.queue[1]
                    c.n_skipped += skip
                    self.n_skipped += skip
                c.queue.append((data, count, t_ready))
        if wake:
            self._wake()
        return True

    def _offer(self, c: _Client, block: _Block) -> bool:
        """Tracking data for a client with a rate or its own request (lock held): the newest
        message per device waits until the device is due; returns whether the I/O thread must
        look at the client."""
        if c.mode == "stopped":
            return False
        if c.mode == "tdata":
            device = c.tdata_device or self.device_name
            msgs = [(device.encode("ascii")[:20].ljust(20, b"\0"), m, k)
                    for m, k in block.tdata(device, c.interval > 0)]
        else:
            msgs = [(d, m, k) for d, (m, k) in block.newest(c.version).items()]
        if c.interval <= 0:                      # every message, queued as usual
            for _, m, k in msgs:
                if len(c.queue) >= self._max_queue and not c.partial:
                    skip = c.queue.popleft()[1]
                    c.n_skipped += skip
                    self.n_skipped += skip
                c.queue.append((m, k, block.t_ready))
                self.n_queued += k
            return bool(msgs)
        fresh = False                            # a device waits anew: the I/O thread must
        for dev, m, k in msgs:                   # time its release
            old = c.pending.get(dev)
            if old is not None:
                self.n_thinned += old[1]
            fresh |= old is None
            c.pending[dev] = (m, 1, block.t_ready)
            self.n_thinned += k - 1              # the older ones of this block
            self.n_queued += k
        return self._release(c, time.monotonic()) or fresh

    def _release(self, c: _Client, now: float) -> bool:
        """Move the due newest messages of ``c`` into its queue (lock held) once the queue is
        empty (what its socket has not taken yet goes first: no backlog builds up behind a
        slow reader) and send what the socket takes now; returns whether data still waits."""
        if not c.pending or c.queue:
            return bool(c.queue)
        due = [d for d in c.pending if c.due.get(d, 0.0) <= now]
        if not due:
            return False
        parts, count, t_ready = [], 0, None
        for d in due:
            m, k, t = c.pending.pop(d)
            # on a grid of the interval: a late release does not delay the next one (the
            # rate asked is kept on average), a device idle for longer starts a new grid
            last = c.due.get(d, 0.0)
            c.due[d] = last + c.interval if now - last < c.interval else now + c.interval
            parts.append(m)
            count += k
            t_ready = t if t_ready is None or (t is not None and t < t_ready) else t_ready
        c.queue.append((b"".join(parts), count, t_ready))
        try:
            self._flush(c)
        except OSError:
            pass
        return bool(c.queue)

    def _wake(self):
        try:
            self._wake_w.send(b"\0")
        except OSError:                             # full: the I/O thread is awake anyway
            pass

    def wait_for_client(self, timeout: float, count: int = 1,
                        header_version: int | None = None) -> bool:
        """Block until at least ``count`` clients are connected (with ``header_version``: that
        many are sent at least that header version) or ``timeout`` seconds pass."""
        end = time.monotonic() + float(timeout)

        def ready():
            if header_version is None:
                return len(self._clients) >= count
            return sum(c.version >= header_version for c in list(self._clients)) >= count

        while not ready() and time.monotonic() < end:
            time.sleep(0.005)
        return ready()

    # ------------------------------------------------------------------ I/O thread
    def _flush(self, c: _Client) -> None:
        """Send what ``c``'s socket takes now (lock held; non-blocking)."""
        while c.queue:
            data, count, t_ready = c.queue[0]
            try:
                n = c.sock.send(data)
            except BlockingIOError:
                return
            if n:
                c.last_progress = time.monotonic()
            if n == len(data):
                c.queue.popleft()
                c.partial = False
                self._count_sent(c, count, t_ready)
            else:
                c.queue[0] = (memoryview(data)[n:], count, t_ready)
                c.partial = True
                return

    def _receive(self, c: _Client, data: bytes) -> None:
        """Parse what a client sent (I/O thread): a version-2 message raises the header
        version it is sent (``header_version="auto"``); STT_TDATA, STP_TDATA and GET_STATUS
        are answered; anything else is ignored. A body larger than 64 KiB is skipped unread
        and a message with a wrong CRC is ignored (``bad_crc``)."""
        if c.skip:
            n = min(c.skip, len(data))
            c.skip -= n
            data = data[n:]
        buf = c.inbuf
        buf += data
        replies = []
        while len(buf) >= 58:
            version, mtype, device, _s, _f, size, crc = _HEADER.unpack_from(buf)
            if size > _MAX_CLIENT_BODY:
                drop = min(len(buf), 58 + size)
                c.skip = 58 + size - drop
                del buf[:drop]
                continue
            if len(buf) < 58 + size:
                break
            body = bytes(buf[58:58 + size])
            del buf[:58 + size]
            if _crc64_small(body) != crc:
                with self._lock:
                    self.n_bad_crc += 1
                continue
            if version >= 2 and self.header_version == "auto" and c.version < 2:
                c.version = 2
                logger.info("OpenIGTLink client %s sent header version %d: sent version 2 "
                            "from now on", c.addr, version)
            if version >= 2 and size >= 12:            # the content of a version-2 body
                ext, mh, mb, _id = _EXT_HEADER.unpack_from(body)
                if 12 <= ext and ext + mh + mb <= size:
                    body = body[ext:size - mh - mb]
            mtype = mtype.rstrip(b"\0")
            device = device.rstrip(b"\0").decode("ascii", "replace")
            if mtype == b"STT_TDATA":
                res = struct.unpack_from(">i", body)[0] if len(body) >= 4 else 0
                with self._lock:
                    c.mode = "tdata"
                    c.tdata_device = device
                    c.interval = max(max(res, 0) / 1000.0,
                                     0.0 if self.rate is None else 1.0 / self.rate)
                    c.pending.clear()
                replies.append(("RTS_TDATA", device, b"\0"))
                logger.info("OpenIGTLink client %s: TDATA every %g s", c.addr, c.interval)
            elif mtype == b"STP_TDATA":
                with self._lock:
                    c.mode = "stopped"
                    c.pending.clear()
                replies.append(("RTS_TDATA", device, b"\0"))
            elif mtype == b"GET_STATUS":
                replies.append(("STATUS", device or self.device_name,
                                status_content(1, "openemt streaming")))
        if replies:
            with self._lock:
                for mtype, device, content in replies:
                    c.queue.append((pack_message(mtype, device or self.device_name, content,
                                                 header_version=c.version), 1, None))
                    self.n_queued += 1
                try:
                    self._flush(c)
                except OSError:
                    pass

    def _remove(self, c: _Client, why: str) -> None:
        with self._lock:
            if c in self._clients:
                self._clients.remove(c)
                lost = sum(item[1] for item in c.queue)
                c.n_skipped += lost
                self.n_skipped += lost
                c.queue.clear()
        try:
            self._sel.unregister(c.sock)
        except (KeyError, ValueError, OSError):
            pass
        try:
            c.sock.close()
        except OSError:  # pragma: no cover
            pass
        logger.info("OpenIGTLink client %s %s", c.addr, why)

    def _accept(self) -> None:
        while True:
            try:
                sock, addr = self._listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError:  # pragma: no cover - listener closed
                return
            if len(self._clients) >= self.max_clients:
                sock.close()
                with self._lock:
                    self.n_refused += 1
                if not self._refusing:                 # one line per burst, not per connect
                    self._refusing = True
                    logger.warning("OpenIGTLink: %d clients connected (the most served at "
                                   "once); refusing further connections", self.max_clients)
                continue
            self._refusing = False
            sock.setblocking(False)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            c = _Client(sock, addr, version=2 if self.header_version == 2 else 1,
                        interval=0.0 if self.rate is None else 1.0 / self.rate)
            with self._lock:
                for block in self._retained.values():  # the current states first
                    c.queue.append((block.encoded(c.version), 1, None))
                    self.n_queued += 1
                self._clients.append(c)
                self.n_connections += 1
                self.clients_max = max(self.clients_max, len(self._clients))
            self._sel.register(sock, selectors.EVENT_READ, c)
            logger.info("OpenIGTLink client %s connected", addr)

    def _io_loop(self) -> None:
        read, write = selectors.EVENT_READ, selectors.EVENT_READ | selectors.EVENT_WRITE
        watching_write: set = set()
        while not self._stop:
            with self._lock:
                clients = list(self._clients)
                want = {c for c in clients if c.queue}
            # sockets with data waiting are also watched for writability (changes only)
            for c in want ^ watching_write:
                try:
                    self._sel.modify(c.sock, write if c in want else read, c)
                except (KeyError, ValueError, OSError):
                    pass
            watching_write = want
            timeout = self.poll
            if any(c.pending for c in clients):        # wake when a held message is due
                with self._lock:
                    due = [min((c.due.get(d, 0.0) for d in c.pending), default=np.inf)
                           for c in clients if c.pending and not c.queue]
                if due:
                    timeout = min(timeout, max(0.0, min(due) - time.monotonic()))
            try:
                events = self._sel.select(timeout)
            except (OSError, ValueError):          # a socket closed under us: look again
                continue
            if self._stop:
                break
            r, w = set(), set()
            for key, mask in events:
                if key.fileobj is self._wake_r:
                    try:
                        while self._wake_r.recv(4096):
                            pass
                    except OSError:
                        pass
                elif key.fileobj is self._listener:
                    self._accept()
                else:
                    if mask & selectors.EVENT_READ:
                        r.add(key.fileobj)
                    if mask & selectors.EVENT_WRITE:
                        w.add(key.fileobj)
            now = time.monotonic()
            for c in clients:
                if c.sock in r:                    # a client message, or the client leaving
                    try:
                        got = c.sock.recv(65536)
                        gone = not got
                    except BlockingIOError:
                        got, gone = b"", False
                    except OSError:
                        got, gone = b"", True
                    if gone:
                        self._remove(c, "disconnected")
                        continue
                    if got:
                        self._receive(c, got)
                stalled = gone = False
                with self._lock:
                    if c.sock in w:
                        try:
                            self._flush(c)
                        except OSError:                # reset by the peer: it left
                            gone = True
                    if c.pending and not gone:
                        self._release(c, now)
                    # a client with a rate holds one message per device at most: never
                    # dropped for reading slowly
                    if (c.queue and not c.interval > 0
                            and now - c.last_progress > self.send_timeout):
                        stalled = True
                if gone:
                    self._remove(c, "disconnected")
                elif stalled:
                    with self._lock:
                        self.n_clients_dropped += 1
                    self._remove(c, f"dropped: no data taken for {self.send_timeout:g} s")

    # ------------------------------------------------------------------ lifetime
    def close(self) -> None:
        """Stop serving, disconnect the clients and join the I/O thread (idempotent)."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        self._stop = True
        self._wake()
        self._thread.join(timeout=5 * self.poll + 1.0)
        for c in list(self._clients):
            self._remove(c, "disconnected (server closing)")
        self._sel.close()
        for s in (self._listener, self._wake_r, self._wake_w):
            s.close()

    @property
    def closed(self) -> bool:
        return self._closed and not self._thread.is_alive()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
