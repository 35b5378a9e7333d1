"""OpenIGTLink output: a TRANSFORM server that 3D Slicer's OpenIGTLinkIF module connects to.

Poses are metres inside openemt; OpenIGTLink transforms for Slicer are in **millimetres**
(Slicer's convention), so :meth:`IgtlServer.send_poses` scales the translation by 1000 at this
edge and nowhere else. The message transports the 4x4 pose as float32 (about 1e-5 mm and
1e-7 rad of rounding at 200 mm). Messages are packed by pyigtl.

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
  waiting (``clients_dropped``); the others are not delayed by it at all;
- queues nothing while no client is connected, and shuts down within about ``poll`` seconds,
  leaving no thread behind.
"""

from __future__ import annotations

import collections
import functools
import logging
import selectors
import socket
import struct
import threading
import time

import numpy as np
import pyigtl
from numba import njit

from .._errors import InputError

__all__ = ["DEFAULT_IGTL_PORT", "IgtlServer", "frame_messages", "pack_transforms",
           "transform_bodies"]

#: The OpenIGTLink port 3D Slicer's client connector uses by default.
DEFAULT_IGTL_PORT = 18944

logger = logging.getLogger(__name__)


# An OpenIGTLink version-1 TRANSFORM message: a 58-byte header (version, type, device name,
# timestamp as seconds and 2^-32 fractions, body size, CRC-64 of the body) and a 48-byte body
# (the upper 3x4 of the matrix column by column, big-endian float32) -- the bytes pyigtl packs.
_MSG = 58 + 48


def _crc64_table() -> np.ndarray:
    """Table of the CRC-64 of OpenIGTLink (ECMA-182 polynomial, MSB first, no reflection)."""
    poly, top, mask = 0x42F0E1EBA9EA3693, 1 << 63, (1 << 64) - 1
    table = np.zeros(256, np.uint64)
    for i in range(256):
        c = i << 56
        for _ in range(8):
            c = ((c << 1) ^ poly) & mask if c & top else (c << 1) & mask
        table[i] = c
    return table


_CRC_TABLE = _crc64_table()


def _fraction_bases() -> np.ndarray:
    """The halving bases of OpenIGTLink's nanoseconds -> 2^-32 fraction conversion."""
    out, base = [], 1_000_000_000
    for _ in range(32):
        base = (base + 1) >> 1
        out.append(base)
    return np.array(out, dtype=np.int64)


_FRAC_BASES = _fraction_bases()


@njit(cache=True, inline="always")
def _put_stamp(out, o, sec, ns, bases):
    """The header's time stamp at ``out[o + 34:o + 42]``: seconds and 2^-32 fractions."""
    frac = np.uint64(0)
    for b in range(32):
        if ns >= bases[b]:
            frac |= np.uint64(1) << np.uint64(31 - b)
            ns -= bases[b]
    s = np.uint64(sec)
    for i in range(4):
        out[o + 34 + i] = (s >> np.uint64(8 * (3 - i))) & np.uint64(0xFF)
        out[o + 38 + i] = (frac >> np.uint64(8 * (3 - i))) & np.uint64(0xFF)


@njit(cache=True)
def _pack_kernel(M, sec, nanosec, device, table, bases, out):
    f = np.empty(12, np.float32)
    u = f.view(np.uint32)
    for k in range(M.shape[0]):
        o = k * 106
        out[o] = 0
        out[o + 1] = 1                                   # version 1
        name = "TRANSFORM"
        for i in range(12):
            out[o + 2 + i] = ord(name[i]) if i < 9 else 0
        for i in range(20):
            out[o + 14 + i] = device[i]
        _put_stamp(out, o, sec[k], nanosec[k], bases)
        for i in range(8):
            out[o + 42 + i] = 48 if i == 7 else 0          # body size
        for c in range(4):
            for r in range(3):
                f[3 * c + r] = M[k, r, c]
        crc = np.uint64(0)
        for i in range(12):
            w = u[i]
            for j in range(4):
                byte = (w >> np.uint32(8 * (3 - j))) & np.uint32(0xFF)
                out[o + 58 + 4 * i + j] = byte
                idx = ((crc >> np.uint64(56)) ^ np.uint64(byte)) & np.uint64(0xFF)
                crc = table[idx] ^ (crc << np.uint64(8))
        for i in range(8):
            out[o + 50 + i] = (crc >> np.uint64(8 * (7 - i))) & np.uint64(0xFF)


