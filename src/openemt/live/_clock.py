"""The ADC's sample clock against the host's: sample index -> UTC, with the drift estimated
online (docs/live.md#time).

A frame whose last sample has index ``s`` arrives at host time ``t >= T(s) + d_min``: the
sample's true time plus the shortest transport delay; any extra delay (USB polling, the
scheduler, bursts of frames read at once) only makes it later. :class:`SampleClock` therefore
fits the *lower envelope* of the arrival times: the points are split into bins of equal sample
span, the earliest arrival of each bin is kept, and the edge of their lower convex hull above
the mean sample time gives the ADC's sample period in host seconds (its drift against the
host, in ppm of the nominal clock; a robust fit: late arrivals, even a backlog drained over
seconds, lie above the hull and cannot tilt it); the line is then moved down onto the
earliest point. ``T(s)`` carries the
constant ``d_min`` (unknown without an outside reference; micro- to milliseconds on USB and
loopback TCP): the acquisition time it gives is an upper bound of the true one, never earlier.
"""

from __future__ import annotations

import collections

import numpy as np

__all__ = ["SampleClock"]


def _envelope_slope(x, y, at: float):
    """Slope of the lower convex hull of the points ``(x, y)`` (x increasing) where it passes
    ``at``: the line below every point that is highest at ``at`` (the linear programme of
    Moon, Skelly and Towsley 1999 for clock skew, which late points cannot pull up)."""
    hull: list = []
    for p in zip(x.tolist(), y.tolist()):
        while len(hull) >= 2:
            (x1, y1), (x2, y2) = hull[-2], hull[-1]
            if (x2 - x1) * (p[1] - y1) - (y2 - y1) * (p[0] - x1) <= 0:
                hull.pop()                              # not a left turn: not on the hull
            else:
                break
        hull.append(p)
    for (x1, y1), (x2, y2) in zip(hull, hull[1:]):
        if x1 <= at <= x2 and x2 > x1:
            return (y2 - y1) / (x2 - x1)
    return None


class SampleClock:
    """Online fit ``UTC = a + k t`` of session time ``t`` (s, sample index / nominal rate).

    Parameters
    ----------
    sample_rate : float
        Nominal ADC rate (Hz).
    window : float
        Seconds of frames the fit uses (older ones are forgotten: the drift may change).
    refit_every : float
        Seconds of samples between refits (the per-frame cost is an append).
    bins : int
        Lower-envelope bins of the window.
    max_drift_ppm : float
        Largest drift believed (crystal clocks: tens of ppm); a larger fitted one is clamped
        and reported (``drift_clamped``).
    """

    def __init__(self, sample_rate: float, *, window: float = 20.0, refit_every: float = 0.25,
                 bins: int = 64, max_drift_ppm: float = 1000.0):
        self.fs = float(sample_rate)
        self.window = float(window)
        self.refit_every = float(refit_every)
        self.bins = int(bins)
        self.max_drift_ppm = float(max_drift_ppm)
        self.clamped = False
        self._s: collections.deque = collections.deque()
        self._t: collections.deque = collections.deque()
        self.a = None          # UTC of session time 0 (s)
        self.k = 1.0           # host seconds per nominal ADC second
        self._next_fit = 0.0
        self.resets = 0

    def reset(self) -> None:
        """Forget the points (a restarted ADC: a new counter origin and phase)."""
        self._s.clear()
        self._t.clear()
        self.a, self.k, self._next_fit, self.clamped = None, 1.0, 0.0, False
        self.resets += 1

    def add(self, end_time: float, arrival: float) -> None:
        """A frame whose samples end at session time ``end_time`` arrived at UTC ``arrival``."""
        s, t = self._s, self._t
        s.append(end_time)
        t.append(arrival)
        while end_time - s[0] > self.window:
            s.popleft()
            t.popleft()
        if self.a is None:
            self.a = arrival - end_time
        elif end_time >= self._next_fit:
            self.fit()
        else:
            self.a = min(self.a, arrival - self.k * end_time)   # the envelope only moves down

    def fit(self) -> None:
        s = np.fromiter(self._s, float, len(self._s))
        t = np.fromiter(self._t, float, len(self._t))
        self._next_fit = s[-1] + self.refit_every
        r = t - s                                       # arrival minus nominal time
        k = self.k
        if s[-1] - s[0] >= 1.0 and len(s) >= 4 * self.bins:
            edges = np.linspace(s[0], s[-1], self.bins + 1)
            b = np.clip(np.searchsorted(edges, s, side="right") - 1, 0, self.bins - 1)
            order = np.lexsort((r, b))                  # by bin, then residual
            first = np.flatnonzero(np.r_[True, b[order][1:] != b[order][:-1]])
            pick = np.sort(order[first])                # the earliest arrival of each bin
            # the hull edge over the newer half: a backlog drained at the start (a reader
            # that started late) lies above it
            at = s[0] + 0.75 * (s[-1] - s[0])
            slope = _envelope_slope(s[pick], r[pick], at)
            if slope is not None:
                lim = 1e-6 * self.max_drift_ppm
                self.clamped = abs(slope) > lim
                k = 1.0 + min(max(slope, -lim), lim)
        self.k = k
        recent = s >= s[0] + 0.5 * (s[-1] - s[0])      # the samples being stamped now
        self.a = float(np.min(t[recent] - k * s[recent]))

    def utc(self, times):
        """UTC (epoch s) of session times ``times`` (s)."""
        return self.a + self.k * np.asarray(times, dtype=np.float64)

    @property
    def drift_ppm(self) -> float | None:
        """The ADC's sample period against nominal, in ppm of host time (positive: its clock
        is slow, each sample takes longer); None before a fit over at least 1 s."""
        if self.a is None or self.k == 1.0:
            return None
        return (self.k - 1.0) * 1e6

    def to_dict(self) -> dict:
        return {"drift_ppm": self.drift_ppm,
                "measured_sample_rate_hz": None if self.drift_ppm is None
                else self.fs / self.k,
                "drift_clamped": self.clamped,
                "fit_seconds": (self._s[-1] - self._s[0]) if self._s else 0.0,
                "clock_restarts": self.resets}
