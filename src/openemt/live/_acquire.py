"""Framed ADC streams: a microcontroller on a serial port (``serial:PORT``) or a network ADC
(``tcp://HOST:PORT``) sending the frames of :mod:`openemt.live._framing`.

:class:`FramedBackend` turns frames into raw-sample chunks for the pipeline. Its sample clock
is the frames' sample counter: a frame that does not continue the previous one starts a new
contiguous run, and the pipeline restarts its demodulator there (the samples of a gap are
never stitched as if continuous). Counted in :meth:`FramedBackend.link_stats`: accepted
frames, CRC errors, bad headers, skipped bytes, gaps (a counter jump forward: lost frames) and
the samples they lost, restarts (the counter went back, or a frame flagged as the emitter's
first) and reconnections. Session time follows the counter (a gap advances it by the lost
samples); after a restart the new counter is placed on the session's time axis from the host
arrival times. The UTC of every sample comes from :class:`~openemt.live._clock.SampleClock`.

:func:`probe_serial` says in one line why a serial port cannot be opened (missing, busy, no
permission and which group to join); ``openemt devices`` and the serial backend use it.
"""

from __future__ import annotations

import errno
import os
import select
import socket
import time

import numpy as np

from .._errors import InputError
from ._backends import Backend
from ._clock import SampleClock
from ._framing import FLAG_START, FrameDecoder

__all__ = ["DEFAULT_BAUD", "FramedBackend", "SerialBackend", "TcpBackend", "list_serial_ports",
           "parse_source", "probe_serial", "probe_tcp"]

#: Baud rate set on a serial port (a USB CDC device ignores it).
DEFAULT_BAUD = 921600


def parse_source(source: str, *, listen: bool = False) -> tuple:
    """``("sim"|"replay"|"sound", None)``, ``("serial", (port, baud))`` or
    ``("tcp", (host, port))`` of a ``--source`` value; InputError naming the forms otherwise.
    ``listen``: a TCP address to listen on (port 0: any free port)."""
    forms = ("expected --source sim, replay, sound, serial:PORT[@BAUD] (e.g. "
             "serial:/dev/ttyACM0) or tcp://HOST:PORT")
    if source in ("sim", "replay", "sound"):
        return source, None
    if isinstance(source, str) and source.startswith("serial:"):
        rest = source[len("serial:"):]
        port, baud = rest, DEFAULT_BAUD
        if "@" in rest:
            port, b = rest.rsplit("@", 1)
            if not b.isdigit() or not 0 < int(b) <= 50_000_000:
                raise InputError(f"{forms}, got a baud rate {b!r} in {source!r}")
            baud = int(b)
        if not port:
            raise InputError(f"{forms}, got no port in {source!r}")
        return "serial", (port, baud)
    if isinstance(source, str) and source.startswith("tcp://"):
        rest = source[len("tcp://"):]
        host, sep, port = rest.rpartition(":")
        host = host.strip("[]")
        if not sep or not host or not port.isdigit() or not (
                0 if listen else 1) <= int(port) <= 65535:
            raise InputError(f"{forms}, got {source!r} (host and port 1..65535 needed)")
        return "tcp", (host, int(port))
    raise InputError(f"{forms}, got {source!r}")


# ------------------------------------------------------------------ serial port diagnosis

def _group_of(path) -> str:
    import grp

    try:
        gid = os.stat(path).st_gid
        return grp.getgrgid(gid).gr_name
    except (OSError, KeyError):
        return "the device's group"


def explain_serial_error(path, exc) -> str:
    """One line saying why ``path`` could not be opened, from the error ``exc``."""
    code = getattr(exc, "errno", None)
    text = str(exc)
    if code is None and exc.__cause__ is not None:
        code = getattr(exc.__cause__, "errno", None)
    if code is None:
        for c in (errno.ENOENT, errno.EACCES, errno.EBUSY, errno.ENXIO, errno.EIO):
            if f"[Errno {c}]" in text:
                code = c
                break
    if code == errno.ENOENT or (code is None and not os.path.exists(path)):
        return f"missing: no device at {path} (unplugged, or another name: openemt devices)"
    if code in (errno.EACCES, errno.EPERM):
        g = _group_of(path)
        return (f"no permission to open {path}: join its group '{g}' (sudo usermod -aG {g} "
                f"$USER, then log in again)")
    if code == errno.EBUSY or "exclusively lock" in text or "busy" in text.lower():
        return f"busy: {path} is open in another program (close it, e.g. a serial monitor)"
    if code in (errno.ENXIO, errno.ENODEV, errno.EIO):
        return f"not working: {path} exists but no device answers ({os.strerror(code)})"
    return f"cannot open {path}: {' '.join(text.split())}"