@njit(cache=True)
def _frame_kernel(body, offsets, version, tname, devices, sec, nanosec, table, bases, out):
    """Frame message bodies: message k is ``body[offsets[k]:offsets[k + 1]]`` behind a
    58-byte header (``version``, type ``tname``, device ``devices[k]`` or ``devices[0]``,
    time stamp, body size, CRC-64 of the body)."""
    o = 0
    for k in range(offsets.shape[0] - 1):
        b0, b1 = offsets[k], offsets[k + 1]
        out[o] = (version >> 8) & 0xFF
        out[o + 1] = version & 0xFF
        for i in range(12):
            out[o + 2 + i] = tname[i]
        d = k if devices.shape[0] > 1 else 0
        for i in range(20):
            out[o + 14 + i] = devices[d, i]
        _put_stamp(out, o, sec[k], nanosec[k], bases)
        size = np.uint64(b1 - b0)
        for i in range(8):
            out[o + 42 + i] = (size >> np.uint64(8 * (7 - i))) & np.uint64(0xFF)
        crc = np.uint64(0)
        for j in range(b1 - b0):
            byte = body[b0 + j]
            out[o + 58 + j] = byte
            idx = ((crc >> np.uint64(56)) ^ np.uint64(byte)) & np.uint64(0xFF)
            crc = table[idx] ^ (crc << np.uint64(8))
        for i in range(8):
            out[o + 50 + i] = (crc >> np.uint64(8 * (7 - i))) & np.uint64(0xFF)
        o += 58 + (b1 - b0)


@functools.lru_cache(maxsize=1024)
def _name_bytes(name: str, size: int) -> np.ndarray:
    out = np.zeros(size, np.uint8)
    raw = name.encode("ascii")[:size]
    out[:len(raw)] = np.frombuffer(raw, np.uint8)
    return out


def frame_messages(bodies, offsets, message_type: str, device_names, timestamps, *,
                   header_version: int = 1) -> bytes:
    """Put OpenIGTLink headers in front of N message bodies, byte for byte what pyigtl's
    ``pack`` writes (a compiled loop: header, time stamp, CRC-64 of each body).

    Parameters
    ----------
    bodies : bytes
        The N bodies one after the other (with a version-2 header: extended header, content,
        metadata).
    offsets : array of N + 1 ints
        Body k is ``bodies[offsets[k]:offsets[k + 1]]``.
    message_type : str
        E.g. ``"TRANSFORM"`` or ``"TDATA"`` (at most 12 ASCII characters).
    device_names : str or sequence of N str
        One device name (1-20 ASCII characters) for all messages, or one per message.
    timestamps : array of N floats
        Seconds since the epoch, in [0, 2**32).
    header_version : int
        1 (OpenIGTLink 1 and 2) or 2 (OpenIGTLink 3: extended header and metadata in the body).
    """
    off = np.asarray(offsets, dtype=np.int64)
    ts = np.asarray(timestamps, dtype=np.float64)
    if ts.shape != (off.size - 1,):
        raise InputError(f"expected {off.size - 1} timestamps, got {ts.shape}")
    if isinstance(device_names, str):
        dev = _name_bytes(device_names, 20)[None]
    else:
        names = list(device_names)
        dev = (np.frombuffer(b"".join([_name_bytes(n, 20).tobytes() for n in names]),
                             np.uint8).reshape(len(names), 20) if names
               else np.zeros((1, 20), np.uint8))
    sec = np.trunc(ts)
    body = np.frombuffer(bodies, np.uint8) if len(bodies) else np.zeros(1, np.uint8)
    out = np.empty(58 * ts.size + int(off[-1] - off[0]) if ts.size else 0, np.uint8)
    _frame_kernel(body, off - off[0], int(header_version), _name_bytes(message_type, 12), dev,
                  sec.astype(np.int64), ((ts - sec) * 1e9).astype(np.int64), _CRC_TABLE,
                  _FRAC_BASES, out)
    return out.tobytes()


