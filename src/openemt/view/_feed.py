"""The live view's side of a session: a read-only observer that keeps the latest blocks, and
the numbers each panel shows, computed from them outside the acquisition thread.

:class:`LiveFeed` implements the observer protocol of :mod:`openemt.live._observe`: the
session appends every raw chunk and every processed chunk (its
:class:`~openemt.live.TrackStep`) to bounded histories, by reference (the arrays are handed
out fresh and never written again; the raw recorder and the log keep them the same way),
an append to a bounded deque and no more. :meth:`LiveFeed.snapshot` (called when a page is
due for an update: :class:`~openemt.view.ViewProcess`'s thread, or the server's own with
:class:`~openemt.view.ViewServer`) copies the deques and computes from the copies:

- per carrier: the drive-current level on its reference channel and the rms level of the
  sensor channels at its frequency (V, from the raw samples: a Hann-windowed correlation at
  the carrier frequency over the last ``raw_samples``), the coupling level ``||C[i, :]||``, the SNR and the
  quadrature ratio ``||Im C[i, :]|| / ||C[i, :]||`` over the last ``window_samples`` outputs;
- per channel: the amplitude spectrum of the last ``raw_samples`` (Hann window, dB re 1 V
  amplitude);
- the latest coupling matrix (every sensor's columns);
- per sensor: the latest status, quadrature ratio, residual and pose, and its trail (the
  converged last pose of each block of the last ``history_seconds``, at most
  ``trail_points`` blocks evenly spaced, of its last ``history_blocks`` blocks). The
  session's thread writes each block's last time, position and convergence, and its
  couplings, into two small per-sensor rings as it publishes the block; a snapshot reads the
  rings. No block is held but each sensor's newest (a block held costs the session's caches;
  a walk over the blocks of a view period cost the snapshot's thread the interpreter lock
  for a millisecond and more at 50x real time).

:meth:`LiveFeed.gather` collects these inputs in the session's process (references, the
ring, one concatenation of the raw chunks); :func:`compute_snapshot` turns them into the
panels' numbers, in the view's own process when :class:`~openemt.view.ViewProcess` serves
the page (the spectra, carrier levels and SNR then cost the session's interpreter nothing).

SNR: the coupling noise of each entry is estimated from second differences of outputs two
output periods apart, ``d = C[k+4] - 2 C[k+2] + C[k]`` (outputs two periods apart share no
raw sample with the Hann and rectangular frames, so their noise is independent and
``var d = 6 sigma^2``; a smooth motion contributes ``(2 T)^4 |C''|^2``, negligible at 1500
outputs/s), and ``SNR_i = 20 log10(||C[i, :]|| / ||sigma[i, :]||)`` in dB. It needs no noise
model and works on a log as on a live session.
"""

from __future__ import annotations

import collections
import functools
import threading
import time

import numpy as np

__all__ = ["LiveFeed", "carrier_levels", "collect_panel", "compute_snapshot", "coupling_snr_db",
           "spectrum_db"]


def carrier_levels(x, frequencies, sample_rate) -> np.ndarray:
    """Amplitude (V) of each carrier in each channel of ``x`` ``(n, n_channels)``: the
    Hann-windowed correlation at the carrier frequency, scaled so that a cosine of amplitude A
    at that frequency gives A. Shape ``(n_carriers, n_channels)``."""
    x = np.asarray(x, dtype=np.float64)
    basis = _carrier_basis(x.shape[0], tuple(float(f) for f in frequencies),
                           float(sample_rate))
    return np.abs(basis @ x)


@functools.lru_cache(maxsize=8)
def _hann(n: int) -> np.ndarray:
    """The demodulator's Hann window of ``n`` samples (computed once per length)."""
    from ..signal import frame_window

    w = frame_window("hann", n)
    w.flags.writeable = False
    return w


@functools.lru_cache(maxsize=8)
def _carrier_basis(n: int, frequencies: tuple, sample_rate: float) -> np.ndarray:
    """``(n_carriers, n)``: Hann window x ``exp(-j 2 pi f t)`` x ``2 / sum(w)``."""
    w = _hann(n)
    f = np.asarray(frequencies)
    basis = w[:, None] * np.exp(-2j * np.pi * np.outer(np.arange(n), f) / sample_rate)
    return np.ascontiguousarray(basis.T) * (2.0 / w.sum())