def _open_serial(path, baud: int):
    import serial

    s = serial.Serial(port=None, baudrate=baud, timeout=0, exclusive=True)
    s.port = path
    s.open()
    if hasattr(s, "fd"):                # POSIX: fully raw, whatever the port's defaults
        import termios
        import tty

        try:
            tty.setraw(s.fd, termios.TCSANOW)
        except termios.error:
            pass
    return s


def probe_serial(path, baud: int = DEFAULT_BAUD) -> tuple:
    """``(True, "opens")`` when ``path`` opens (it is closed again at once), else ``(False,
    reason)`` with the one-line reason of :func:`explain_serial_error`."""
    try:
        s = _open_serial(path, baud)
    except (OSError, ValueError) as exc:          # serial.SerialException is an OSError
        return False, explain_serial_error(path, exc)
    s.close()
    return True, "opens"


def list_serial_ports() -> list:
    """The serial ports pyserial sees: dicts with ``port``, ``description``, ``vid_pid``
    (``"16c0:0483"`` or None), ``serial_number``, ``manufacturer``, and ``opens`` /
    ``reason`` from :func:`probe_serial`."""
    from serial.tools import list_ports

    out = []
    for p in sorted(list_ports.comports(), key=lambda p: p.device):
        ok, why = probe_serial(p.device)
        out.append({"port": p.device, "description": p.description,
                    "vid_pid": (f"{p.vid:04x}:{p.pid:04x}" if p.vid is not None else None),
                    "serial_number": p.serial_number, "manufacturer": p.manufacturer,
                    "opens": ok, "reason": why})
    return out


def probe_tcp(host: str, port: int, timeout: float = 1.0) -> tuple:
    """``(True, "accepts connections")`` or ``(False, reason)`` for an emitter at
    ``host:port`` (connected and closed again at once)."""
    try:
        with socket.create_connection((host, port), timeout=timeout):
            return True, "accepts connections"
    except ConnectionRefusedError:
        return False, f"refused: nothing listens on {host}:{port} (emitter not started?)"
    except TimeoutError:
        return False, f"no answer from {host}:{port} in {timeout:g} s (address, cable, firewall?)"
    except OSError as exc:
        return False, f"cannot reach {host}:{port}: {exc.strerror or exc}"


# ------------------------------------------------------------------------- the backends

class _Run:
    """Decoded samples of one contiguous run of frames, waiting to be read."""

    __slots__ = ("parts", "n", "start", "restart")

    def __init__(self, start: int, restart: bool):
        self.parts, self.n, self.start, self.restart = [], 0, start, restart


