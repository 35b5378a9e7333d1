"""What every reference pose passes before a collection uses it, wherever it comes from (an
OpenIGTLink message or a CSV row): a rigid rotation block and a time stamp that continues the
stream. Every pose turned away is counted by reason (:class:`Drops`)."""

from __future__ import annotations

import math
from collections import Counter

import numpy as np

__all__ = ["MAX_STEP_S", "ROTATION_TOL", "Drops", "TimeGate", "rigid_rows"]

#: A rotation block R is taken when ``max |R^T R - I| <= ROTATION_TOL`` and ``det R > 0`` (a
#: float32 matrix of a true rotation is within 1e-6; a block scaled by 1.01 is 2e-2 off); it is
#: never projected onto the nearest rotation.
ROTATION_TOL = 1e-4
#: Reference time stamps more than this far beyond the last one taken (s) are a glitch when the
#: next stamp continues the old clock, and a jump of the reference's clock when it continues
#: the new one.
MAX_STEP_S = 2.0


class Drops(Counter):
    """Reference poses turned away, by reason (``reason -> count``)."""

    def to_dict(self) -> dict:
        return {k: int(v) for k, v in sorted(self.items()) if v}


def rigid_rows(M) -> np.ndarray:
    """For matrices (N, 4, 4): which are finite rigid transforms (rotation block within
    :data:`ROTATION_TOL` of orthonormal with determinant +1, last row ``[0, 0, 0, 1]``)."""
    M = np.asarray(M, dtype=np.float64).reshape(-1, 4, 4)
    finite = np.all(np.isfinite(M), axis=(1, 2))
    Mf = np.where(finite[:, None, None], M, np.eye(4))
    R = Mf[:, :3, :3]
    off = np.abs(np.swapaxes(R, 1, 2) @ R - np.eye(3)).max(axis=(1, 2))
    last = np.abs(Mf[:, 3] - [0.0, 0.0, 0.0, 1.0]).max(axis=1)
    return finite & (off <= ROTATION_TOL) & (np.linalg.det(R) > 0) & (last <= ROTATION_TOL)


class TimeGate:
    """Time stamps of one reference stream, one at a time: each is taken, or turned away with a
    reason counted in ``drops``.

    A stamp that is not finite, or not after the last one taken, is dropped. A stamp more than
    ``max_step`` beyond the last one taken is held: when the next stamp continues the old clock
    it was a glitch (dropped); when the next continues from it, the reference's clock jumped and
    the stream ends there (:attr:`jumped` says by how much; later stamps are dropped as
    ``after_clock_jump``), since poses on either side of a jump cannot share one time offset.
    """

    def __init__(self, drops: Drops, max_step: float = MAX_STEP_S):
        self.drops, self.max_step = drops, float(max_step)
        self.last: float | None = None
        self.jumped: float | None = None
        self._held: float | None = None

    def take(self, t: float) -> bool:
        """Whether the stamp ``t`` is taken (the caller keeps its pose then)."""
        if self.jumped is not None:
            self.drops["after_clock_jump"] += 1
            return False
        if not math.isfinite(t):
            self.drops["time_not_finite"] += 1
            return False
        if self._held is not None:
            held, self._held = self._held, None
            if held < t <= held + self.max_step:
                self.jumped = held - self.last
                self.drops["clock_jump"] += 2
                return False
            self.drops["time_glitch"] += 1
        if self.last is not None:
            if t <= self.last:
                self.drops["time_not_increasing"] += 1
                return False
            if t > self.last + self.max_step:
                self._held = t
                return False
        self.last = t
        return True

    def finish(self) -> None:
        """The stream ended: a stamp still held was a glitch."""
        if self._held is not None:
            self._held = None
            self.drops["time_glitch"] += 1
