"""Reference poses for ``openemt collect``: an OpenIGTLink client, a CSV table, and a simulated
robot or optical tracker served by a real OpenIGTLink server.

- :func:`parse_reference_url` reads ``igtl://HOST:PORT/DEVICE``;
- :class:`ReferenceClient` connects to an OpenIGTLink server (PLUS, 3D Slicer, a robot's
  bridge) and keeps **every** TRANSFORM of one device with its time stamp (pyigtl's own client
  keeps only the latest message per device), each checked (sizes, CRC, rotation, status, time
  stamp) and counted by reason when dropped; translations arrive in millimetres (the
  OpenIGTLink convention of Slicer and PLUS) and are kept in metres;
- :class:`DwellMotion` is a robot-like motion through the poses of
  :func:`openemt.simulate.simulate_reference` (hold, move with a minimum-jerk profile, hold);
- :class:`SimulatedReferenceServer` serves the reference poses of a :class:`DwellMotion`
  through :class:`pyigtl.OpenIGTLinkServer` on a local port, at its own rate, with a latency
  and a clock offset of its own.
"""

from __future__ import annotations

import signal
import socket
import threading
import time
from dataclasses import dataclass
from urllib.parse import urlsplit

import numpy as np
from scipy.spatial.transform import Rotation

from .._errors import InputError
from ..geometry import invert, pose_from_rt, pose_from_vector
from ._gate import Drops, TimeGate, rigid_rows

__all__ = [
    "DwellMotion",
    "ReferenceClient",
    "SimulatedReferenceServer",
    "parse_reference_url",
    "parse_transform_body",
    "simulated_motion",
]

_HEADER = 58


def parse_reference_url(url: str) -> tuple[str, int, str]:
    """``igtl://HOST:PORT/DEVICE`` -> ``(host, port, device)``."""
    bad = InputError(f"expected --reference as igtl://HOST:PORT/DEVICE (e.g. "
                     f"igtl://127.0.0.1:18944/RobotToBase), got {url!r}")
    try:
        u = urlsplit(str(url))
        port = u.port
    except ValueError:
        raise bad from None
    device = u.path.lstrip("/")
    if u.scheme != "igtl" or not u.hostname or port is None or not device or "/" in device \
            or len(device.encode()) > 20 or not device.isascii():
        raise bad
    return u.hostname, int(port), device


#: The largest body of a message of the reference device read into memory (a TRANSFORM with
#: metadata is a few hundred bytes); larger bodies of other messages are skipped unread up to
#: :data:`MAX_SKIP_BODY`, beyond which the stream is not taken for OpenIGTLink.
MAX_BODY = 1 << 16
MAX_SKIP_BODY = 1 << 26
_STATUS_OK = {"OK"}


def _crc64():
    import crcmod

    return crcmod.mkCrcFun(0x142F0E1EBA9EA3693, rev=False, initCrc=0, xorOut=0)


def parse_transform_body(version: int, body: bytes):
    """The matrix (4, 4, float64, translation as sent) and metadata of a TRANSFORM body, or
    ``(None, reason)`` when the body is not one: a version-1 body is 48 bytes; a version-2 body
    is a 12-byte extended header, 48 bytes of content, a metadata header and the metadata,
    every size checked against the body's."""
    import struct

    meta = {}
    if version == 1:
        if len(body) != 48:
            return None, "transform_body_size"
        content = body
    else:
        if len(body) < 12 + 48:
            return None, "transform_body_size"
        ext, mh, ms, _ = struct.unpack(">HHII", body[:12])
        if ext < 12 or ext + 48 + mh + ms != len(body):
            return None, "extended_header_sizes"
        content = body[ext:ext + 48]
        if mh:
            if mh < 2:
                return None, "metadata_sizes"
            (count,) = struct.unpack(">H", body[ext + 48:ext + 50])
            if 2 + 8 * count != mh:
                return None, "metadata_sizes"
            heads = [struct.unpack(">HHI", body[ext + 50 + 8 * i:ext + 58 + 8 * i])
                     for i in range(count)]
            if sum(k + v for k, _, v in heads) != ms:
                return None, "metadata_sizes"
            o = ext + 48 + mh
            for k, _, v in heads:
                key = body[o:o + k].decode("utf-8", "replace")
                meta[key] = body[o + k:o + k + v].decode("utf-8", "replace").strip("\0 ")
                o += k + v
        elif ms:
            return None, "metadata_sizes"
    v = np.frombuffer(content, dtype=">f4").astype(np.float64)
    M = np.eye(4)
    M[:3, :4] = v.reshape(4, 3).T
    return M, meta


