"""The layout search of a rig source (dipole model): each source coil's position, within a
box about its start, and its moment (direction and size), for a fixed total drive power
(docs/design.md#rig-sources).

The coils are the start's (same windings): a coil's moment is its current times its
turns-area, and its drive power ``I^2 R``, so at fixed windings the power of coil ``i`` is
proportional to ``|m_i|^2`` and the total power constraint is ``sum |m_i|^2 = sum |m_i0|^2``.
The search's vector is ``[offset_i (3), v_i (3)]`` per coil; the moments are the ``v_i``
scaled together to the start's ``sum |m_i|^2`` (so the constraint holds exactly, and a
coil can take power from another). The sensor is the start's. The dipole model has no coil
extent: no spacing constraint, the box is the placement constraint.
"""

from __future__ import annotations

import numpy as np

from ._crb import pose_bound
from ._search import _Search

__all__ = []


class _RigLayout(_Search):
    N = 6

    def __init__(self, model, points, rotations, sigma, statistic, box):
        super().__init__(points, rotations, sigma, statistic)
        self.model = model
        self.box = float(box)
        self.power = float(np.sum(model.M_so ** 2))

    def vector(self) -> np.ndarray:
        return np.concatenate([np.zeros((self.model.n_source, 3)), self.model.M_so.T],
                              axis=1).ravel()

    def model_of(self, x):
        v = np.asarray(x).reshape(-1, self.N)
        M = v[:, 3:].T * np.sqrt(self.power / max(np.sum(v[:, 3:] ** 2), 1e-300))
        return self.model.replace(L_so=self.model.L_so + v[:, :3].T, M_so=M)

    def penalty(self, x) -> float:
        return 0.0 if np.any(np.asarray(x).reshape(-1, self.N)[:, 3:]) else 1.0

    def position_std(self, x) -> np.ndarray:
        return pose_bound(self.model_of(x), self.poses, self.sigma).position_std

    def bounds(self):
        """(scale, lo, hi) of the search: offsets in units of 10 mm within the box, moment
        components in units of a tenth of the largest start moment, each within +-1.5 of
        it."""
        x0 = self.vector()
        mmax = float(np.max(np.linalg.norm(self.model.M_so, axis=0)))
        off = np.arange(x0.size) % self.N < 3
        scale = np.where(off, 0.01, 0.1 * mmax)
        lo = np.where(off, -self.box, -1.5 * mmax)
        hi = np.where(off, self.box, 1.5 * mmax)
        return x0, scale, lo, hi
