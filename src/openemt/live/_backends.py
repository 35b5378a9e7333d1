"""Acquisition backends: where raw samples come from.

Every backend has a :class:`~openemt.signal.ChannelLayout` (carriers, rate, channel order),
``t0_epoch`` (wall-clock time of its first sample), ``read() -> (n, n_channels) | None``
(``None`` = end of data) and ``close()``:

- :class:`SimulatedBackend` -- the raw-signal simulator along a pose trajectory, paced in real
  time or as fast as possible (default);
- :class:`ReplayBackend` -- a raw HDF5 recording (:func:`openemt.signal.write_raw` schema);
- :class:`SoundDeviceBackend` -- a multi-channel audio interface through the optional
  ``sounddevice`` package (``pip install openemt[sound]``), imported only when used.
"""

from __future__ import annotations

import logging
import queue
import time

import numpy as np

from .._constants import SIMULATED_MAINS_AMPLITUDES_V
from .._errors import InputError
from ..geometry import pose_from_vector
from ..signal import ChannelLayout, RawSignalConfig, RawSimulator, read_raw

__all__ = [
    "Backend",
    "ReplayBackend",
    "SimulatedBackend",
    "SoundDeviceBackend",
    "default_model",
    "default_trajectory",
]

logger = logging.getLogger(__name__)


def default_trajectory(t) -> np.ndarray:
    """A slow figure-of-eight around (200, 0, 0) mm with rocking orientation, poses (N, 4, 4).

    Position: ``x = 200 + 10 sin(w t / 2)`` mm, ``y = 40 sin(w t)`` mm, ``z = 25 sin(2 w t)`` mm
    with ``w = 2 pi / 8 s``; rotation vector ``(0.3 sin(w t), 0.2 cos(w t), 0.4 sin(w t / 2))``
    rad. It stays in the +x hemisphere.
    """
    t = np.atleast_1d(np.asarray(t, dtype=np.float64))
    w = 2 * np.pi / 8.0
    v = np.stack([0.200 + 0.010 * np.sin(w * t / 2), 0.040 * np.sin(w * t),
                  0.025 * np.sin(2 * w * t), 0.3 * np.sin(w * t), 0.2 * np.cos(w * t),
                  0.4 * np.sin(w * t / 2)], axis=1)
    return pose_from_vector(v)


def default_model():
    """The simulated tracker's dipole model: preset ``concentric`` of :mod:`openemt.simulate`
    when available, else an ideal concentric tri-axial source and sensor."""
    try:
        from ..simulate import get_preset
        return get_preset("concentric").dipole
    except ImportError:  # pragma: no cover - simulate always ships with openemt
        from ..field import DipoleModel
        return DipoleModel.concentric()


class Backend:
    """Base class: a source of raw sample chunks."""

    layout: ChannelLayout
    t0_epoch: float = 0.0

    def read(self):  # pragma: no cover - abstract
        raise NotImplementedError

    def truth_poses(self, times):
        """True poses ``(N, 4, 4)`` at sample times (s), or None when unknown."""
        return

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class SimulatedBackend(Backend):
    """Simulated device: raw samples from :class:`openemt.signal.RawSimulator`.

    Parameters
    ----------
    model : coupling model, optional
        Truth model (default :func:`default_model`).
    trajectory : callable, optional
        ``trajectory(times) -> poses (N, 4, 4)`` (default :func:`default_trajectory`).
    config : RawSignalConfig, optional
        Drive, noise and interference (default: 1e-4 V rms sensor noise, 50 Hz mains of
        10 mV plus harmonics).
    seed : int
    chunk : int
        Samples per read (640 = ten output frames, 6.7 ms at 96 kS/s, like an audio block).
    realtime : bool
        Pace reads so samples arrive at the sample rate of the wall clock.
    duration : float, optional
        Seconds of signal before ``read`` returns None (None = endless).
    """

    def __init__(self, model=None, trajectory=None, config: RawSignalConfig | None = None, *,
                 seed: int = 0, chunk: int = 640, realtime: bool = False,
                 duration: float | None = None):
        self.model = default_model() if model is None else model
        if config is None:
            config = RawSignalConfig(mains_amplitudes=SIMULATED_MAINS_AMPLITUDES_V)
        self._sim = RawSimulator(self.model, default_trajectory if trajectory is None
                                 else trajectory, config, seed=seed)
        self.layout = config.layout
        self.chunk = int(chunk)
        if self.chunk < 1:
            raise InputError(f"expected `chunk` >= 1, got {chunk!r}")
        self.realtime = bool(realtime)
        fs = self.layout.sample_rate
        self._end = None if duration is None else round(float(duration) * fs)
        self._block = 9600
        self._buf = np.empty((0, self.layout.n_channels))
        self._i = 0
        self.t0_epoch = time.time()
        self._t0_perf = time.perf_counter()

    def read(self):
        i = self._i
        n = self.chunk if self._end is None else min(self.chunk, self._end - i)
        if n <= 0:
            return None
        if self._buf.shape[0] < n:            # simulate ahead in blocks (cheaper per sample)
            more = max(n, self._block)
            if self._end is not None:
                more = min(max(n, self._block), self._end - self._sim.sample_index)
            self._buf = np.concatenate([self._buf, self._sim.read(more)])
        if self.realtime:
            due = self._t0_perf + (i + n) / self.layout.sample_rate
            delay = due - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
        out, self._buf = self._buf[:n], self._buf[n:]
        self._i = i + n
        return out

    def restart_clock(self) -> None:
        """Make "now" the wall-clock time of the next sample (for real-time pacing and the
        IGTL timestamps), e.g. after waiting for a viewer to connect."""
        now_perf, now = time.perf_counter(), time.time()
        elapsed = self._i / self.layout.sample_rate
        self._t0_perf = now_perf - elapsed
        self.t0_epoch = now - elapsed

    def truth_poses(self, times):
        return self._sim.poses(times)

    def true_couplings(self, times):
        """Complex truth couplings ``(N, n_source, n_sensor)`` at ``times`` (s)."""
        return self._sim.true_couplings(times)