class ReferenceClient:
    """An OpenIGTLink client that keeps every TRANSFORM of one device, checked.

    Each message's header is read (58 bytes), its body size bounded before anything is
    allocated (:data:`MAX_BODY` for the device's TRANSFORMs; other messages are skipped unread
    up to :data:`MAX_SKIP_BODY`), and its CRC-64 (ECMA-182, as the protocol states) checked. A
    TRANSFORM is kept when its body parses (:func:`parse_transform_body`), its metadata does
    not mark it invalid (``TransformStatus`` other than ``OK``, ``TransformValid`` false), its
    rotation block is a rotation (:func:`~openemt.collect.rigid_rows`, never projected) and its
    time stamp continues the stream (:class:`~openemt.collect.TimeGate`). Everything turned
    away is counted by reason in :attr:`drops`. Translations arrive in millimetres (the
    OpenIGTLink convention of Slicer and PLUS) and are kept in metres.

    Parameters
    ----------
    host, port : str, int
    device : str
        Device name of the reference transform (e.g. ``RobotToBase``); other devices and
        message types are counted (``n_other``) and skipped.
    connect_timeout : float
        Seconds to keep trying to connect before :attr:`error` says so.

    Attributes
    ----------
    closed : bool
        The server ended the connection (or it failed: :attr:`error`).
    n_messages : int
        Transforms of ``device`` kept.
    last_receipt : float or None
        Wall-clock time of the latest one.
    drops : Drops
    """

    def __init__(self, host: str, port: int, device: str, *, connect_timeout: float = 5.0):
        self.host, self.port, self.device = host, int(port), device
        self.connect_timeout = float(connect_timeout)
        self.closed = False
        self.connected = False
        self.error: str | None = None
        self.n_messages = 0
        self.n_other = 0
        self.last_receipt: float | None = None
        self.drops = Drops()
        self.gate = TimeGate(self.drops)
        self._lock = threading.Lock()
        self._t: list = []
        self._M: list = []
        self._r: list = []
        self._stop = False
        self._thread = threading.Thread(target=self._run, name="openemt-reference", daemon=True)
        self._thread.start()

    def _connect(self):
        end = time.monotonic() + self.connect_timeout
        while not self._stop:
            try:
                return socket.create_connection((self.host, self.port), timeout=0.5)
            except OSError as exc:
                if time.monotonic() > end:
                    self.error = (f"expected an OpenIGTLink server at {self.host}:{self.port}, "
                                  f"got {exc.strerror or exc} for {self.connect_timeout:g} s")
                    return None
                time.sleep(0.05)

    def _recv(self, sock, n, keep=True):
        buf, got = bytearray(), 0
        while got < n and not self._stop:
            try:
                part = sock.recv(min(n - got, 1 << 16))
            except TimeoutError:
                continue
            if not part:
                return None
            got += len(part)
            if keep:
                buf += part
        return bytes(buf) if got == n else None

    def _run(self):
        try:
            sock = self._connect()
            if sock is None:
                return
            try:
                sock.settimeout(0.2)
                self.connected = True
                self._read(sock)
            finally:
                sock.close()
        except Exception as exc:                # noqa: BLE001 - said once, never a traceback
            if not self._stop:
                self.error = f"reference stream {self.host}:{self.port} failed: {exc}"
        finally:
            self.closed = True

    def _read(self, sock):
        import struct

        crc64 = _crc64()
        while not self._stop:
            head = self._recv(sock, _HEADER)
            if head is None:
                return
            version, mtype, dev, sec, frac, size, crc = struct.unpack(">H12s20sIIQQ", head)
            mtype = mtype.rstrip(b"\0").decode("ascii", "replace")
            dev = dev.rstrip(b"\0").decode("ascii", "replace")
            if version not in (1, 2, 3):
                self.error = (f"expected OpenIGTLink header version 1, 2 or 3 from "
                              f"{self.host}:{self.port}, got {version}: not an OpenIGTLink "
                              f"stream, or out of step")
                return
            ours = mtype == "TRANSFORM" and dev == self.device
            if size > (MAX_BODY if ours else MAX_SKIP_BODY):
                self.error = (f"expected an OpenIGTLink {mtype or 'message'} body of at most "
                              f"{MAX_BODY if ours else MAX_SKIP_BODY} bytes from "
                              f"{self.host}:{self.port}, got a size of {size}")
                return
            body = self._recv(sock, size, keep=ours)
            if body is None:
                if not self._stop:
                    self.drops["truncated"] += 1
                return
            now = time.time()
            if not ours:
                self.n_other += 1
                continue
            if crc64(body) != crc:
                self.drops["crc"] += 1
                continue
            M, meta = parse_transform_body(version, body)
            if M is None:
                self.drops[meta] += 1
                continue
            status = meta.get("TransformStatus")
            if status is not None and status.upper() not in _STATUS_OK:
                self.drops["transform_status_" + "".join(
                    c for c in status.lower() if c.isalnum() or c == "_")[:20]] += 1
                continue
            if meta.get("TransformValid", "true").strip().lower() in ("false", "0", "no"):
                self.drops["transform_not_valid"] += 1
                continue
            M[:3, 3] *= 1e-3                       # OpenIGTLink mm -> m
            if not rigid_rows(M)[0]:
                self.drops["not_a_rotation" if np.all(np.isfinite(M)) else "not_finite"] += 1
                continue
            stamp = sec + frac / 2.0 ** 32 if (sec or frac) else now   # none: time of receipt
            if not self.gate.take(stamp):
                continue
            with self._lock:
                self._t.append(stamp)
                self._M.append(M)
                self._r.append(now)
                self.n_messages += 1
                self.last_receipt = now

    def take(self, *, receipts: bool = False):
        """The time stamps (s) and poses (m) received since the last call (and the wall-clock
        times of their receipt with ``receipts``)."""
        with self._lock:
            t, M, r = self._t, self._M, self._r
            self._t, self._M, self._r = [], [], []
        out = (np.array(t, dtype=np.float64),
               np.array(M, dtype=np.float64).reshape(len(M), 4, 4))
        return (*out, np.array(r, dtype=np.float64)) if receipts else out

    def close(self) -> None:
        self._stop = True
        self._thread.join(timeout=2.0)
        self.gate.finish()


