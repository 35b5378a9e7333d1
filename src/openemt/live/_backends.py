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
    "SourceStalled",
    "StallWatch",
    "default_model",
    "default_trajectory",
    "import_sounddevice",
    "list_audio_inputs",
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


class _StackedModel:
    """Several sensors of one coupling model side by side, for the raw-signal simulator:
    ``coupling(poses (N, K, 4, 4)) -> (N, n_source, K * n_sensor)`` (sensor k's coils in
    columns ``k * n_sensor ...``)."""

    def __init__(self, model, k: int):
        self.model = model
        self.k = int(k)
        self.n_source = model.n_source
        self.n_sensor = model.n_sensor * self.k

    def coupling(self, poses):
        P = np.asarray(poses, dtype=np.float64)
        n = P.shape[0]
        C = self.model.coupling(np.ascontiguousarray(P.reshape(n * self.k, 4, 4)))
        so, se = C.shape[1:]
        return C.reshape(n, self.k, so, se).transpose(0, 2, 1, 3).reshape(n, so, self.k * se)

    def metal_couplings(self, scene, poses, frequency_hz, t):
        """A metal scene's coupling change, laid out as :meth:`coupling`."""
        P = np.asarray(poses, dtype=np.float64)
        n = P.shape[0]
        C = scene.induced_couplings(self.model, P.reshape(n * self.k, 4, 4), frequency_hz,
                                    t=np.repeat(np.asarray(t, dtype=np.float64), self.k))
        so, se = C.shape[1:]
        return C.reshape(n, self.k, so, se).transpose(0, 2, 1, 3).reshape(n, so, self.k * se)


def _offset_trajectory(trajectory, offsets):
    """``trajectory`` shifted by each of ``offsets`` (K, 3) m: ``times -> (N, K, 4, 4)``."""
    off = np.asarray(offsets, dtype=np.float64)

    def poses(t):
        P = np.asarray(trajectory(t), dtype=np.float64)
        out = np.repeat(P[:, None], len(off), axis=1)
        out[:, :, :3, 3] += off[None]
        return out

    return poses