class FramedBackend(Backend):
    """Raw samples from a byte stream of frames. Subclasses give ``_open(timeout)`` (the link:
    a port or socket; OSError or ValueError when it cannot be opened) and
    ``_read_link(timeout)`` (the bytes it gives within ``timeout`` s; :meth:`_drop` when it
    went away); a link that went away is opened again every 0.2 s.

    ``read`` returns the samples of one contiguous run, at least ``chunk`` of them when they
    arrive within ``timeout`` (else what arrived, possibly none: a live stream has no end);
    after a read, :meth:`pop_restart` gives the session time of a run that does not continue
    the previous one (the pipeline restarts its demodulator there).

    Parameters
    ----------
    layout : ChannelLayout
    n_channels : int
        Channels per frame (the tracker's ``adc.channels``).
    chunk : int
        Samples per read (640 = 6.7 ms at 96 kS/s).
    timeout : float
        Seconds a read waits.
    truth : callable, optional
        ``truth(times) -> poses`` at the sample counter's times (s), when the emitter's truth
        is known (tests and benches of a simulated emitter).
    drain : bool
        Throw away the bytes waiting before the first read (default; False: keep them, for an
        emitter that starts after the port is open).
    """

    discontinuous = True
    realtime = True

    def __init__(self, layout, n_channels: int | None = None, *, chunk: int = 640,
                 timeout: float = 0.1, truth=None, drain: bool = True):
        self.layout = layout
        self.n_channels = layout.n_channels if n_channels is None else int(n_channels)
        self.chunk = int(chunk)
        if self.chunk < 1:
            raise InputError(f"expected `chunk` >= 1, got {chunk!r}")
        self.timeout = float(timeout)
        self.fs = float(layout.sample_rate)
        self.decoder = FrameDecoder(self.n_channels, self.fs)
        self.clock = SampleClock(self.fs)
        self._truth = truth
        self._runs: list = []
        self._next = None           # expected counter of the next frame
        self._offset = 0            # session sample index = counter + offset
        self._end = 0               # session index after the last accepted frame
        self._last_arrival = None
        self._restart_at = None
        self.gaps = 0
        self.samples_lost = 0
        self.restarts = 0
        self.reconnects = 0
        self.samples = 0
        self.stale_bytes = None if drain else 0
        self._last_utc = self._last_time = None

    # subclasses
    _link = None                    # the open port or socket; None while it is gone
    _retry = 0.0                    # time.monotonic() of the next try to open it again

    def _recv(self, timeout: float) -> bytes:
        if self._link is not None:
            return self._read_link(timeout)
        now = time.monotonic()                         # gone: try again now and then
        if now >= self._retry:
            self._retry = now + 0.2
            try:
                self._link = self._open(0.2)
                self.reconnects += 1
                return b""
            except (OSError, ValueError):
                pass
        time.sleep(min(timeout, 0.05))
        return b""

    def _drop(self) -> None:
        """The link went away: close it and forget the bytes of a torn frame."""
        try:
            self._link.close()
        except OSError:  # pragma: no cover
            pass
        self._link = None
        self.decoder.drop_buffer()

    def close(self) -> None:
        if self._link is not None:
            self._link.close()
            self._link = None

    @property
    def t0_epoch(self) -> float:
        return self.clock.a if self.clock.a is not None else time.time()

    def epoch_times(self, times):
        """UTC of session ``times`` (one chunk after the other, in order) from the clock fit,
        never decreasing: when a refit moves the line back, the stamps advance at 0.1 % of
        the sample clock until the fit catches up (less than one output period for a step
        back of up to 0.6 ms)."""
        times = np.asarray(times, dtype=np.float64)
        t = (np.full(times.shape, time.time()) if self.clock.a is None
             else self.clock.utc(times))
        if len(t):
            if self._last_utc is not None:
                t = np.maximum(t, self._last_utc + 1e-3 * (times - self._last_time) + 1e-9)
            self._last_utc, self._last_time = float(t[-1]), float(times[-1])
        return t

    def truth_poses(self, times):
        """``truth(counter times)``: the given truth at the sample counter's time (s) of
        session ``times`` (valid until the device restarts)."""
        if self._truth is None:
            return None
        return self._truth(self.counter_times(times))

    def counter_times(self, times):
        """The sample counter's time (counter / sample clock, s) of session ``times``: the
        device's own time axis (valid back to its last restart)."""
        return np.asarray(times, dtype=np.float64) - self._offset / self.fs

    def pop_restart(self):
        r, self._restart_at = self._restart_at, None
        return r

    def link_stats(self) -> dict:
        d = self.decoder
        return {"frames": d.frames, "crc_errors": d.crc_errors, "bad_headers": d.bad_headers,
                "bytes_skipped": d.bytes_skipped, "bytes_read": d.bytes_read,
                "gaps": self.gaps, "samples_lost": self.samples_lost,
                "restarts": self.restarts, "reconnects": self.reconnects,
                "samples": self.samples, "stale_bytes_at_start": self.stale_bytes,
                **self.clock.to_dict()}

    def _ingest(self, data: bytes, arrival: float) -> None:
        for counter, flags, x in self.decoder.feed(data):
            n = x.shape[0]
            new = False
            if self._next is None:                       # the first frame: session index 0
                self._offset = -counter
            elif counter == self._next and not flags & FLAG_START:
                pass
            elif counter > self._next and not flags & FLAG_START:
                self.gaps += 1                           # lost frames: time goes on
                self.samples_lost += counter - self._next
                new = True
            else:                                        # the emitter restarted
                self.restarts += 1
                waited = 0 if self._last_arrival is None else arrival - self._last_arrival
                start = self._end + max(0, round(waited * self.fs) - n)
                self._offset = start - counter
                self.clock.reset()
                new = True
            s0 = counter + self._offset
            self._next = counter + n
            self._end = s0 + n
            self._last_arrival = arrival
            self.clock.add(self._end / self.fs, arrival)
            self.samples += n
            if new or not self._runs or self._runs[-1].start + self._runs[-1].n != s0:
                self._runs.append(_Run(s0, new))
            run = self._runs[-1]
            run.parts.append(x)
            run.n += n

    def _take(self, force: bool):
        runs = self._runs
        if not runs or not (len(runs) > 1 or runs[0].n >= self.chunk or (force and runs[0].n)):
            return None
        run = runs.pop(0)
        if run.restart:
            self._restart_at = run.start / self.fs
        return run.parts[0] if len(run.parts) == 1 else np.concatenate(run.parts)

    def _drain_stale(self) -> None:
        """Throw away what waited in the buffers before the first read (bytes sent while the
        session started are not live; a paced device dropped frames meanwhile anyway)."""
        n, end = 0, time.monotonic() + 0.02
        while time.monotonic() < end:
            data = self._recv(0.0)
            if not data:
                break
            n += len(data)
        self.stale_bytes = n

    def read(self):
        if self.stale_bytes is None:
            self._drain_stale()
        deadline = time.monotonic() + self.timeout
        while True:
            out = self._take(False)
            if out is not None:
                return out
            left = deadline - time.monotonic()
            if left <= 0:
                out = self._take(True)
                return np.empty((0, self.n_channels)) if out is None else out
            data = self._recv(left)
            if data:
                self._ingest(data, time.time())