_EXT_HEADER = struct.Struct(">HHII")          # extended header: size, metadata sizes, id
_META_ENTRY = struct.Struct(">HHI")           # metadata index: key size, encoding, value size
_ASCII = 3                                    # IANA US-ASCII, the encoding pyigtl writes


def _metadata_columns(metadata, n: int) -> tuple:
    """``metadata`` (key -> N values) as ASCII keys and, per key, N ASCII values; numbers are
    written as ``format(x, ".3e")``."""
    keys, cols = [], []
    for key, values in metadata.items():
        vals = values.tolist() if isinstance(values, np.ndarray) else list(values)
        if len(vals) != n:
            raise InputError(f"expected {n} values of metadata {key!r}, got {len(vals)}")
        keys.append(key.encode("ascii"))
        if isinstance(values, np.ndarray) and values.dtype.kind in "fiu":
            cols.append([b"%.3e" % v for v in vals])           # one kind: no test per value
        else:
            cols.append([(v if isinstance(v, str) else format(v, ".3e")).encode("ascii")
                         for v in vals])
    return keys, cols


@functools.lru_cache(maxsize=256)
def _v2_head(key_sizes: tuple, lens: tuple) -> tuple:
    """Extended header, metadata index and body size of a version-2 TRANSFORM whose metadata
    keys and values have these byte lengths."""
    index = struct.pack(">H", len(key_sizes)) + b"".join(
        _META_ENTRY.pack(k, _ASCII, v) for k, v in zip(key_sizes, lens))
    ext = _EXT_HEADER.pack(12, len(index), sum(key_sizes) + sum(lens), 0)
    return ext, index, 60 + len(index) + sum(key_sizes) + sum(lens)


#: Fewest messages whose version-2 bodies are built with array operations (measured: 1 message
#: 17 us as arrays, 8 us joined; about equal at 6).
_VECTOR_BODIES = 6


def transform_bodies(matrices, metadata=None) -> tuple:
    """TRANSFORM message bodies and their offsets (see :func:`frame_messages`): the 3x4 matrix
    as big-endian float32 column by column; with ``metadata`` (key -> one value per message,
    str or number) in the version-2 layout: extended header, matrix, metadata index, keys and
    values."""
    M = np.asarray(matrices, dtype=np.float64)
    n = len(M)
    content = np.ascontiguousarray(M[:, :3, :].transpose(0, 2, 1)).reshape(n, 12)
    content = content.astype(">f4").tobytes()
    if metadata is None:
        return content, 48 * np.arange(n + 1)
    keys, cols = _metadata_columns(metadata, n)
    key_sizes = tuple(len(k) for k in keys)

    lens0 = tuple(len(c[0]) for c in cols) if n else ()
    if n >= _VECTOR_BODIES and all(len(v) == w for c, w in zip(cols, lens0) for v in c):
        # the usual case of a block, every value of a key as long (e.g. all "OK"): one array
        # operation per part of the body instead of a loop over the messages (below a few
        # messages, the loop's byte joins cost less than the arrays: one sample per read)
        ext, index, size = _v2_head(key_sizes, lens0)
        body = np.empty((n, size), np.uint8)
        body[:, :12] = np.frombuffer(ext, np.uint8)
        body[:, 12:60] = np.frombuffer(content, np.uint8).reshape(n, 48)
        o = 60 + len(index)
        body[:, 60:o] = np.frombuffer(index, np.uint8)
        for k, c, w in zip(keys, cols, lens0):
            body[:, o:o + len(k)] = np.frombuffer(k, np.uint8)
            o += len(k)
            body[:, o:o + w] = np.frombuffer(b"".join(c), np.uint8).reshape(n, w)
            o += w
        return body.tobytes(), size * np.arange(n + 1)
    parts, offsets = [], [0]
    for i, vals in enumerate(zip(*cols)):
        h = _v2_head(key_sizes, tuple(map(len, vals)))
        parts += [h[0], content[48 * i:48 * i + 48], h[1]]
        for k, v in zip(keys, vals):
            parts += [k, v]
        offsets.append(offsets[-1] + h[2])
    return b"".join(parts), offsets