def _min_jerk(u):
    u = np.clip(u, 0.0, 1.0)
    return u ** 3 * (10 - 15 * u + 6 * u ** 2)


@dataclass(frozen=True, eq=False)
class DwellMotion:
    """A robot-like motion: hold at each pose, move to the next, hold again.

    Attributes
    ----------
    poses : ndarray (K, 4, 4)
        Sensor poses in the source frame at the holds (m).
    reported : ndarray (K, 4, 4)
        What the reference reports at each hold (``Y^-1 P X`` with the reference's error of
        that pose).
    errors : ndarray (K, 4, 4)
        The reference's error of each hold, in its tool frame (``reported = true @ error``).
    X, Y : ndarray (4, 4)
        Reference tool -> sensor, reference frame -> source frame.
    hold_starts, hold_ends : ndarray (K,)
        Time (s, from the start of the motion) of each hold; the move to pose k+1 takes
        ``hold_starts[k+1] - hold_ends[k]``. After the last hold the motion stays there.
    kind : str
    noise_trans, noise_rot : float
        Stated noise of the reference (3-D RMS m, RMS angle rad).
    jitter_trans, jitter_rot : float
        Per-message noise of the stream (3-D RMS m, RMS angle rad).
    hemisphere : list
        Direction of the working volume's centre from the source.
    box : ndarray (2, 3)
        Working volume (m).
    """

    poses: np.ndarray
    reported: np.ndarray
    errors: np.ndarray
    X: np.ndarray
    Y: np.ndarray
    hold_starts: np.ndarray
    hold_ends: np.ndarray
    kind: str
    noise_trans: float
    noise_rot: float
    jitter_trans: float
    jitter_rot: float
    hemisphere: list
    box: np.ndarray

    def _segments(self, t):
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        k = np.clip(np.searchsorted(self.hold_starts, t, side="right") - 1, 0,
                    len(self.poses) - 1)
        nxt = np.minimum(k + 1, len(self.poses) - 1)
        move = np.maximum(self.hold_starts[nxt] - self.hold_ends[k], 1e-9)
        s = np.where(nxt > k, _min_jerk((t - self.hold_ends[k]) / move), 0.0)
        s = np.where(t < self.hold_starts[0], 0.0, s)
        return k, nxt, s

    def sensor_poses(self, t) -> np.ndarray:
        """True sensor poses (N, 4, 4) at times ``t`` (s)."""
        k, nxt, s = self._segments(t)
        P = self.poses
        pos = P[k, :3, 3] + s[:, None] * (P[nxt, :3, 3] - P[k, :3, 3])
        rel = Rotation.from_matrix(np.swapaxes(P[k, :3, :3], 1, 2) @ P[nxt, :3, :3]).as_rotvec()
        R = P[k, :3, :3] @ Rotation.from_rotvec(s[:, None] * rel).as_matrix()
        return pose_from_rt(R, pos)

    def reference_poses(self, t) -> np.ndarray:
        """What the reference reports at times ``t`` (no per-message noise): the pose of its
        tool ``Y^-1 P(t) X`` with the error of the hold the motion comes from."""
        k, _, _ = self._segments(t)
        return invert(self.Y) @ self.sensor_poses(t) @ self.X @ self.errors[k]

    def holds_within(self, t0: float, t1: float) -> int:
        """Holds that lie entirely within ``[t0, t1]``."""
        return int(np.sum((self.hold_starts >= t0) & (self.hold_ends <= t1)))


