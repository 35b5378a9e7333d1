"""``collect --source sim --follow-reference``: the simulated tracker moves with the poses an
external reference reports, so any reference can be tried end to end without EM hardware."""

from __future__ import annotations

import threading
import time

import numpy as np

from ..geometry import invert

__all__ = ["Follower"]


class Follower:
    """The sensor poses ``P = Y B X^-1`` of the reference poses ``B`` as they arrive.

    A simulated tracker samples :meth:`sensor_poses` at its own times ``tau`` (s from its
    start ``t0``, simulated seconds at ``speed`` per wall second); each gets the latest
    reference pose received by wall time ``t0 + tau / speed`` (the reference's own latency and
    clock stay, for :class:`~openemt.collect.Collector` to find). Until the first pose arrives
    the sensor rests at ``rest``.

    Parameters
    ----------
    X, Y : (4, 4)
        Reference tool -> sensor and reference frame -> source frame (the simulated robot's,
        by default).
    rest : (4, 4)
        Sensor pose before the first reference pose.
    """

    def __init__(self, X, Y, rest, *, speed: float = 1.0):
        self.X_inv, self.Y = invert(np.asarray(X, float)), np.asarray(Y, float)
        self.rest = np.asarray(rest, float)
        self.speed = float(speed)
        self.t0: float | None = None
        self.client = None
        self._lock = threading.Lock()
        self._recv = np.empty(0)
        self._P = np.empty((0, 4, 4))
        self._out_t, self._out_B = [], []

    def pull(self) -> None:
        """Move the client's new poses here (their receipt times, and a copy for the
        collector: :meth:`take`)."""
        if self.client is None:
            return
        t, B, recv = self.client.take(receipts=True)
        if not len(t):
            return
        self._out_t.append(t)
        self._out_B.append(B)
        P = self.Y @ B @ self.X_inv
        with self._lock:
            keep = max(0, len(self._recv) - 4096)          # a bounded history
            self._recv = np.concatenate([self._recv[keep:], recv])
            self._P = np.concatenate([self._P[keep:], P])

    def take(self):
        """The reference poses pulled since the last call, for the collector."""
        t, B = self._out_t, self._out_B
        self._out_t, self._out_B = [], []
        if not t:
            return np.empty(0), np.empty((0, 4, 4))
        return np.concatenate(t), np.concatenate(B)

    def sensor_poses(self, tau) -> np.ndarray:
        tau = np.atleast_1d(np.asarray(tau, dtype=np.float64))
        if self.t0 is None:
            self.t0 = time.time() - float(tau[0]) / self.speed
        self.pull()
        with self._lock:
            recv, P = self._recv, self._P
        if not len(recv):
            return np.broadcast_to(self.rest, (len(tau), 4, 4)).copy()
        k = np.searchsorted(recv, self.t0 + tau / self.speed, "right") - 1
        out = P[np.clip(k, 0, len(P) - 1)].copy()
        out[k < 0] = self.rest
        return out