def pack_transforms(matrices, timestamps, device_name: str, metadata=None) -> bytes:
    """Pack N TRANSFORM messages at once, byte for byte what pyigtl's
    ``TransformMessage.pack`` gives, in a compiled loop (a block of poses costs about as much
    as one pyigtl message).

    Parameters
    ----------
    matrices : ndarray, shape (N, 4, 4)
        Transforms as sent (the caller scales metres to millimetres).
    timestamps : array of N floats
        Seconds since the epoch, in [0, 2**32).
    device_name : str
        1-20 ASCII characters.
    metadata : dict, optional
        OpenIGTLink version-2 metadata, key -> N values (str, or numbers written as
        ``format(x, ".3e")``): the messages then have header version 2 (as pyigtl's with
        ``header_version = 2`` and the same ``metadata`` dict); without it, version 1.
    """
    if metadata is not None:
        body, off = transform_bodies(matrices, metadata)
        return frame_messages(body, off, "TRANSFORM", device_name, timestamps,
                              header_version=2)
    M = np.ascontiguousarray(matrices, dtype=np.float64)
    ts = np.asarray(timestamps, dtype=np.float64)
    sec = np.trunc(ts)
    dev = _name_bytes(device_name, 20)
    out = np.empty(M.shape[0] * _MSG, np.uint8)
    _pack_kernel(M, sec.astype(np.int64), ((ts - sec) * 1e9).astype(np.int64), dev,
                 _CRC_TABLE, _FRAC_BASES, out)
    return out.tobytes()


def _check_device_name(name) -> str:
    if not isinstance(name, str) or not name or len(name) > 20 or not name.isascii():
        raise InputError(f"expected a `device_name` of 1-20 ASCII characters, got {name!r}")
    return name


