"""Collecting a reference-pose dataset live: :class:`Collector` feeds the two streams as they
arrive; the pure array functions it analyses them with live in :mod:`openemt.align`."""

from __future__ import annotations

import numpy as np

from ..align import (
    DwellSet,
    collect_dwells,
)

__all__ = ["Collector"]


class Collector:
    """The two streams of a collection, fed as they arrive, analysed on demand.

    Raw chunks are demodulated (:class:`openemt.signal.Demodulator`) and the in-phase couplings
    of one sensor's columns averaged over ``decimate`` frames (300 per second at the default
    1500 frames/s); reference poses are appended with their time stamps. Memory grows by
    about 22 kB per second of a tri-axial sensor and 128 bytes per reference pose.

    Parameters
    ----------
    layout : ChannelLayout
    columns : sequence of int or None
        Columns of the demodulated coupling matrix that hold the sensor's coils.
    output_rate, window : demodulator settings
    t0 : float
        Tracker clock of the first raw sample (s; the backend's ``t0_epoch``).
    decimate : int
    """

    def __init__(self, layout, columns=None, *, output_rate: float = 1500.0,
                 window: str = "hann", t0: float = 0.0, decimate: int = 5):
        from ..signal import Demodulator

        self.demod = Demodulator(layout, output_rate=output_rate, window=window, t0=t0)
        self.columns = None if columns is None else list(columns)
        self.decimate = max(1, int(decimate))
        self.t0 = float(t0)
        self._t: list = []
        self._C: list = []
        self._rest_t = np.empty(0)
        self._rest_C = None
        self._rt: list = []
        self._rB: list = []
        self.n_frames = 0
        self.n_reference = 0

    def add_chunk(self, chunk) -> None:
        d = self.demod.process(chunk)
        if not len(d.times):
            return
        C = d.in_phase
        if self.columns is not None:
            C = C[:, :, self.columns]
        self.n_frames += len(d.times)
        t = np.concatenate([self._rest_t, d.times])
        C = C if self._rest_C is None else np.concatenate([self._rest_C, C])
        m = len(t) // self.decimate * self.decimate
        if m:
            k = self.decimate
            self._t.append(t[:m].reshape(-1, k).mean(axis=1))
            self._C.append(C[:m].reshape(-1, k, *C.shape[1:]).mean(axis=1))
        self._rest_t, self._rest_C = t[m:], C[m:]

    def add_reference(self, times, poses) -> None:
        t = np.asarray(times, dtype=np.float64)
        if len(t):
            self._rt.append(t)
            self._rB.append(np.asarray(poses, dtype=np.float64).reshape(len(t), 4, 4))
            self.n_reference += len(t)

    def _joined(self):
        if len(self._t) > 1:
            self._t, self._C = [np.concatenate(self._t)], [np.concatenate(self._C)]
        if len(self._rt) > 1:
            t, B = np.concatenate(self._rt), np.concatenate(self._rB)
            order = np.argsort(t, kind="stable")
            t, B = t[order], B[order]
            keep = np.concatenate([[True], np.diff(t) > 0])   # repeated stamps: first kept
            self._rt, self._rB = [t[keep]], [B[keep]]

    @property
    def tracker_time(self) -> float | None:
        """Tracker clock of the latest averaged sample (s)."""
        return float(self._t[-1][-1]) if self._t else None

    @property
    def reference_time(self) -> float | None:
        """Reference clock of the latest reference pose (s)."""
        self._joined()
        return float(self._rt[0][-1]) if self._rt else None

    def streams(self):
        """``(t_tracker, couplings, t_reference, reference_poses)`` so far."""
        self._joined()
        if not self._t or not self._rt:
            return None
        return self._t[0], self._C[0], self._rt[0], self._rB[0]

    def analyse(self, *, time_offset=None, max_offset=None) -> DwellSet | None:
        """:func:`collect_dwells` of everything so far (None while either stream has less
        than a second)."""
        s = self.streams()
        if s is None or s[0][-1] - s[0][0] < 1.0 or s[2][-1] - s[2][0] < 1.0 \
                or len(s[2]) < 4:
            return None
        return collect_dwells(*s, time_offset=time_offset, max_offset=max_offset)