class SerialBackend(FramedBackend):
    """Frames from a serial port (USB CDC ACM, a UART adapter, a pseudo-terminal) through
    pyserial, opened exclusively; reopened when the device goes away (unplugged and back)."""

    def __init__(self, port: str, layout, n_channels: int | None = None, *,
                 baud: int = DEFAULT_BAUD, **kw):
        super().__init__(layout, n_channels, **kw)
        self.port, self.baud = port, int(baud)
        self.source = f"serial:{port}" + ("" if self.baud == DEFAULT_BAUD else f"@{baud}")
        try:
            self._link = self._open(0.0)
        except (OSError, ValueError) as exc:
            raise InputError(f"expected a serial port openemt can open at {port}, got "
                             f"{explain_serial_error(port, exc)}") from None

    def _open(self, timeout: float):
        return _open_serial(self.port, self.baud)

    def _read_link(self, timeout: float) -> bytes:
        s = self._link
        try:
            if hasattr(s, "fd"):
                r, _, _ = select.select([s.fd], [], [], timeout)
                return os.read(s.fd, 1 << 16) if r else b""
            return s.read(s.in_waiting or 1)           # pragma: no cover - Windows
        except OSError:                                # EIO: the other end went away
            self._drop()
            return b""


class TcpBackend(FramedBackend):
    """Frames from a TCP server (a network ADC, or the reference emitter with ``--to
    tcp://...``): openemt connects as the client and connects again when the connection
    drops (the emitter restarted)."""

    def __init__(self, host: str, port: int, layout, n_channels: int | None = None, *,
                 connect_timeout: float = 2.0, **kw):
        super().__init__(layout, n_channels, **kw)
        self.host, self.port = host, int(port)
        self.source = f"tcp://{host}:{self.port}"
        try:
            self._link = self._open(connect_timeout)
        except OSError:
            ok, why = probe_tcp(host, port, connect_timeout)
            raise InputError(f"expected an ADC frame stream at tcp://{host}:{port}, got "
                             f"{why}") from None

    def _open(self, timeout: float):
        s = socket.create_connection((self.host, self.port), timeout=timeout)
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        s.setblocking(False)
        return s

    def _read_link(self, timeout: float) -> bytes:
        s = self._link
        r, _, _ = select.select([s], [], [], timeout)
        if not r:
            return b""
        try:
            data = s.recv(1 << 16)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError:
            data = b""
        if not data:                                   # closed by the emitter
            self._drop()
        return data