def spectrum_db(x, sample_rate, max_points: int = 1024):
    """Amplitude spectrum of each channel of ``x`` ``(n, n_channels)`` in dB re 1 V
    (Hann window, scaled so a sinusoid of amplitude A at a bin reads ``20 log10 A``), reduced
    to at most ``max_points`` frequencies by keeping the largest value of each group of bins
    (a carrier never disappears between two points). Returns ``(frequencies (F,), dB (F,
    n_channels))``."""
    x = np.asarray(x, dtype=np.float64)
    n = x.shape[0]
    w = _hann(n)
    amp = np.abs(np.fft.rfft(x * w[:, None], axis=0)) * (2.0 / w.sum())
    f = np.fft.rfftfreq(n, 1.0 / sample_rate)
    g = max(1, -(-len(f) // int(max_points)))
    m = len(f) // g * g
    amp = amp[:m].reshape(m // g, g, -1).max(axis=1)
    f = f[:m].reshape(m // g, g).mean(axis=1)
    with np.errstate(divide="ignore"):
        return f, 20 * np.log10(np.maximum(amp, 1e-300))


def coupling_snr_db(C) -> tuple[np.ndarray, np.ndarray]:
    """SNR per carrier (dB) of complex couplings ``C`` ``(N, n_source, n_sensor)`` and the
    noise ``sigma`` per entry (coupling units, real part), from second differences of outputs
    two periods apart (see the module docstring). NaN with fewer than 8 outputs."""
    C = np.asarray(C)
    n_so = C.shape[1] if C.ndim == 3 else 0
    if C.ndim != 3 or C.shape[0] < 8:
        return np.full(n_so, np.nan), np.full(C.shape[1:] if C.ndim == 3 else (0,), np.nan)
    d = C.real[4:] - 2 * C.real[2:-2] + C.real[:-4]
    sigma = np.sqrt(np.mean(d ** 2, axis=0) / 6.0)
    level = np.sqrt(np.mean(np.abs(C) ** 2, axis=0))         # rms |C| per entry
    num = np.sqrt(np.sum(level ** 2, axis=1))
    den = np.sqrt(np.sum(sigma ** 2, axis=1))
    with np.errstate(divide="ignore", invalid="ignore"):
        return 20 * np.log10(num / den), sigma


class LiveFeed:
    """The read-only observer a session publishes to, and the source of every panel.

    Parameters
    ----------
    raw_samples : int
        Raw samples kept per channel for the spectrum and the carrier levels (default 4096:
        43 ms at 96 kS/s, bins of 23 Hz).
    history_seconds, history_blocks : float, int
        The trail covers the last ``history_seconds`` of each sensor, within its last
        ``history_blocks`` processed blocks (5 s and 1024: 6.8 s of 640-sample reads).
    window_samples : int
        Outputs over which the SNR and the quadrature ratio per carrier are computed
        (default 300: 0.2 s at 1500/s).
    trail_points : int
        Most points of a trail handed to the view (the history decimated evenly).
    """

    def __init__(self, *, raw_samples: int = 4096, history_seconds: float = 5.0,
                 history_blocks: int = 1024, window_samples: int = 300,
                 trail_points: int = 500):
        self.raw_samples = int(raw_samples)
        self.history_seconds = float(history_seconds)
        self.window = max(int(window_samples), 8)
        self.blocks = max(int(history_blocks), 1)
        self.trail_points = int(trail_points)
        self.layout = None
        self.names: tuple = ()
        self.source = None
        self._lock = threading.Lock()
        self._raw: collections.deque = collections.deque(maxlen=8)
        self._n_chunks = 0
        self._last: list = []         # per sensor: its newest block
        self._windows: list = []      # per sensor: a _Rows ring of its recent couplings
        self.n_samples: list = []
        self._cache = (None, None)
        self._collect = None          # the latest state of a collection (``collect``)
        self._trails: list = []       # per sensor: a _Trail

    # -- the observer protocol (the session's thread: as little as possible). A block is
    # kept as the sensor's newest (one reference), counted, and copied into two small rings
    # of fixed memory: its couplings (the couplings window) and its last time, position and
    # convergence (the trail); no older block is held (holding blocks costs the session's
    # caches: docs/live.md#what-the-view-costs-the-acquisition-openemt-bench-track---view---json).
    # A ring row is complete before the count that makes it visible is raised, and the view
    # reads rows in one copy under the interpreter lock, so the session never waits for it.
    def start(self, layout) -> None:
        with self._lock:
            self.layout = layout
            self._raw = collections.deque(maxlen=8)

    def sensors(self, names) -> None:
        with self._lock:
            self.names = tuple(names)
            self._last = [None] * len(self.names)
            self._windows = [_Rows(self.window) for _ in self.names]
            self._trails = [_Trail(self.blocks) for _ in self.names]
            self.n_samples = [0] * len(self.names)

    def raw(self, chunk) -> None:
        self._raw.append(chunk)      # a reference: the array is never written again
        self._n_chunks += 1

    def step(self, step, sensor: int = 0) -> None:
        if step.couplings is not None:             # (a log without couplings has none)
            self._windows[sensor].append(step.couplings)
        self._trails[sensor].append(step)
        self._last[sensor] = step
        self.n_samples[sensor] += step.times.shape[0]

    def collect(self, state: dict) -> None:
        """A collection's state (``openemt collect``, once per analysis and at the end): a
        dict of numbers and arrays handed out fresh (references kept, never written)."""
        self._collect = state

    # -- the view's side
    @property
    def version(self) -> tuple:
        """Changes with every block published (the samples counted, the raw chunks
        received, the latest collection state, which the feed holds)."""
        return (sum(self.n_samples), self._n_chunks, id(self._collect))

    def _raw_chunks(self) -> list:
        """The raw chunks held, newest last; the deque sized to hold ``raw_samples`` (grown
        when full and short of them, shrunk when far beyond: a chunk appended while it is
        swapped is left out of the spectra, once)."""
        q = self._raw
        chunks = list(q)
        if not chunks:
            return chunks
        need, n = 0, 0
        for c in reversed(chunks):
            need += 1
            n += len(c)
            if n >= self.raw_samples:
                break
        if n < self.raw_samples and len(chunks) == q.maxlen:
            self._raw = collections.deque(q, maxlen=2 * q.maxlen)
        elif q.maxlen > 2 * (need + 1):
            self._raw = collections.deque(q, maxlen=need + 1)
        return chunks[-need:]

    def snapshot(self) -> dict:
        """Every number the panels show, from the blocks published so far (cached until the
        next block arrives): :func:`compute_snapshot` of :meth:`gather`."""
        with self._lock:
            if self._cache[0] == self.version:
                return self._cache[1]
        snap = compute_snapshot(self.gather())
        with self._lock:
            self._cache = (snap["version"], snap)
        return snap

    def gather(self) -> dict:
        """What the panels are computed from, as plain arrays (:func:`compute_snapshot`
        turns it into the snapshot; :class:`~openemt.view.ViewProcess` sends it to the
        view's process, which does that there, off this interpreter): the version, the
        layout and sensor names, each sensor's latest state, trail and recent couplings
        (``window`` outputs), the last ``raw_samples`` raw samples and a collection's
        state."""
        with self._lock:
            version = self.version
            last = list(self._last)
            windows = [w.last() for w in self._windows]
            chunks = self._raw_chunks()
            layout, names = self.layout, self.names
            counts = list(self.n_samples)
            collecting = self._collect
            trails = [tr.points(self.history_seconds, self.trail_points)
                      for tr in self._trails]
        raw = None
        if chunks and layout is not None:
            raw = np.concatenate(chunks)[-self.raw_samples:, :layout.n_channels]
        return {"version": version, "source": self.source, "layout": layout, "names": names,
                "wall_time": time.time(), "raw": raw, "collect": collecting,
                "sensors": _sensor_states(names, last, windows, counts, trails)}


class _Rows:
    """The last ``n`` rows appended (arrays of rows, e.g. a block's couplings), in a ring of
    fixed memory written by the session's thread (:meth:`append`) and read by the view's
    (:meth:`last`). A row is written before the count that makes it visible is raised; the
    ring holds twice the rows read, and a reader whose rows the writer may have reached
    meanwhile (more than ``n`` rows appended since it read the count) copies again."""

    def __init__(self, n: int):
        self.n = int(n)
        self.cap = 2 * self.n
        self.rows = None                  # allocated with the first block (its row shape)
        self.count = 0

    def append(self, block) -> None:
        k = block.shape[0]
        if k > self.n:                    # only the last n rows can be read
            block, k = block[-self.n:], self.n
        if self.rows is None or self.rows.shape[1:] != block.shape[1:]:
            self.rows = np.zeros((self.cap,) + block.shape[1:], block.dtype)
            self.count = 0
        j = self.count % self.cap
        m = min(k, self.cap - j)
        self.rows[j:j + m] = block[:m]
        if m < k:                         # wrapped around
            self.rows[:k - m] = block[m:]
        self.count += k

    def last(self):
        """A copy of the last ``n`` rows (fewer before that many were appended), oldest
        first; None before the first."""
        while True:
            n, rows = self.count, self.rows
            if not n or rows is None:
                return None
            out = rows[np.arange(n - min(n, self.n), n) % self.cap]
            if self.count - n <= self.cap - self.n and rows is self.rows:
                return out


class _Trail:
    """One sensor's trail: the last time, position and convergence of each of its last
    ``held`` blocks, in a ring written by the session's thread as each block is published
    (:meth:`append`, three small writes) and read by the view's (:meth:`points`). A row is
    complete before the count that makes it visible is raised; the ring holds twice the rows
    read, and a reader whose rows the writer may have reached meanwhile reads again."""

    def __init__(self, held: int):
        self.held = int(held)
        self.cap = 2 * self.held
        self.t = np.full(self.cap, np.nan)
        self.p = np.zeros((self.cap, 3))
        self.ok = np.zeros(self.cap, dtype=bool)
        self.count = 0                    # blocks appended so far
        from ..solve import Status

        self.converged = int(Status.CONVERGED)

    def append(self, block) -> None:
        j = self.count % self.cap
        self.t[j] = block.times[-1]
        self.p[j] = block.pose_vectors[-1, :3]
        self.ok[j] = block.status[-1] == self.converged
        self.count += 1

    def points(self, seconds: float, most: int):
        """The converged positions of the blocks held that end at most ``seconds`` before
        the newest one, at most ``most`` blocks evenly spaced (counted back from the newest,
        which is always in), oldest first: ``(K, 3)``; None before the first block."""
        while True:
            n = self.count
            if not n:
                return None
            rows = np.arange(n - min(n, self.held), n) % self.cap
            t = self.t[rows]
            recent = rows[t >= t[-1] - seconds]
            stride = max(1, -(-len(recent) // most))
            pick = recent[::-1][::stride]
            pick = pick[self.ok[pick]][::-1]
            out = self.p[pick]                      # a copy (fancy indexing)
            if self.count - n <= self.cap - self.held:
                return out


def _sensor_states(names, lasts, windows, counts, trails) -> list:
    """Each sensor's latest state, its trail and (``"window"``) its recent couplings."""
    from ..solve import Status

    out = []
    for name, last, C, count, trail in zip(names, lasts, windows, counts, trails):
        if last is None:
            out.append({"name": name, "n_samples": 0, "window": None})
            continue
        k = len(last) - 1
        code = int(last.status[k])
        try:
            status = Status(code).name
        except ValueError:
            status = str(code)
        rel = getattr(last, "relative_residual", None)
        out.append({
            "name": name, "n_samples": count, "time": float(last.times[k]),
            "status": status, "status_code": code,
            "distortion": float(last.distortion[k]), "distorted": bool(last.distorted[k]),
            "residual": float(last.residual[k]),
            "relative_residual": float("nan") if rel is None else float(rel[k]),
            "pose_vector": np.array(last.pose_vectors[k], dtype=np.float64),
            "trail": trail,
            "couplings": None if C is None else C[-1].copy(), "window": C})
    return out


def compute_snapshot(inputs: dict) -> dict:
    """The numbers the panels show from :meth:`LiveFeed.gather`'s ``inputs`` (a pure
    function of them: it may run in another process)."""
    layout, raw = inputs["layout"], inputs["raw"]
    sensors = [dict(s) for s in inputs["sensors"]]
    blocks = [s.pop("window", None) for s in sensors]   # per sensor: (window, n_so, k)
    snap: dict = {"wall_time": inputs["wall_time"], "sensors": sensors,
                  "frequencies": None if layout is None else list(layout.frequencies)}
    # per carrier, over every sensor's columns
    have = [b for b in blocks if b is not None]
    if have:
        n = min(len(b) for b in have)
        C = np.concatenate([b[-n:] for b in have], axis=2)       # (n, n_so, all columns)
        snr, sigma = coupling_snr_db(C)
        im = np.sqrt(np.sum(C.imag ** 2, axis=2))
        ab = np.sqrt(np.sum(np.abs(C) ** 2, axis=2))
        with np.errstate(divide="ignore", invalid="ignore"):
            quad = np.mean(im / ab, axis=0)
        snap["carriers"] = {"snr_db": snr, "quadrature": quad,
                            "coupling_level": np.sqrt(np.mean(ab ** 2, axis=0)),
                            "noise": sigma, "window": n}
    if raw is not None and len(raw) >= 64 and layout is not None:
        fs = layout.sample_rate
        lv = carrier_levels(raw, layout.frequencies, fs)          # (n_so, n_channels)
        ref = lv[np.arange(layout.n_source), list(layout.reference_channels)]
        sens = np.sqrt(np.mean(lv[:, list(layout.sensor_channels)] ** 2, axis=1))
        snap.setdefault("carriers", {}).update({"reference_level": ref, "sensor_level": sens,
                                                "levels": lv})
        f, db = spectrum_db(raw, fs, max_points=512)
        snap["spectrum"] = {"frequencies": f, "db": db, "samples": len(raw)}
    if inputs["collect"] is not None:
        snap["collect"] = collect_panel(inputs["collect"])
    snap["version"], snap["source"] = inputs["version"], inputs["source"]
    return snap


def collect_panel(state: dict) -> dict:
    """What the collect panel shows of a collection's ``state`` (see
    :meth:`LiveFeed.collect`): the dwell count against the target and the minimum, the
    coverage (:func:`openemt.align.coverage` of the tracker's dwell positions and the
    reference's rotations in the working volume ``box``, as the collection reports it), the
    dwell positions (mm) and the direction of each dwell's sensor z axis (azimuth and
    elevation in the tracker's frame, degrees)."""
    from ..align import coverage

    P = np.asarray(state["poses"], dtype=np.float64).reshape(-1, 4, 4)
    B = np.asarray(state["reference_poses"], dtype=np.float64).reshape(-1, 4, 4)
    box = np.asarray(state["box"], dtype=np.float64)
    n = min(len(P), len(B))
    cov = coverage(P[:n, :3, 3], B[:n], box)
    axis = P[:n, :3, 2]
    return {
        "n_dwells": int(state["n_dwells"]), "n_used": n, "n_target": int(state["n_target"]),
        "n_min": int(state["n_min"]), "coverage": cov, "box_mm": 1e3 * box,
        "positions_mm": 1e3 * P[:n, :3, 3],
        "azimuth_deg": np.degrees(np.arctan2(axis[:, 1], axis[:, 0])),
        "elevation_deg": np.degrees(np.arcsin(np.clip(axis[:, 2], -1.0, 1.0))),
        "tracker_seconds": float(state["tracker_seconds"]),
        "time_offset_ms": state.get("time_offset_ms"), "locked": bool(state.get("locked")),
        "ended_by": state.get("ended_by"), "sensor": state.get("sensor")}
