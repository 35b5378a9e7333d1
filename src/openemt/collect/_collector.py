"""Collecting a reference-pose dataset live: :class:`Collector` takes the two streams as they
arrive and analyses them incrementally, so the work per second of signal stays the same however
long the collection runs. The pure array functions it uses are in :mod:`openemt.align`."""

from __future__ import annotations

import numpy as np

from ..align import (
    BASELINE_S,
    COUPLING_RATE_STATIC,
    LEVER_M,
    MARGIN_S,
    MIN_DWELL_S,
    ROTATION_SPEED_STATIC,
    SPEED_STATIC,
    DwellSet,
    OffsetEstimate,
    average_dwell,
    coupling_motion,
    find_dwells,
    log_profile,
    pose_motion,
    time_offset_scan,
)
from ..align import GRID_S as STEP

__all__ = ["MIN_CONFIDENCE", "MIN_CORRELATION", "MIN_OVERLAP_S", "OFFSET_WINDOW_S", "Collector"]

#: The time offset is taken once the two motion profiles correlate by at least this much ...
MIN_CORRELATION = 0.6
#: ... with at least this confidence (:attr:`openemt.align.OffsetEstimate.confidence`: no other
#: alignment, 0.5 s or more away, nearly as good) ...
MIN_CONFIDENCE = 0.25
#: ... over at least this many seconds of overlap.
MIN_OVERLAP_S = 10.0
#: The offset is estimated on the last this-many seconds of the tracker's motion (bounded work),
#: and refined within +-REFINE_S every REFINE_EVERY_S seconds of signal once taken ...
OFFSET_WINDOW_S = 120.0
REFINE_S = 0.25
REFINE_EVERY_S = 10.0
#: ... on the last this-many seconds of it.
REFINE_WINDOW_S = 30.0
#: Samples beyond the profiled grid needed by its box average and difference (s).
_PAD = 2.5 * BASELINE_S
#: Profiles are computed in pieces of at most this many seconds.
_PIECE_S = 30.0


class _Grow:
    """An array grown along its first axis with amortised copying."""

    def __init__(self, tail=(), dtype=np.float64):
        self.a = np.empty((256, *tail), dtype=dtype)
        self.n = 0

    def extend(self, x) -> None:
        x = np.asarray(x, dtype=self.a.dtype)
        need = self.n + len(x)
        if need > len(self.a):
            b = np.empty((max(need, 2 * len(self.a)), *self.a.shape[1:]), dtype=self.a.dtype)
            b[:self.n] = self.a[:self.n]
            self.a = b
        self.a[self.n:need] = x
        self.n = need

    @property
    def v(self):
        return self.a[:self.n]

    def __len__(self):
        return self.n


class _Profile:
    """The motion profile and static flags of one stream on the grid ``g0 + k * STEP``, extended
    piece by piece as samples arrive (each grid value depends on the samples within ``_PAD``
    only). Static runs that have ended are reported once, as grid index pairs."""

    def __init__(self, kind: str):
        self.kind = kind
        self.g0: float | None = None
        self.motion = _Grow()
        self.static = _Grow(dtype=bool)
        self.closed: list = []               # (first, last) grid index of ended static runs
        self._run = None

    @property
    def t_end(self) -> float | None:
        """Grid time just after the last profiled value."""
        return None if self.g0 is None else self.g0 + STEP * len(self.motion)

    def times(self, i0=0, i1=None):
        i1 = len(self.motion) if i1 is None else i1
        return self.g0 + STEP * np.arange(i0, i1)

    def index(self, t) -> int:
        return int(np.floor((t - self.g0) / STEP + 1e-9))

    def update(self, t, x) -> None:
        """Profile the samples ``(t, x)`` (the whole stream so far, sorted) up to ``_PAD``
        before the last one."""
        if len(t) < 4:
            return
        if self.g0 is None:
            self.g0 = float(t[0]) + _PAD
        k_end = self.index(t[-1] - _PAD)          # last grid index to compute
        while len(self.motion) <= k_end:
            ka = len(self.motion)
            kb = min(k_end, ka + int(_PIECE_S / STEP))
            lo = np.searchsorted(t, self.g0 + STEP * ka - _PAD, "right") - 1
            hi = np.searchsorted(t, self.g0 + STEP * kb + _PAD, "left") + 1
            lo, hi = max(lo, 0), min(hi, len(t))
            if hi - lo < 2:
                break
            if self.kind == "coupling":
                g, rate = coupling_motion(t[lo:hi], x[lo:hi], grid_start=self.g0)
                motion, static = rate, rate < COUPLING_RATE_STATIC
            else:
                g, v, w = pose_motion(t[lo:hi], x[lo:hi], grid_start=self.g0)
                motion = v + LEVER_M * w
                static = (v < SPEED_STATIC) & (w < ROTATION_SPEED_STATIC)
            k = np.rint((g - self.g0) / STEP).astype(np.int64)
            sel = (k >= ka) & (k <= kb)
            if not sel.any() or k[sel][0] != ka:
                break
            self.motion.extend(motion[sel])
            self.static.extend(static[sel])
            self._runs(ka)

    def _runs(self, k0) -> None:
        s = self.static.v[k0:].astype(np.int8)
        prev = 1 if self._run is not None else 0
        edges = np.diff(np.concatenate([[prev], s]))
        for i in np.flatnonzero(edges):
            if edges[i] > 0:
                self._run = k0 + int(i)
            else:
                if self._run is not None:
                    self.closed.append((self._run, k0 + int(i) - 1))
                self._run = None