class Backend:
    """Base class: a source of raw sample chunks."""

    layout: ChannelLayout
    t0_epoch: float = 0.0

    def read(self):  # pragma: no cover - abstract
        raise NotImplementedError

    #: whether a read may start a run that does not continue the previous one (then
    #: :meth:`pop_restart` says where)
    discontinuous: bool = False
    #: whether the samples arrive at the pace of their sample clock (end-to-end latency is
    #: measured only then)
    realtime: bool = True

    def truth_poses(self, times):
        """True poses ``(N, 4, 4)`` at sample times (s), or None when unknown."""
        return

    def epoch_times(self, times):
        """The acquisition time (UTC, epoch s) of session times ``times`` (s): ``t0_epoch +
        times`` for a device whose sample clock is the host's (the simulator, a sound card)."""
        return self.t0_epoch + times

    def pop_restart(self):
        """The session time (s) where the last read's samples start a new contiguous run
        (after lost frames or a restarted device), once; None otherwise."""
        return None

    def link_stats(self) -> dict | None:
        """Counters of a framed link (frames, CRC errors, gaps, ...), or None."""
        return None

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
    offsets : array (K, 3), optional
        Several sensors of the same model: sensor k follows ``trajectory`` shifted by
        ``offsets[k]`` (m); the layout of ``config`` must list K times the model's sensor
        channels (sensor 0's first). :meth:`truth_poses` is then ``(N, K, 4, 4)``.
    metal : MetalScene, optional
        Metal near the tracker (source frame), its response added per carrier
        (:class:`openemt.signal.RawSimulator`).
    """

    def __init__(self, model=None, trajectory=None, config: RawSignalConfig | None = None, *,
                 seed: int = 0, chunk: int = 640, realtime: bool = False,
                 duration: float | None = None, offsets=None, metal=None):
        self.model = default_model() if model is None else model
        if config is None:
            config = RawSignalConfig(mains_amplitudes=SIMULATED_MAINS_AMPLITUDES_V)
        traj = default_trajectory if trajectory is None else trajectory
        sim_model = self.model
        if offsets is not None:
            off = np.asarray(offsets, dtype=np.float64)
            if off.ndim != 2 or off.shape[1] != 3 or len(off) < 1:
                raise InputError(f"expected `offsets` of shape (K, 3), got {off.shape}")
            if not callable(traj):
                fixed = np.asarray(traj, dtype=np.float64)

                def traj(t, fixed=fixed):
                    return np.broadcast_to(fixed, (len(t), 4, 4))
            traj = _offset_trajectory(traj, off)
            sim_model = _StackedModel(self.model, len(off))
        self._sim = RawSimulator(sim_model, traj, config, seed=seed, metal=metal)
        self.layout = config.layout
        self.chunk = int(chunk)
        if self.chunk < 1:
            raise InputError(f"expected `chunk` >= 1, got {chunk!r}")
        self.realtime = bool(realtime)
        fs = self.layout.sample_rate
        if duration is not None and not 0 < float(duration) < np.inf:
            raise InputError(f"expected a positive, finite `duration` in seconds (None: no end), "
                             f"got {duration!r}")
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

    def simulate_ahead(self) -> None:
        """Simulate every remaining sample of a finite ``duration`` now, so that reads only
        hand samples over, as a device's samples exist before they are read (the simulation
        in blocks of 0.1 s otherwise runs inside the reading thread, a burst of CPU every
        0.1 s that a latency measurement would count against the pipeline)."""
        if self._end is None:
            raise InputError("expected a backend with a finite `duration` to simulate ahead, "
                             "got an endless one")
        more = self._end - self._sim.sample_index
        if more > 0:
            self._buf = np.concatenate([self._buf, self._sim.read(more)])

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


def import_sounddevice():
    """The optional ``sounddevice`` module, or an ImportError saying how to install it."""
    try:
        import sounddevice
    except (ImportError, OSError) as exc:   # OSError: the PortAudio library is missing
        extra = "" if isinstance(exc, ImportError) else f" ({exc})"
        raise ImportError("expected the optional package 'sounddevice' for the sound-card "
                          "backend (pip install sounddevice, or pip install "
                          f"'openemt[sound]'), got it missing{extra}") from None
    if sounddevice is None:   # pragma: no cover - blocked in sys.modules
        raise ImportError("expected the optional package 'sounddevice' (pip install "
                          "sounddevice), got it missing")
    return sounddevice


def list_audio_inputs() -> list:
    """Audio input devices seen by ``sounddevice``: dicts with ``index``, ``name``,
    ``max_input_channels``, ``default_samplerate`` and ``hostapi`` (name)."""
    sd = import_sounddevice()
    try:
        apis = [a["name"] for a in sd.query_hostapis()]
    except Exception:  # noqa: BLE001 - host API names are cosmetic
        apis = []
    out = []
    for i, d in enumerate(sd.query_devices()):
        if int(d.get("max_input_channels", 0)) <= 0:
            continue
        api = d.get("hostapi")
        out.append({"index": int(d.get("index", i)), "name": str(d.get("name", "")),
                    "max_input_channels": int(d["max_input_channels"]),
                    "default_samplerate": float(d.get("default_samplerate", 0.0)),
                    "hostapi": apis[api] if isinstance(api, int) and api < len(apis)
                    else api})
    return out


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
        Seconds ``read`` waits for a block; when none arrives it returns an empty block
        (shape (0, channels)), never None: an audio stream has no end, and a slow first
        block is not the end of the session (see :class:`StallWatch` for a silent device).
    channels : int, optional
        Input channels to open (default: enough for the layout); a tracker file's
        ``adc.channels``.
    """

    def __init__(self, layout: ChannelLayout, *, device=None, chunk: int = 64 * 16,
                 timeout: float = 0.25, max_blocks: int = 64, channels: int | None = None):
        sounddevice = import_sounddevice()
        n_ch = layout.n_channels if channels is None else int(channels)
        if n_ch < layout.n_channels:
            raise InputError(f"expected at least {layout.n_channels} input channels for the "
                             f"layout, got {n_ch}")
        self.layout = layout
        self.timeout = float(timeout)
        self.n_overflow = 0
        self._n_ch = n_ch
        self._closed = False
        self._q: queue.Queue = queue.Queue(maxsize=int(max_blocks))

        def callback(indata, frames, time_info, status):
            if status:
                logger.warning("sound device: %s", status)
            try:
                self._q.put_nowait(np.array(indata, dtype=np.float64))
            except queue.Full:
                self.n_overflow += 1

        self._stream = sounddevice.InputStream(samplerate=layout.sample_rate,
                                               channels=n_ch, dtype="float32",
                                               blocksize=int(chunk), device=device,
                                               callback=callback)
        self.t0_epoch = time.time()
        self._stream.start()

    def read(self):
        if self._closed:
            return None
        try:
            return self._q.get(timeout=self.timeout)
        except queue.Empty:
            return np.empty((0, self._n_ch))

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._stream.stop()
        self._stream.close()


