"""The coupling model of a board: its finite coils (straight segments) with per-coil gains,
position offsets and small tilts, read by the board file's sensor (one coil: 5-DOF; two or
three coils: 6-DOF).

``C_ik(p, u) = g_i s_k * mean over the sensor length of B_i(p + s u) . u`` for sensor coil ``k``
at ``p`` with axis ``u`` where ``B_i`` is the field
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

__all__ = ["DipoleOnlyError", "BoardModel", "dipole_only"]


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
class BoardModel:
    """A board with per-coil gains ``(n,)``, offsets ``(n, 3)`` (m) and tilts ``(n, 3)``
    (rotation vectors, rad), read by the board file's sensor: one coil (5-DOF) or several
    (6-DOF), each with a relative gain ``sensor_gains (n_sensor,)`` (the first is 1, the gauge
    of the common scale). Build with :meth:`from_board`.

    It is a coupling model like every other (:class:`openemt.field.CouplingModel`):
    ``coupling(poses) -> (N, n_coils, n_sensor)`` where sensor coil ``k`` sits at
    ``R l_k + t`` with axis ``R a_k`` (``l_k``, ``a_k`` from the board file's sensor).
    """

    board: Board
    gains: np.ndarray
    offsets: np.ndarray
    tilts: np.ndarray
    sensor_gains: np.ndarray | None = None
    kind = "finite"

    def __post_init__(self):
        n = self.board.n_coils
        ne = self.board.sensor.n_coils
        if self.sensor_gains is None:
            object.__setattr__(self, "sensor_gains", np.ones(ne))
        for name, shape in (("gains", (n,)), ("offsets", (n, 3)), ("tilts", (n, 3)),
                            ("sensor_gains", (ne,))):
            a = np.array(getattr(self, name), dtype=np.float64)
            if a.shape != shape or not np.all(np.isfinite(a)):
                raise InputError(f"expected finite `{name}` of shape {shape}, got {a.shape}")
            a.setflags(write=False)
            object.__setattr__(self, name, a)
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
        # only reached for attributes a board model lacks: a dipole model's attribute is bad
        # input for the use that asked (DipoleOnlyError), anything else a plain AttributeError
        from ..field import DipoleModel

        if not name.startswith("_") and hasattr(DipoleModel, name) or name in (
                "L_so", "M_so", "L_se", "M_se", "gain"):
            raise dipole_only(name)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    @property
    def solver_family(self) -> str:
        """``'planar'`` (the compiled 5-DOF solver) for a single-coil sensor, else ``'board'``
        (the compiled 6-DOF LM; docs/field-models.md#the-model-interface)."""
        return "planar" if self.n_sensor == 1 else "board"

    @classmethod
    def from_board(cls, board=None, gains=1.0, offsets=None, tilts=None,
                   sensor_gains=None) -> BoardModel:
        """A model of ``board`` (a :class:`Board` or built-in name; default ``anser``; a file:
        :func:`openemt.io.load_board`)."""
        b = as_board(board)
        n = b.n_coils
        return cls(b, np.broadcast_to(np.asarray(gains, np.float64), (n,)),
                   np.zeros((n, 3)) if offsets is None else offsets,
                   np.zeros((n, 3)) if tilts is None else tilts, sensor_gains)

    def replace(self, **kw) -> BoardModel:
        d = {"board": self.board, "gains": self.gains, "offsets": self.offsets,
             "tilts": self.tilts, "sensor_gains": self.sensor_gains, **kw}
        if d["board"].sensor.n_coils != self.board.sensor.n_coils and "sensor_gains" not in kw:
            d["sensor_gains"] = None
        return BoardModel(**d)

    @property
    def n_coils(self) -> int:
        return self.board.n_coils

    @property
    def n_source(self) -> int:
        return self.board.n_coils

    @property
    def n_sensor(self) -> int:
        return self.board.sensor.n_coils

    @property
    def dof(self) -> int:
        """5 for a single sensor coil (no roll about its axis), 6 for several non-parallel ones."""
        a = self.board.sensor.coil_axes()
        return 6 if len(a) > 1 and np.linalg.matrix_rank(a, tol=1e-9) >= 2 else 5

    @property
    def front(self) -> np.ndarray:
        """The common coil normal of a planar board (its front side, the default hemisphere),
        zeros when the coils face different ways."""
        normals = np.stack([c.normal for c in self.board.coils])
        return normals[0].copy() if np.allclose(normals, normals[0], atol=1e-9) \
            else np.zeros(3)

    @property
    def sensor_length(self) -> float:
        return self.board.sensor.length

    def coupling_points(self, points, axes, *, gradient=False):
        """Couplings ``(N, n_coils)`` into single sensor coils at ``points (N, 3)`` with
        ``axes (N, 3)`` (no sensor gain); with ``gradient=True`` also ``dC/dp`` and ``dC/du``,
        each ``(N, n_coils, 3)``."""
        from ..field._segments import segment_coupling

        return segment_coupling(self.segments, self.segment_offsets, self.gains, points, axes,
                                sensor_length=self.sensor_length, gradient=gradient)

    def _sensor_coils(self, poses):
        from ..geometry import check_poses

        P = np.asarray(check_poses(poses), dtype=np.float64).reshape(-1, 4, 4)
        R, t = P[:, :3, :3], P[:, :3, 3]
        L = self.board.sensor.coil_positions()
        A = self.board.sensor.coil_axes()
        q = np.einsum("nab,kb->nka", R, L)                       # (N, n_sensor, 3)
        return q + t[:, None, :], q, np.einsum("nab,kb->nka", R, A)

    def coupling(self, poses) -> np.ndarray:
        """Couplings ``(N, n_coils, n_sensor)`` for sensor poses ``(N, 4, 4)``."""
        p, _, u = self._sensor_coils(poses)
        C = np.empty((p.shape[0], self.n_source, self.n_sensor))
        for k in range(self.n_sensor):
            C[:, :, k] = self.sensor_gains[k] * self.coupling_points(p[:, k], u[:, k])
        return C

    # -- the coupling-model interface (openemt.field.CouplingModel) ------------------------
    def _slices(self):
        n, ne = self.n_source, self.n_sensor
        return {"gains": slice(0, n), "offsets": slice(n, 4 * n),
                "tilts": slice(4 * n, 7 * n), "sensor_gains": slice(7 * n, 7 * n + ne)}

    @property
    def params(self) -> np.ndarray:
        """``[gains | offsets (coil by coil) | tilts (coil by coil) | sensor_gains]``."""
        return np.concatenate([self.gains, self.offsets.ravel(), self.tilts.ravel(),
                               self.sensor_gains])

    def with_params(self, x) -> BoardModel:
        return BoardModel(self.board, **self.split_params(x))

    def split_params(self, x) -> dict:
        x = np.asarray(x, dtype=np.float64)
        sl = self._slices()
        return {"gains": x[sl["gains"]], "offsets": x[sl["offsets"]].reshape(-1, 3),
                "tilts": x[sl["tilts"]].reshape(-1, 3), "sensor_gains": x[sl["sensor_gains"]]}

    @property
    def parameter_groups(self) -> dict:
        """``gains``, ``offsets``, ``tilts``, ``sensor_gains`` (all but the first) and
        ``frame`` (coil 0's offset and tilt: held when the board's frame is itself fitted, as
        by a reference calibration's Y)."""
        sl = self._slices()
        g = {k: np.arange(s.start, s.stop) for k, s in sl.items()}
        g["sensor_gains"] = g["sensor_gains"][1:]
        g["frame"] = np.concatenate([g["offsets"][:3], g["tilts"][:3]])
        # tilts out of each coil's plane (turning a coil about its own normal barely changes
        # its field): the two rotation-vector components across a normal along x, y or z
        inplane = []
        for i, c in enumerate(self.board.coils):
            ax = np.flatnonzero(np.abs(np.abs(c.normal) - 1.0) < 1e-12)
            comps = [a for a in range(3) if a != ax[0]] if ax.size else [0, 1, 2]
            inplane += [g["tilts"][3 * i + a] for a in comps]
        g["tilts_in_plane"] = np.array(inplane, dtype=np.int64)
        return g

    @property
    def gauge(self) -> np.ndarray:
        """The first sensor coil's gain (a common scale of board and sensor gains)."""
        return np.array([self._slices()["sensor_gains"].start], dtype=np.int64)

    @property
    def fit_groups(self) -> tuple:
        """Groups a calibration fits by default: coil gains and offsets (and the sensor coils'
        relative gains); tilts on request."""
        return ("gains", "offsets") + (("sensor_gains",) if self.n_sensor > 1 else ())

    @property
    def fixed_groups(self) -> tuple:
        """Held by default beside the gauge: coil 0's offset and tilt, which a fitted frame
        (a reference calibration's Y) would otherwise share."""
        return ("frame",)

    @property
    def cold_start(self) -> str:
        """The start name of :func:`openemt.solve.prepare`'s solver from no prior pose."""
        return "grid" if self.n_sensor == 1 else "cold"

    def parameter_unit(self, i: int) -> tuple:
        """Report unit and scale of parameter ``i`` (offsets in mm, tilts in degrees)."""
        name = self.parameter_label(i).split("[")[0]
        return {"offsets": ("mm", 1e3), "tilts": ("deg", float(np.rad2deg(1.0)))}.get(
            name, ("gain", 1.0))

    def parameter_label(self, i: int) -> str:
        for name, s in self._slices().items():
            if s.start <= i < s.stop:
                k = i - s.start
                if name in ("offsets", "tilts"):
                    return f"{name}[{k // 3}, {k % 3}]"
                return f"{name}[{k}]"
        raise InputError(f"expected a parameter index below {self.params.size}, got {i}")

    def jacobians(self, poses, params: bool = True):
        """:class:`~openemt.field.ModelJacobians`: pose derivatives from the segment kernel's
        gradients by the sensor coil's position ``p`` and axis ``u``; a coil offset moves the
        coil as ``-p`` would move the sensor, a coil tilt turns it about its (offset) centre."""
        from ..field import ModelJacobians
        from ..geometry import left_jacobian_so3

        p, q, u = self._sensor_coils(poses)
        N, n, ne = p.shape[0], self.n_source, self.n_sensor
        C = np.empty((N, n, ne))
        dt = np.empty((N, n, ne, 3))
        dr = np.empty((N, n, ne, 3))
        sl = self._slices()
        dpar = np.zeros((N, n, ne, self.params.size)) if params else None
        centres = np.stack([c.center for c in self.board.coils]) + self.offsets
        Jl = left_jacobian_so3(self.tilts) if params else None
        for k in range(ne):
            base, dp, du = self.coupling_points(p[:, k], u[:, k], gradient=True)
            s = self.sensor_gains[k]
            C[:, :, k] = s * base
            dt[:, :, k] = s * dp
            dr[:, :, k] = s * (np.cross(q[:, k, None, :], dp) + np.cross(u[:, k, None, :], du))
            if not params:
                continue
            dpar[:, :, k, sl["sensor_gains"].start + k] = base
            for i in range(n):
                with np.errstate(divide="ignore", invalid="ignore"):
                    dpar[:, i, k, sl["gains"].start + i] = s * np.where(
                        self.gains[i] != 0, base[:, i] / self.gains[i], 0.0)
                o = sl["offsets"].start + 3 * i
                dpar[:, i, k, o:o + 3] = -s * dp[:, i]
                w = s * (np.cross(dp[:, i], p[:, k] - centres[i]) + np.cross(du[:, i], u[:, k]))
                o = sl["tilts"].start + 3 * i
                dpar[:, i, k, o:o + 3] = w @ Jl[i]
        return ModelJacobians(C, dt, dr, dpar)

    def packed(self):
        """The arrays of the compiled segment kernel: segments, coil offsets, gains."""
        return self.segments, self.segment_offsets, np.ascontiguousarray(self.gains)

    def describe(self) -> dict:
        """JSON-able summary for ``openemt info``."""
        return {"model_kind": self.kind, "n_source": self.n_source, "n_sensor": self.n_sensor,
                "dof": self.dof, "concentric": False, "board": self.board.name,
                "sensor": self.board.sensor.to_dict(), "sensor_length_m": self.sensor_length,
                "gains": self.gains.tolist(), "offsets_mm": (self.offsets * 1e3).tolist(),
                "tilts_deg": np.degrees(self.tilts).tolist(),
                "sensor_gains": self.sensor_gains.tolist()}

    def sensor_coil_model(self, k: int) -> BoardModel:
        """The board read by sensor coil ``k`` alone (a single-coil, 5-DOF model whose gains
        carry that coil's gain): used to start a multi-coil sensor's solve coil by coil."""
        from dataclasses import replace

        one = replace(self.board.sensor, kind="single", angle=0.0, separation=0.0)
        return BoardModel(replace(self.board, sensor=one), self.gains * self.sensor_gains[k],
                           self.offsets, self.tilts)