class ReplayBackend(Backend):
    """Replay a raw HDF5 recording (see :func:`openemt.signal.write_raw`).

    Raises ``ValueError`` / ``FileNotFoundError`` with a one-line message for unreadable files.
    Truth poses stored in the file (simulations) are interpolated to the requested times
    (nearest tabulated sample).
    """

    def __init__(self, path, *, chunk: int = 640, realtime: bool = False):
        self.raw = read_raw(path)
        self.layout = self.raw.layout
        self.chunk = int(chunk)
        if self.chunk < 1:
            raise InputError(f"expected `chunk` >= 1, got {chunk!r}")
        self.realtime = bool(realtime)
        self._i = 0
        self.t0_epoch = time.time()
        self._t0_perf = time.perf_counter()

    def read(self):
        i, n_total = self._i, self.raw.n_samples
        if i >= n_total:
            return None
        n = min(self.chunk, n_total - i)
        if self.realtime:
            delay = self._t0_perf + (i + n) / self.layout.sample_rate - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
        self._i = i + n
        return self.raw.samples[i:i + n]

    def truth_poses(self, times):
        tt, P = self.raw.truth_times, self.raw.truth_poses
        if tt is None or P is None or len(tt) == 0:
            return None
        t = np.asarray(times, dtype=np.float64)
        if len(tt) == 1:
            return np.broadcast_to(P[0], (len(t), 4, 4))
        k = np.clip(np.searchsorted(tt, t), 1, len(tt) - 1)
        k = np.where(t - tt[k - 1] < tt[k] - t, k - 1, k)   # nearest tabulated time
        return P[k]


class SoundDeviceBackend(Backend):
    """A multi-channel audio interface (96 kS/s, e.g. 8-in) through ``sounddevice``.

    Sensor and reference channels are wired as in ``layout``. Blocks arrive from the audio
    callback through a bounded queue; overflowing blocks are dropped and counted
    (``n_overflow``), never buffered without bound.

    Parameters
    ----------
    layout : ChannelLayout
    device : int or str, optional
        ``sounddevice`` input device.
    chunk : int
        Block size (samples).
    timeout : float
        Seconds ``read`` waits for a block before giving up (returns None).
    """

    def __init__(self, layout: ChannelLayout, *, device=None, chunk: int = 64 * 16,
                 timeout: float = 1.0, max_blocks: int = 64):
        try:
            import sounddevice
        except ImportError:
            raise ImportError("expected the optional package 'sounddevice' for the sound-card "
                              "backend (pip install 'openemt[sound]'), got it missing") from None
        self.layout = layout
        self.timeout = float(timeout)
        self.n_overflow = 0
        self._q: queue.Queue = queue.Queue(maxsize=int(max_blocks))

        def callback(indata, frames, time_info, status):
            if status:
                logger.warning("sound device: %s", status)
            try:
                self._q.put_nowait(np.array(indata, dtype=np.float64))
            except queue.Full:
                self.n_overflow += 1

        self._stream = sounddevice.InputStream(samplerate=layout.sample_rate,
                                               channels=layout.n_channels, dtype="float32",
                                               blocksize=int(chunk), device=device,
                                               callback=callback)
        self.t0_epoch = time.time()
        self._stream.start()

    def read(self):
        try:
            return self._q.get(timeout=self.timeout)
        except queue.Empty:
            return None

    def close(self) -> None:
        self._stream.stop()
        self._stream.close()
