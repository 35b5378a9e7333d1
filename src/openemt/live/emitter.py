"""Reference emitter of the ADC framing: what a microcontroller's firmware sends, from the
simulator's raw signal (docs/live.md#adc-framing).

Run it as a program::

    python -m openemt.live.emitter --to pty                      # prints the port to open
    python -m openemt.live.emitter --to tcp://127.0.0.1:5000     # one client at a time
    python -m openemt.live.emitter --to serial:/dev/ttyUSB0      # a real port (pyserial)

and track it with ``openemt track --source serial:PORT`` or ``--source tcp://HOST:PORT``.
It paces the frames at the sample clock (``--fast``: as fast as the reader takes them) and can
damage the stream on purpose: ``--flip-every K`` flips one bit in every K-th frame,
``--drop-every K`` drops a few bytes of every K-th frame, ``--skip-every K`` leaves out every
K-th frame (a counter gap) and ``--restart-after S`` restarts the counter after S seconds
(as a reset microcontroller would). A firmware does per frame exactly what
:meth:`Emitter.frame` does: one ``struct.pack`` of the header, the samples as little-endian
integers, and a CRC-32 of everything after the sync word.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

from .._errors import InputError
from ._framing import FLAG_START, FORMATS, format_code, pack_frame

__all__ = ["Emitter", "EmitterThread", "fd_writer", "main", "open_pty"]


class Emitter:
    """Frames of the simulated tracker's raw samples.

    Parameters
    ----------
    tracker : TrackerSpec, optional
        The tracker whose ADC is emulated (default: the simulated one-sensor tracker of
        ``openemt track`` without ``--tracker``: the same samples as ``--source sim``).
    frame_samples : int
        Samples per channel and frame (64 = 0.67 ms at 96 kS/s).
    fmt : {"int32", "int16", "float32"}
    full_scale : float
        Volts of the largest count (integer formats).
    realtime : bool
        Pace frames at the sample clock (the sample clock runs ``clock_ppm`` slow).
    flip_every, drop_every, skip_every : int
        Damage every K-th frame (0 = never): one bit flipped, 1-8 bytes dropped, or the whole
        frame left out. The damaged frames are counted in :attr:`damaged`.
    restart_after : float, optional
        Seconds of signal after which the counter starts again at 0 (once).
    seed : int
        Simulation (and damage) seed.
    """

    def __init__(self, tracker=None, *, frame_samples: int = 64, fmt: str = "int32",
                 full_scale: float = 10.0, realtime: bool = True, clock_ppm: float = 0.0,
                 flip_every: int = 0, drop_every: int = 0, skip_every: int = 0,
                 restart_after: float | None = None, seed: int = 0,
                 duration: float | None = None, noise: float | None = None):
        from ._session import tracker_backend

        if tracker is None:                 # the tracker of `openemt track` without a file
            from ._session import TrackOptions, default_tracker

            tracker = default_tracker(TrackOptions())
        self.spec = tracker
        self.n = int(frame_samples)
        if not 1 <= self.n <= 4096:
            raise InputError(f"expected 1..4096 samples per frame, got {frame_samples}")
        self.code = format_code(fmt)
        self.dtype = FORMATS[self.code][0]
        self.scale = 1.0 if self.code == 3 else float(full_scale) / (
            np.iinfo(np.dtype(self.dtype)).max)
        self.fs = float(tracker.sample_rate)
        self.rate_true = self.fs * (1.0 - 1e-6 * float(clock_ppm))   # a slow clock: ppm > 0
        self.realtime = bool(realtime)
        self.flip_every, self.drop_every = int(flip_every), int(drop_every)
        self.skip_every = int(skip_every)
        self.restart_after = restart_after
        self._rng = np.random.default_rng(seed + 1)
        self.sim = tracker_backend(tracker, "sim", realtime=False, duration=duration,
                                   seed=seed, chunk=self.n, noise_rms=noise)
        self.n_channels = tracker.n_channels
        self.counter = 0               # the ADC's sample counter (restarts)
        self.index = 0                 # samples simulated so far (never restarts)
        self.flags = FLAG_START
        self.frames = self.damaged = self.skipped = self.restarts = self.overruns = 0
        self.t0_epoch = None           # UTC of sample index 0 (set when run starts)

    def truth_poses(self, times):
        """True poses at simulation times (s from the first sample, never restarting)."""
        return self.sim.truth_poses(times)

    def sample_utc(self, index):
        """The true UTC of simulated sample ``index`` (paced runs)."""
        return self.t0_epoch + np.asarray(index, dtype=np.float64) / self.rate_true

    def frame(self, samples, counter: int, flags: int) -> bytes:
        """The bytes of one frame, as a firmware packs them (:func:`~._framing.pack_frame` of
        the samples in counts, or in volts for float32)."""
        if self.code != 3:
            info = np.iinfo(np.dtype(self.dtype))
            samples = np.clip(np.rint(samples / self.scale), info.min, info.max)
        return pack_frame(samples, counter, self.fs, fmt=self.code, scale=self.scale,
                          flags=flags)

    def frames_iter(self):
        """Every frame's bytes (damaged as configured; ``b""`` for a frame left out), in
        order."""
        while True:
            x = self.sim.read()
            if x is None:
                return
            x = x[:, :self.n_channels] if x.shape[1] > self.n_channels else x
            if (self.restart_after is not None and not self.restarts
                    and self.index >= self.restart_after * self.fs):
                self.restarts += 1
                self.counter, self.flags = 0, FLAG_START
            n = x.shape[0]
            k = self.frames + 1
            self.frames += 1
            data = self.frame(x, self.counter, self.flags)
            self.counter += n
            self.index += n
            self.flags = 0
            if self.skip_every and k % self.skip_every == 0:
                self.skipped += 1
                yield b""
                continue
            if self.flip_every and k % self.flip_every == 0:
                b = bytearray(data)
                bit = int(self._rng.integers(len(b) * 8))
                b[bit // 8] ^= 1 << (bit % 8)
                data = bytes(b)
                self.damaged += 1
            if self.drop_every and k % self.drop_every == 0:
                at = int(self._rng.integers(len(data)))
                data = data[:at] + data[at + int(self._rng.integers(1, 9)):]
                self.damaged += 1
            yield data

    def run(self, write, *, stop=None, max_lag: float = 0.05) -> dict:
        """Write every frame with ``write(bytes)`` (paced when ``realtime``) until the end of
        the signal or ``stop()``; the counts.

        Paced, it behaves as an ADC does: sampling never waits, so a frame more than
        ``max_lag`` seconds late (the reader stopped reading and the write blocked) is
        dropped, counted in ``overruns``, and the counter goes on (the reader sees a gap)."""
        t0 = time.perf_counter()
        self.t0_epoch = time.time()
        try:
            for data in self.frames_iter():
                if stop is not None and stop():
                    break
                if self.realtime:
                    delay = t0 + self.index / self.rate_true - time.perf_counter()
                    if delay > 0:
                        time.sleep(delay)
                    elif delay < -max_lag:
                        self.overruns += 1
                        continue
                if data:
                    write(data)
        except KeyboardInterrupt:
            pass
        return self.stats()

    def stats(self) -> dict:
        return {"frames": self.frames, "samples": self.index, "damaged": self.damaged,
                "skipped": self.skipped, "restarts": self.restarts, "overruns": self.overruns,
                "sample_rate": self.fs, "format": FORMATS[self.code][1],
                "t0_epoch": self.t0_epoch,
                "frame_samples": self.n}


def fd_writer(fd, stop=None):
    """``write(bytes)`` to a file descriptor (a pty master) that returns without writing all
    once ``stop()`` is true: a reader that stopped reading never leaves the emitter blocked."""
    import select

    os.set_blocking(fd, False)

    def write(data):
        view = memoryview(data)
        while view and not (stop is not None and stop()):
            try:
                view = view[os.write(fd, view):]
            except BlockingIOError:
                select.select([], [fd], [], 0.05)
    return write


class EmitterThread:
    """Emitters run one after the other on a background thread, writing to a pty master
    (``fd``) or, with ``fd=None``, serving each on its own TCP connection on
    ``127.0.0.1:port`` (:attr:`port`; an ADC board that restarts between them);
    ``with EmitterThread(...)`` starts it and, on leaving, stops it and waits for it."""

    def __init__(self, emitters, fd=None):
        import socket
        import threading

        self.emitters = list(emitters)
        self._stop = threading.Event()
        self.error = None
        self._srv = None
        if fd is None:
            self._srv = socket.create_server(("127.0.0.1", 0))
            self._srv.settimeout(0.1)
            self.port = self._srv.getsockname()[1]
        self._fd = fd
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self):
        import socket

        try:
            for em in self.emitters:
                if self._fd is not None:
                    em.run(fd_writer(self._fd, self._stop.is_set), stop=self._stop.is_set)
                    continue
                conn = None
                while conn is None and not self._stop.is_set():
                    try:
                        conn, _ = self._srv.accept()
                    except TimeoutError:
                        pass
                if conn is None:
                    return
                with conn:
                    conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                    try:
                        em.run(conn.sendall, stop=self._stop.is_set)
                    except (ConnectionError, BrokenPipeError):
                        return                       # the reader went away
        except Exception as exc:  # noqa: BLE001 - kept for the caller
            self.error = exc
        finally:
            if self._srv is not None:
                self._srv.close()

    def start(self):
        self._thread.start()
        return self

    def stop(self, timeout: float = 10.0) -> None:
        self._stop.set()
        self._thread.join(timeout)

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()


def open_pty():
    """A raw pseudo-terminal pair: ``(master fd, slave fd, slave path)``."""
    import tty

    master, slave = os.openpty()
    tty.setraw(slave)
    return master, slave, os.ttyname(slave)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m openemt.live.emitter",
                                description="Send the simulated tracker's raw samples in the "
                                "openemt ADC framing (docs/live.md#adc-framing).")
    p.add_argument("--to", required=True,
                   help="pty (make a pseudo-terminal, print its path), serial:PORT[@BAUD] or "
                        "tcp://HOST:PORT (listen there; one client at a time, each from a "
                        "freshly started counter)")
    p.add_argument("--tracker", help="tracker file whose ADC is emulated (default: simulated)")
    p.add_argument("--frame-samples", type=int, default=64)
    p.add_argument("--format", default="int32", choices=[v[1] for v in FORMATS.values()])
    p.add_argument("--full-scale", type=float, default=10.0, help="volts of the largest count")
    p.add_argument("--duration", type=float, help="seconds of signal (default: endless)")
    p.add_argument("--fast", action="store_true", help="as fast as the reader takes them")
    p.add_argument("--clock-ppm", type=float, default=0.0,
                   help="make the sample clock this many ppm slow")
    p.add_argument("--flip-every", type=int, default=0)
    p.add_argument("--drop-every", type=int, default=0)
    p.add_argument("--skip-every", type=int, default=0)
    p.add_argument("--restart-after", type=float)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", action="store_true", help="print the counts as JSON at the end")
    a = p.parse_args(argv)
    try:
        from ._acquire import _open_serial, parse_source

        spec = None
        if a.tracker:
            from ._tracker_file import read_tracker

            spec = read_tracker(a.tracker)

        def emitter():
            return Emitter(spec, frame_samples=a.frame_samples, fmt=a.format,
                           full_scale=a.full_scale, realtime=not a.fast,
                           clock_ppm=a.clock_ppm, flip_every=a.flip_every,
                           drop_every=a.drop_every, skip_every=a.skip_every,
                           restart_after=a.restart_after, seed=a.seed, duration=a.duration)

        if a.to == "pty":
            master, _slave, path = open_pty()
            print(path, flush=True)
            stats = emitter().run(fd_writer(master))
        elif a.to.startswith("tcp://"):
            import socket

            _, (host, port) = parse_source(a.to, listen=True)
            srv = socket.create_server((host, port))
            print(f"listening on {host}:{srv.getsockname()[1]}", file=sys.stderr, flush=True)
            while True:                  # each client gets a freshly started ADC
                conn, _ = srv.accept()
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                em = emitter()
                try:
                    with conn:
                        stats = em.run(conn.sendall)
                except (BrokenPipeError, ConnectionError):
                    stats = em.stats()
                    continue             # the client went away: wait for the next one
                break
        else:
            _, (port, baud) = parse_source(a.to)
            ser = _open_serial(port, baud)
            stats = emitter().run(ser.write)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except (BrokenPipeError, ConnectionError, KeyboardInterrupt):
        return 0
    if a.json:
        print(json.dumps(stats))
    else:
        print(f"sent {stats['frames']} frames ({stats['samples']} samples)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