class _Client:
    """One connected client: its non-blocking socket and its queue of unsent items."""

    __slots__ = ("addr", "last_progress", "n_sent", "n_skipped", "partial", "queue", "sock")

    def __init__(self, sock, addr):
        self.sock = sock
        self.addr = addr
        self.n_sent = 0
        self.n_skipped = 0
        self.queue: collections.deque = collections.deque()
        self.partial = False              # the head item is partly sent: it must go out next
        self.last_progress = time.monotonic()


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

    Examples
    --------
    >>> with IgtlServer(port=0, device_name="SensorToTracker") as srv:   # doctest: +SKIP
    ...     srv.send_pose(pose_in_metres)
    """

    def __init__(self, port: int = DEFAULT_IGTL_PORT, *, host: str = "127.0.0.1",
                 device_name: str = "openemt", max_queue: int = 16, send_timeout: float = 1.0,
                 poll: float = 0.02, max_clients: int = 64, backlog: int = 128):
        self.device_name = _check_device_name(device_name)
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
    def n_dropped(self) -> int:
        """Messages skipped for slow clients (alias of ``messages_skipped``)."""
        return self.n_skipped

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
        once because ``max_clients`` were connected)."""
        with self._lock:
            return {"queued": self.n_queued, "sent": self.n_sent, "dropped": self.n_skipped,
                    "messages_skipped": self.n_skipped, "no_client": self.n_no_client,
                    "connections": self.n_connections, "clients": len(self._clients),
                    "clients_max": self.clients_max,
                    "clients_dropped": self.n_clients_dropped,
                    "clients_refused": self.n_refused}

    def clients(self) -> list:
        """The connected clients now: ``address`` (host, port), ``sent`` and ``skipped``
        messages, ``waiting`` (items in its queue)."""
        with self._lock:
            return [{"address": c.addr, "sent": c.n_sent, "skipped": c.n_skipped,
                     "waiting": len(c.queue)} for c in self._clients]

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
            OpenIGTLink version-2 metadata of each message: key -> N values (str, or numbers
            written as ``format(x, ".3e")``), e.g. ``{"Status": [...], "Distortion": [...]}``;
            the messages then have header version 2 (3D Slicer shows the metadata as
            attributes of the transform node). Without it, header version 1.
        """
        P = np.asarray(poses, dtype=np.float64)
        if P.ndim != 3 or P.shape[1:] != (4, 4):
            raise InputError(f"expected `poses` of shape (N, 4, 4), got {P.shape}")
        ts = [None] * len(P) if timestamps is None else [float(t) for t in timestamps]
        if len(ts) != len(P):
            raise InputError(f"expected {len(P)} timestamps, got {len(ts)}")
        if device_name is None or isinstance(device_name, str):
            name = self.device_name if device_name is None else _check_device_name(device_name)
            names = None
        else:                                    # one device name per message
            name = names = list(device_name)
            if len(names) != len(P):
                raise InputError(f"expected {len(P)} device names, got {len(names)}")
            for d in set(names):
                _check_device_name(d)
        if len(P) == 0:
            return False
        if not self._clients:                    # cheap exit before packing
            with self._lock:
                self.n_no_client += len(P)
            return False
        M = P.copy()
        M[:, :3, 3] *= 1000.0                    # metres -> millimetres (Slicer convention)
        if timestamps is None:
            stamps = np.full(len(P), time.time())
        else:
            stamps = np.asarray(ts, dtype=np.float64)
        if np.all(np.isfinite(M)) and np.all(stamps >= 0) and np.all(stamps < 2.0 ** 32):
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
        return self._enqueue(data, len(P), t_ready)

    def send_message(self, message, t_ready: float | None = None, *, retain=None) -> bool:
        """Queue any pyigtl message (e.g. a ``StringMessage`` with the tracking status).

        ``retain`` (a key, e.g. the message's device name): the message is also kept as that
        key's current one, and a client that connects later receives every kept message
        first -- a viewer that joins a running stream learns each sensor's state at once, not
        at its next change."""
        data = message.pack()
        if retain is not None:
            with self._lock:            # kept and sent under one lock: a client gets it once
                self._retained[retain] = data
                return self._enqueue(data, 1, t_ready)
        return self._enqueue(data, 1, t_ready)

    def send_packed(self, data: bytes, count: int = 1, t_ready: float | None = None) -> bool:
        """Queue ``count`` messages already packed into ``data`` (e.g. TDATA messages from
        :func:`openemt.live._tdata.pack_tdata`), written to each client in one piece."""
        if not self._clients:
            with self._lock:
                self.n_no_client += count
            return False
        return self._enqueue(bytes(data), int(count), t_ready)

    def _enqueue(self, data: bytes, count: int, t_ready) -> bool:
        wake = False
        with self._lock:                # re-entrant: send_message(retain=) holds it already
            if self._closed:
                return False
            if not self._clients:
                self.n_no_client += count
                return False
            for c in self._clients:
                self.n_queued += count
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

    def _wake(self):
        try:
            self._wake_w.send(b"\0")
        except OSError:                             # full: the I/O thread is awake anyway
            pass

    def wait_for_client(self, timeout: float, count: int = 1) -> bool:
        """Block until at least ``count`` clients are connected or ``timeout`` seconds pass."""
        end = time.monotonic() + float(timeout)
        while len(self._clients) < count and time.monotonic() < end:
            time.sleep(0.005)
        return len(self._clients) >= count

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
            c = _Client(sock, addr)
            with self._lock:
                for data in self._retained.values():   # the current states first
                    c.queue.append((data, 1, None))
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
            try:
                events = self._sel.select(self.poll)
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
                if c.sock in r:                    # a client message (ignored) or leaving
                    try:
                        gone = not c.sock.recv(65536)
                    except BlockingIOError:
                        gone = False
                    except OSError:
                        gone = True
                    if gone:
                        self._remove(c, "disconnected")
                        continue
                stalled = gone = False
                with self._lock:
                    if c.sock in w:
                        try:
                            self._flush(c)
                        except OSError:                # reset by the peer: it left
                            gone = True
                    if c.queue and now - c.last_progress > self.send_timeout:
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