class SourceStalled(OSError):
    """A live source delivered no samples for longer than the allowed time."""


class BackendWrapper(Backend):
    """A backend around another one (``self.backend``): layout, start time, truth and closing
    are the wrapped backend's; a subclass changes :meth:`read`."""

    def __init__(self, backend):
        self.backend = backend

    @property
    def layout(self):
        return self.backend.layout

    @property
    def t0_epoch(self):
        return self.backend.t0_epoch

    def truth_poses(self, times):
        return self.backend.truth_poses(times)

    # the wrapped backend's, or the defaults of Backend for one that does not derive from it
    @property
    def discontinuous(self):
        return getattr(self.backend, "discontinuous", False)

    @property
    def realtime(self):
        return getattr(self.backend, "realtime", True)

    def epoch_times(self, times):
        f = getattr(self.backend, "epoch_times", None)
        return self.backend.t0_epoch + times if f is None else f(times)

    def pop_restart(self):
        f = getattr(self.backend, "pop_restart", None)
        return None if f is None else f()

    def link_stats(self):
        f = getattr(self.backend, "link_stats", None)
        return None if f is None else f()

    def read(self):
        return self.backend.read()

    def close(self) -> None:
        self.backend.close()


class StallWatch(BackendWrapper):
    """Watch a backend for silence: an empty read (a sound card's read timeout) is not the
    end of the data; after ``warn_after`` seconds without a sample ``on_warn(message)`` is
    called once per silence, and after ``timeout`` seconds :class:`SourceStalled` is raised
    (the source never started, or stopped delivering).

    Parameters
    ----------
    backend : Backend
    warn_after : float or None
        Seconds of silence before the warning (None: no warning).
    timeout : float or None
        Seconds of silence before the error (None: wait forever).
    on_warn : callable, optional
        Gets the warning text (default: the module logger).
    """

    def __init__(self, backend, *, warn_after: float | None = 2.0,
                 timeout: float | None = 10.0, on_warn=None):
        for name, v in (("warn_after", warn_after), ("timeout", timeout)):
            if v is not None and not 0 < float(v) < np.inf:
                raise InputError(f"expected a positive, finite `{name}` in seconds (or None), "
                                 f"got {v!r}")
        super().__init__(backend)
        self.warn_after = None if warn_after is None else float(warn_after)
        self.timeout = None if timeout is None else float(timeout)
        self.on_warn = on_warn or logger.warning
        self.n_stalls = 0            # silences that reached warn_after
        self.longest_silence = 0.0   # seconds, over the session
        self._started = False
        self._last = None            # the silence counts from the first read
        self._warned = False

    def read(self):
        if self._last is None:
            self._last = time.monotonic()
        x = self.backend.read()
        now = time.monotonic()
        if x is None:
            return None
        silent = now - self._last
        if len(x):
            self.longest_silence = max(self.longest_silence, silent)
            self._started, self._last, self._warned = True, now, False
            return x
        what = ("no samples from the source since it started" if not self._started
                else "no samples from the source")
        if self.warn_after is not None and not self._warned and silent >= self.warn_after:
            self._warned = True
            self.n_stalls += 1
            self.on_warn(f"warning: {what} for {silent:.1f} s (still waiting; an error after "
                         f"{self.timeout:g} s)" if self.timeout is not None else
                         f"warning: {what} for {silent:.1f} s (still waiting)")
        if self.timeout is not None and silent >= self.timeout:
            self.longest_silence = max(self.longest_silence, silent)
            why = "it stopped delivering" if self._started else "it never started"
            raise SourceStalled(f"expected samples from the live source, got none for "
                                f"{silent:.1f} s ({why}; limit --stall-timeout "
                                f"{self.timeout:g} s)")
        return x

