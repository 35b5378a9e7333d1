"""The coupling model of a board: its finite coils (straight segments) with per-coil gains,
position offsets and small tilts, read by a single-coil (5-DOF) sensor.

``C_i(p, u) = g_i * mean over the sensor length of B_i(p + s u) . u`` where ``B_i`` is the field
(T for 1 A) of coil ``i`` moved by its offset ``delta_i`` and turned by its tilt ``tau_i`` (a
rotation vector, about the coil centre), computed segment by segment
(:func:`openemt.field._segments.segment_coupling`). The gain ``g_i`` carries the coil current
and the sensor's sensitivity, so couplings have the units of the measurements (tesla for the
Anser board's calibrated data).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from .._errors import InputError
from ._geometry import Board, as_board

__all__ = ["DipoleOnlyError", "PlanarModel", "dipole_only"]


class DipoleOnlyError(InputError, AttributeError):
    """A dipole model's (or dipole calibration's) attribute asked of a finite-coil board: bad
    input for the command that asked (an ``InputError``), a missing attribute to ``hasattr``."""


def dipole_only(name: str) -> DipoleOnlyError:
    """The error for a dipole-only attribute ``name`` asked of a board model or calibration."""
    if name.startswith("__"):
        return AttributeError(name)
    return DipoleOnlyError(f"expected a dipole-model calibration (this use needs its {name!r}), "
                           f"got a finite-coil board calibration: use it with `openemt info`, "
                           f"`solve`, `report` or `track` (docs/planar.md)")


@dataclass(frozen=True, eq=False)
class PlanarModel:
    """A board with per-coil gains ``(n,)``, offsets ``(n, 3)`` (m) and tilts ``(n, 3)``
    (rotation vectors, rad). Build with :meth:`from_board`."""

    board: Board
    gains: np.ndarray
    offsets: np.ndarray
    tilts: np.ndarray

    def __post_init__(self):
        n = self.board.n_coils
        for name, shape in (("gains", (n,)), ("offsets", (n, 3)), ("tilts", (n, 3))):
            a = np.array(getattr(self, name), dtype=np.float64)
            if a.shape != shape or not np.all(np.isfinite(a)):
                raise InputError(f"expected finite `{name}` of shape {shape}, got {a.shape}")
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        if self.board.sensor.kind != "single":
            raise InputError(f"expected a single-coil (5-DOF) sensor in the board, got "
                             f"{self.board.sensor.kind!r}")
        segs, off = [], [0]
        for c, d, t in zip(self.board.coils, self.offsets, self.tilts):
            s = c.segments()
            if np.any(t != 0):
                s = (s - c.center) @ Rotation.from_rotvec(np.array(t)).as_matrix().T + c.center
            segs.append(s + d)
            off.append(off[-1] + len(s))
        S = np.ascontiguousarray(np.concatenate(segs))
        o = np.asarray(off, dtype=np.int64)
        S.setflags(write=False)
        o.setflags(write=False)
        object.__setattr__(self, "segments", S)
        object.__setattr__(self, "segment_offsets", o)

    def __getattr__(self, name):
        # only reached for attributes a board model lacks: those of a dipole model
        raise dipole_only(name)

    @classmethod
    def from_board(cls, board=None, gains=1.0, offsets=None, tilts=None) -> PlanarModel:
        """A model of ``board`` (a :class:`Board` or built-in name; default ``anser``; a file:
        :func:`openemt.io.load_board`)."""
        b = as_board(board)
        n = b.n_coils
        return cls(b, np.broadcast_to(np.asarray(gains, np.float64), (n,)),
                   np.zeros((n, 3)) if offsets is None else offsets,
                   np.zeros((n, 3)) if tilts is None else tilts)

    def replace(self, **kw) -> PlanarModel:
        d = {"board": self.board, "gains": self.gains, "offsets": self.offsets,
             "tilts": self.tilts, **kw}
        return PlanarModel(**d)

    @property
    def n_coils(self) -> int:
        return self.board.n_coils

    @property
    def sensor_length(self) -> float:
        return self.board.sensor.length

    def coupling(self, points, axes, *, gradient=False):
        """Couplings ``(N, n_coils)`` into sensors at ``points (N, 3)`` with ``axes (N, 3)``;
        with ``gradient=True`` also ``dC/dp`` and ``dC/du``, each ``(N, n_coils, 3)``."""
        from ..field._segments import segment_coupling

        return segment_coupling(self.segments, self.segment_offsets, self.gains, points, axes,
                                sensor_length=self.sensor_length, gradient=gradient)

    def coupling_poses(self, poses) -> np.ndarray:
        """Couplings ``(N, n_coils, 1)`` for sensor poses ``(N, 4, 4)`` (sensor axis = z)."""
        P = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
        return self.coupling(P[:, :3, 3], P[:, :3, 2])[:, :, None]
