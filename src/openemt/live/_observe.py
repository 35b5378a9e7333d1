"""A read-only observer of a tracking session (a live view, :mod:`openemt.view`).

The session hands an *observer* what it already has, block by block, and never waits for it:

- ``observer.start(layout)`` once, with the source's :class:`~openemt.signal.ChannelLayout`;
- ``observer.sensors(names)`` once, with the sensor names in tracker order;
- ``observer.raw(chunk)`` after every read, with the raw samples ``(n, n_channels)``;
- ``observer.step(step, sensor)`` after every processed chunk of every sensor, with its
  :class:`~openemt.live.TrackStep` (the arrays the log gets).

Nobody writes into these arrays afterwards (a backend hands out a new array, or a slice of
memory it never writes again, per read; the raw recorder and the log keep references the
same way), so an observer may keep references; it must not write into them. Each call must
be cheap (a reference appended under a lock: about a microsecond): the view does its own
work in its own thread. Nothing flows back: the observer cannot change the
session.
"""

from __future__ import annotations

from ._backends import BackendWrapper

__all__ = ["ObservedLog", "ObservedSource"]


class ObservedSource(BackendWrapper):
    """A backend whose every raw chunk is also handed to ``observer.raw``."""

    def __init__(self, backend, observer):
        super().__init__(backend)
        self.observer = observer
        observer.start(backend.layout)

    def read(self):
        chunk = self.backend.read()
        if chunk is not None and len(chunk):
            self.observer.raw(chunk)
        return chunk


class ObservedLog:
    """The pipeline's log slot: every processed chunk goes to ``observer.step`` and to the
    session's own log (a :class:`~openemt.live.TrackLogWriter`, or None)."""

    def __init__(self, log, observer):
        self.log = log
        self.observer = observer

    def set_sensors(self, names) -> None:
        if self.log is not None:
            self.log.set_sensors(names)
        self.observer.sensors(tuple(names))

    def append(self, step, sensor: int = 0) -> None:
        if self.log is not None:
            self.log.append(step, sensor)
        if step.times.shape[0]:             # (no Python-level len(): once per block)
            self.observer.step(step, sensor)