def simulated_motion(kind: str = "robot", n_poses: int = 100, *, spare: int = 0,
                     preset: str = "concentric", seed=0, hold=(0.8, 1.4), move: float = 0.6,
                     jitter: float = 0.2, noise_trans=None, noise_rot=None) -> DwellMotion:
    """A :class:`DwellMotion` through the poses of :func:`openemt.simulate.simulate_reference`.

    The first ``n_poses`` poses, X, Y and the reference's error at each pose are those of
    ``simulate_reference(preset, kind, n_poses, seed=seed)`` (the same draw as ``openemt
    simulate --reference KIND --n-poses N --seed S``); ``spare`` more poses follow (another
    draw), for holds that a collection drops. Hold times are uniform in ``hold`` (s, so that
    the motion is not periodic), each move takes ``move`` seconds with a minimum-jerk profile,
    and the stream adds a per-message noise of ``jitter`` times the stated noise.
    """
    from ..simulate import simulate_reference, working_volume

    if not 0 < hold[0] <= hold[1] or not move > 0:
        raise InputError(f"expected positive hold times (min <= max) and move time, got "
                         f"hold={hold!r}, move={move!r}")
    draws = [simulate_reference(preset, kind, n, noise_trans=noise_trans, noise_rot=noise_rot,
                                seed=s)
             for n, s in ((n_poses, seed), (spare, None if seed is None else int(seed) + 7919))
             if n > 0]
    ds = draws[0]
    P = np.concatenate([d.poses for d in draws])
    B = np.concatenate([d.extra["reference_poses"] for d in draws])
    Bt = np.concatenate([d.extra["reference_poses_true"] for d in draws])
    ref = ds.meta["reference"]
    rng = np.random.default_rng([0 if seed is None else int(seed), 20])
    h = rng.uniform(hold[0], hold[1], len(P))
    starts = np.concatenate([[0.0], np.cumsum(h[:-1] + move)])
    lo, hi, _ = working_volume(preset)
    return DwellMotion(poses=P, reported=B, errors=invert(Bt) @ B,
                       X=np.asarray(ds.meta["truth"]["X"]), Y=np.asarray(ds.meta["truth"]["Y"]),
                       hold_starts=starts, hold_ends=starts + h, kind=ref["kind"],
                       noise_trans=float(ref["noise_trans_m"]),
                       noise_rot=float(ref["noise_rot_rad"]),
                       jitter_trans=jitter * float(ref["noise_trans_m"]),
                       jitter_rot=jitter * float(ref["noise_rot_rad"]),
                       hemisphere=list(ref["hemisphere"]), box=np.array([lo, hi]))