class Collector:
    """The two streams of a collection, fed as they arrive and analysed incrementally.

    Raw chunks are demodulated (:class:`openemt.signal.Demodulator`) and the in-phase couplings
    of one sensor's columns averaged over ``decimate`` frames (300 per second at the default
    1500 frames/s); reference poses are appended with their time stamps. :meth:`update`
    extends both motion profiles over the new samples only, estimates the time offset on a
    bounded window (:data:`OFFSET_WINDOW_S`) until it is sure (:data:`MIN_CORRELATION`,
    :data:`MIN_CONFIDENCE`, :data:`MIN_OVERLAP_S`) and then refines it within +-``REFINE_S``,
    and averages both streams over each tracker dwell that has ended and that the reference
    covers: a dwell, once kept, stays kept (:attr:`n_dwells` is what :meth:`result` returns).
    Memory grows by about 22 kB per second of a tri-axial sensor and 136 bytes per reference
    pose.

    Parameters
    ----------
    layout : ChannelLayout or None
        None: no raw chunks, couplings are given demodulated (:meth:`add_couplings`).
    columns : sequence of int or None
        Columns of the demodulated coupling matrix that hold the sensor's coils.
    output_rate, window : demodulator settings
    t0 : float
        Tracker clock of the first raw sample (s; the backend's ``t0_epoch``).
    decimate : int
    max_offset : float, optional
        Search the offset within +-this many seconds.
    reference_complete : bool
        The whole reference is given at once (a CSV): the offset is searched over all of it.
    """

    def __init__(self, layout, columns=None, *, output_rate: float = 1500.0,
                 window: str = "hann", t0: float = 0.0, decimate: int = 5,
                 max_offset: float | None = None, reference_complete: bool = False):
        from ..signal import Demodulator

        self.demod = (None if layout is None else
                      Demodulator(layout, output_rate=output_rate, window=window, t0=t0))
        self.columns = None if columns is None else list(columns)
        self.decimate = max(1, int(decimate))
        self.t0 = float(t0)
        self.max_offset = max_offset
        self.reference_complete = bool(reference_complete)
        self._t = _Grow()
        self._C = None
        self._rest_t = np.empty(0)
        self._rest_C = None
        self._rt = _Grow()
        self._rB = _Grow((4, 4))
        self._pa, self._pb = _Profile("coupling"), _Profile("pose")
        self.n_reference = 0
        self.n_reference_out_of_order = 0
        self.offset: OffsetEstimate | None = None       # the latest estimate
        self.locked = False
        self._refined_at = None
        self._pending: list = []                       # tracker dwells (a, b) not yet paired
        self._n_closed_a = 0
        self._keep: list = []                          # (a, b, C, B, n_a, n_b)
        self.dropped = {"moved": 0, "no_reference": 0}

    # -- the streams
    def add_chunk(self, chunk) -> None:
        d = self.demod.process(chunk)
        if not len(d.times):
            return
        C = d.in_phase
        if self.columns is not None:
            C = C[:, :, self.columns]
        t = np.concatenate([self._rest_t, d.times])
        C = C if self._rest_C is None else np.concatenate([self._rest_C, C])
        m = len(t) // self.decimate * self.decimate
        if m:
            k = self.decimate
            self.add_couplings(t[:m].reshape(-1, k).mean(axis=1),
                               C[:m].reshape(-1, k, *C.shape[1:]).mean(axis=1))
        self._rest_t, self._rest_C = t[m:], C[m:]

    def add_couplings(self, times, couplings) -> None:
        """Couplings already demodulated (and averaged), with their times (s, increasing)."""
        C = np.asarray(couplings)
        if self._C is None:
            self._C = _Grow(C.shape[1:], C.dtype)
        self._t.extend(np.asarray(times, dtype=np.float64))
        self._C.extend(C)

    def add_reference(self, times, poses) -> None:
        """Reference poses (m) with their time stamps (s, increasing; a stamp not after the
        last one is counted in ``n_reference_out_of_order`` and left out)."""
        t = np.asarray(times, dtype=np.float64)
        if not len(t):
            return
        B = np.asarray(poses, dtype=np.float64).reshape(len(t), 4, 4)
        last = self._rt.v[-1] if len(self._rt) else -np.inf
        ok = np.diff(np.concatenate([[last], t])) > 0
        ok &= np.maximum.accumulate(np.where(ok, t, -np.inf)) <= t
        self.n_reference_out_of_order += int((~ok).sum())
        self._rt.extend(t[ok])
        self._rB.extend(B[ok])
        self.n_reference += int(ok.sum())

    @property
    def tracker_time(self) -> float | None:
        """Tracker clock of the latest averaged sample (s)."""
        return float(self._t.v[-1]) if len(self._t) else None

    def streams(self):
        """``(t_tracker, couplings, t_reference, reference_poses)`` so far (views)."""
        if not len(self._t) or not len(self._rt):
            return None
        return self._t.v, self._C.v, self._rt.v, self._rB.v

    def reference_frozen(self) -> bool:
        """The reference stayed static (over 99.5 % of its profile, at least 2 s) while the
        tracker moved (static over less than 95 % of its profile)."""
        pa, pb = self._pa, self._pb
        return (len(pb.static) * STEP >= 2.0 and len(pa.static) > 0
                and pb.static.v.mean() > 0.995 and pa.static.v.mean() < 0.95)

    def reference_span(self) -> float:
        """Seconds between the first and last reference pose."""
        return float(self._rt.v[-1] - self._rt.v[0]) if len(self._rt) else 0.0

    @property
    def n_dwells(self) -> int:
        """Dwells kept so far."""
        return len(self._keep)

    # -- the analysis
    def _estimate(self, *, refine: bool) -> OffsetEstimate | None:
        pa, pb = self._pa, self._pb
        na, nb = len(pa.motion), len(pb.motion)
        if na < 64 or nb < 64:
            return None
        ia = max(0, na - int((REFINE_WINDOW_S if refine else OFFSET_WINDOW_S) / STEP))
        ga, a = pa.times(ia), log_profile(pa.motion.v[ia:])
        if refine:
            c = self.offset.offset
            ib0 = max(0, pb.index(ga[0] + c - 2 * REFINE_S))
            ib1 = min(nb, pb.index(ga[-1] + c + 2 * REFINE_S) + 1)
            if ib1 - ib0 < 64:
                return None
            return time_offset_scan(ga, a, pb.times(ib0, ib1),
                                    log_profile(pb.motion.v[ib0:ib1]), max_offset=REFINE_S,
                                    center=c, min_overlap=0.0)
        ib = 0 if self.reference_complete else max(0, nb - int(2 * OFFSET_WINDOW_S / STEP))
        gb, b = pb.times(ib), log_profile(pb.motion.v[ib:])
        f = 10                                   # coarse search on a 20 ms grid, then fine
        ca, cb = len(a) // f, len(b) // f
        if ca < 8 or cb < 8:
            return None
        coarse = time_offset_scan(ga[:ca * f:f] + (f - 1) / 2 * STEP,
                                  a[:ca * f].reshape(ca, f).mean(axis=1),
                                  gb[:cb * f:f] + (f - 1) / 2 * STEP,
                                  b[:cb * f].reshape(cb, f).mean(axis=1),
                                  max_offset=self.max_offset)
        fine = time_offset_scan(ga, a, gb, b, max_offset=2 * f * STEP, center=coarse.offset)
        return fine._replace(runner_up=coarse.runner_up)

    def _sure(self, e: OffsetEstimate | None) -> bool:
        return (e is not None and e.correlation >= MIN_CORRELATION
                and e.confidence >= MIN_CONFIDENCE and e.overlap_s >= MIN_OVERLAP_S)

    def update(self, *, final: bool = False) -> None:
        """Analyse what arrived since the last call (``final``: the streams have ended)."""
        s = self.streams()
        if s is None:
            return
        tt, C, tr, B = s
        self._pa.update(tt, C)
        self._pb.update(tr, B)
        for a0, b0 in self._pa.closed[self._n_closed_a:]:
            g = self._pa.times(a0, b0 + 1)
            a, b = g[0] + MARGIN_S, g[-1] - MARGIN_S
            if b - a >= MIN_DWELL_S:
                self._pending.append((a0, b0))
        self._n_closed_a = len(self._pa.closed)
        t_now = self._pa.t_end
        if not self.locked:
            e = self._estimate(refine=False)
            if e is not None:
                self.offset = e
                self.locked = self._sure(e)
                self._refined_at = t_now
        elif t_now - self._refined_at >= REFINE_EVERY_S or final:
            e = self._estimate(refine=True)
            self._refined_at = t_now
            if e is not None and e.correlation >= MIN_CORRELATION:
                self.offset = e._replace(runner_up=self.offset.runner_up)
        if self.locked:
            self._pair(final)

    def _pair(self, final: bool) -> None:
        tt, C, tr, B = self.streams()
        pa, pb = self._pa, self._pb
        off = self.offset.offset
        still = []
        for a0, b0 in self._pending:
            lo = max(a0 - 1, 0)                 # a run from the start has no edge before it
            ga = pa.times(lo, b0 + 2)
            a, b = ga[0] + MARGIN_S, ga[-1] - MARGIN_S
            if pb.g0 is None or b + off >= pb.t_end:      # the reference is not there yet
                if final:
                    self.dropped["no_reference"] += 1
                else:
                    still.append((a0, b0))
                continue
            if b + off <= pb.g0:
                self.dropped["no_reference"] += 1
                continue
            i0 = max(pb.index(ga[0] + off), 0)
            i1 = min(pb.index(ga[-1] + off) + 2, len(pb.motion))
            sb = (np.interp(ga + off, pb.times(i0, i1), pb.static.v[i0:i1].astype(float),
                            left=0.0, right=0.0) > 0.999) if i1 - i0 >= 2 else False
            flag = pa.static.v[lo:b0 + 2] & sb
            kept = False
            for c, d in find_dwells(ga, flag):
                got = average_dwell(tt, C, tr, B, c, d, off)
                if got is not None:
                    self._keep.append((c, d, *got))
                    kept = True
            if not kept:
                self.dropped["no_reference" if a + off < pb.g0 else "moved"] += 1
        self._pending = still

    def result(self) -> DwellSet | None:
        """The dwells kept so far (None before the time offset is known)."""
        if self.offset is None:
            return None
        k = self._keep
        shape = self._C.v.shape[1:] if self._C is not None else (0, 0)
        e = self.offset
        return DwellSet(
            couplings=np.array([x[2] for x in k]).reshape(len(k), *shape),
            reference_poses=np.array([x[3] for x in k]).reshape(len(k), 4, 4),
            intervals=np.array([x[:2] for x in k], dtype=np.float64).reshape(len(k), 2),
            n_tracker_samples=np.array([x[4] for x in k], dtype=np.int64),
            n_reference_samples=np.array([x[5] for x in k], dtype=np.int64),
            time_offset=float(e.offset), offset_correlation=float(e.correlation),
            tracker_dwells=_long(self._pa.closed), reference_dwells=_long(self._pb.closed),
            dropped=dict(self.dropped))


def _long(runs) -> int:
    """Static runs long enough for a dwell."""
    return sum(1 for a, b in runs if (b - a) * STEP >= MIN_DWELL_S + 2 * MARGIN_S)
