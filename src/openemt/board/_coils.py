"""A board's coils as :class:`openemt.field.Coil` objects, so that the magpylib-based finite-coil
code (simulator truth, :class:`openemt.field.FiniteCoilModel`) uses the board's actual traces."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..field import Coil
from ._geometry import as_board

__all__ = ["board_coils"]


@dataclass(frozen=True, eq=False)
class _TraceCoil(Coil):
    """A :class:`Coil` of kind ``spiral`` whose current path is a given closed trace."""

    trace: np.ndarray = None

    def spiral_path(self) -> np.ndarray:
        return self.trace


def board_coils(board=None, gains=1.0) -> tuple:
    """The board's source coils (default: the built-in ``anser``) as ``Coil`` objects with the
    board's traces (magpylib polylines); ``gains`` scalar or one per coil (dipole gain units,
    docs/field-models.md)."""
    b = as_board(board)
    g = np.broadcast_to(np.asarray(gains, dtype=np.float64), (b.n_coils,))
    out = []
    for c, gi in zip(b.coils, g):
        path = c.local_path()
        path.setflags(write=False)
        turns = max(1, int(c.turns_per_layer))
        width = c.trace_width if c.trace_width > 0 else 1e-6
        out.append(_TraceCoil("spiral", c.center, c.rotation, max(c.outer_size),
                              length=c.layer_spacing, turns=turns, gain=float(gi),
                              trace_width=width, spacing=c.trace_spacing, layers=c.layers,
                              order=(1, 1, 1), trace=path))
    return tuple(out)
