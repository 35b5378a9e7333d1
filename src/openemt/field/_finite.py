"""Coupling between finite source and sensor coils (physical ground truth for simulation).

``C[k, i, j] = gain * g_j * sum_q w_jq B_i(R x_jq + t) . (R a_j)`` where ``B_i`` is source coil
i's field in dipole gain units (:func:`~openemt.field.coil_fields`), ``x_jq, w_jq`` the sensor
coil j's area quadrature (sensor coordinates), ``a_j`` its axis and ``g_j`` its gain, and
``(R, t)`` the pose (sensor -> source coordinates). In the limit of small coils at large
distance this is exactly :meth:`FiniteCoilModel.dipole_equivalent`'s dipole coupling.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._errors import InputError
from ._coils import _check_coils, _coil_fields, _gain
from ._dipole import ILEMT_GAIN, DipoleModel, _split

__all__ = ["FiniteCoilModel"]

#: Observer points handled per block of poses in :meth:`FiniteCoilModel.coupling`.
_POINTS_PER_BLOCK = 200_000


@dataclass(frozen=True, eq=False)
class FiniteCoilModel:
    """Finite source coils (source coordinates) and sensor coils (sensor coordinates).

    Parameters
    ----------
    sources : sequence of Coil
        Source coils, in source coordinates.
    sensors : sequence of Coil
        Sensor coils, in sensor coordinates.
    gain : float
        Overall coupling scale (``1/250``, the ILEMT convention of :class:`DipoleModel`).
    chunk : int
        Work size (filament x point evaluations) per ``magpylib.getB`` call; bounds memory.
    """

    sources: tuple
    sensors: tuple
    gain: float = ILEMT_GAIN
    chunk: int = 400_000

    def __post_init__(self):
        object.__setattr__(self, "sources", _check_coils(self.sources, "sources"))
        object.__setattr__(self, "sensors", _check_coils(self.sensors, "sensors"))
        object.__setattr__(self, "gain", _gain(self.gain))
        if isinstance(self.chunk, bool) or not isinstance(self.chunk, (int, np.integer)) \
                or self.chunk < 1:
            raise InputError(f"expected a positive integer `chunk`, got {self.chunk!r}")
        # sensor quadrature, concatenated over sensor coils (cached geometry of each coil)
        quads = [c.sensor_quadrature() for c in self.sensors]
        pts = np.concatenate([q[0] for q in quads])
        n_se = len(self.sensors)
        W = np.zeros((n_se, len(pts)))
        a = 0
        for j, (p, w) in enumerate(quads):
            W[j, a:a + len(p)] = w * self.sensors[j].gain
            a += len(p)
        axes = np.stack([c.axis for c in self.sensors])
        for name, val in (("_points", pts), ("_weights", W), ("_axes", axes)):
            val.setflags(write=False)
            object.__setattr__(self, name, val)

    @property
    def n_source(self) -> int:
        return len(self.sources)

    @property
    def n_sensor(self) -> int:
        return len(self.sensors)

    def coupling(self, poses) -> np.ndarray:
        """Couplings ``(N, n_source, n_sensor)`` for sensor poses ``(N, 4, 4)`` (sensor ->
        source coordinates).

        Each sensor coil's response is the flux-weighted mean of the source field over the
        area of its turns (sensor quadrature), times its gain, times ``gain``.
        """
        R, t = _split(poses)
        n, m = R.shape[0], len(self._points)
        C = np.empty((n, self.n_source, self.n_sensor))
        block = max(1, _POINTS_PER_BLOCK // m)           # poses per block: bounds memory
        for a in range(0, n, block):
            Rb, tb = R[a:a + block], t[a:a + block]
            obs = np.einsum("kab,mb->kma", Rb, self._points) + tb[:, None, :]   # (n, M, 3)
            B = _coil_fields(self.sources, obs.reshape(-1, 3), self.chunk).reshape(
                self.n_source, len(Rb), m, 3)
            Bmean = np.einsum("jm,ikma->kija", self._weights, B)    # (n, n_so, n_se, 3)
            normals = np.einsum("kab,jb->kja", Rb, self._axes)       # (n, n_se, 3)
            C[a:a + block] = self.gain * np.einsum("kija,kja->kij", Bmean, normals)
        return C

    def dipole_equivalent(self) -> DipoleModel:
        """The dipole model of equal moments: coil centres and ``gain * axis`` per coil."""
        return DipoleModel(
            L_so=np.stack([c.center for c in self.sources], axis=1),
            M_so=np.stack([c.moment for c in self.sources], axis=1),
            L_se=np.stack([c.center for c in self.sensors], axis=1),
            M_se=np.stack([c.moment for c in self.sensors], axis=1),
            gain=self.gain)