class SimulatedReferenceServer:
    """Serve a :class:`DwellMotion`'s reference poses as OpenIGTLink TRANSFORMs (mm).

    A thread sends one message every ``1 / rate`` seconds of simulated time through a
    :class:`pyigtl.OpenIGTLinkServer` on 127.0.0.1 (``port=0``: a free port, see
    :attr:`port`). At simulated time ``tau = (time.time() - t0) * speed`` it sends the pose of
    time ``tau - latency`` (plus per-message noise), stamped with its own clock
    ``t0 + tau + clock_offset``: a pose of tracker time ``t`` carries the stamp
    ``t + latency + clock_offset``.

    Parameters
    ----------
    motion : DwellMotion
    t0 : float
        Wall-clock time (s since the epoch) at which the motion starts (the tracker's start).
    rate : float
        Messages per second of simulated time.
    latency, clock_offset : float
        Seconds.
    speed : float
        Simulated seconds per wall second.
    stop_after : float, optional
        Stop serving (close the connection) after this many simulated seconds.
    """

    def __init__(self, motion: DwellMotion, *, t0: float, rate: float = 250.0,
                 latency: float = 0.03, clock_offset: float = 0.25, speed: float = 1.0,
                 device: str = "RobotToBase", port: int = 0, seed=0,
                 stop_after: float | None = None):
        import pyigtl

        if not 0 < rate < 1e4 or not 0 < speed <= 100:
            raise InputError(f"expected a reference rate in (0, 10000) Hz and a speed in "
                             f"(0, 100], got {rate!r} and {speed!r}")
        self.motion, self.t0, self.rate = motion, float(t0), float(rate)
        self.latency, self.clock_offset, self.speed = float(latency), float(clock_offset), speed
        self.device, self.stop_after = device, stop_after
        self._rng = np.random.default_rng([0 if seed is None else int(seed), 21])
        # pyigtl's server installs SIGINT/SIGTERM handlers of its own; the caller's stay
        main = threading.current_thread() is threading.main_thread()
        saved = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)} if main \
            else {}
        try:
            self._server = pyigtl.OpenIGTLinkServer(port=int(port), local_server=True)
        except OSError as exc:
            raise OSError(f"expected a free TCP port for the simulated reference on "
                          f"127.0.0.1:{port}, got {exc.strerror or exc}") from None
        finally:
            for s, h in saved.items():
                signal.signal(s, h)
        self.port = int(self._server.server_address[1])
        self.n_sent = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="openemt-simref", daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        return f"igtl://127.0.0.1:{self.port}/{self.device}"

    @property
    def time_offset(self) -> float:
        """Reference clock minus tracker clock for the same pose (s)."""
        return self.latency + self.clock_offset

    def _run(self):
        import pyigtl

        m = self.motion
        period = 1.0 / (self.rate * self.speed)
        k = 0
        while not self._stop.is_set():
            due = self.t0 + k * period
            delay = due - time.time()
            if delay > 0:
                self._stop.wait(delay)
                continue
            tau = (time.time() - self.t0) * self.speed
            if self.stop_after is not None and tau > self.stop_after:
                break
            B = m.reference_poses([tau - self.latency])[0]
            v = np.concatenate([m.jitter_trans / np.sqrt(3) * self._rng.standard_normal(3),
                                m.jitter_rot / np.sqrt(3) * self._rng.standard_normal(3)])
            B = B @ pose_from_vector(v)
            B[:3, 3] *= 1e3                                   # m -> OpenIGTLink mm
            msg = pyigtl.TransformMessage(B, timestamp=self.t0 + tau + self.clock_offset,
                                          device_name=self.device)
            if self._server.is_connected():
                self._server.send_message(msg, wait=False)
                self.n_sent += 1
            k = max(k + 1, int((time.time() - self.t0) / period))
        self._close()

    def _close(self):
        if not getattr(self, "_closed", False):
            self._closed = True
            self._server.stop()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._close()
