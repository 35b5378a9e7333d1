"""The general dipole coupling model (MacLachlan et al. 2025, §V, eqs. 3-5) for any numbers of coils.

``C[i, j] = gain * m_j . B_i(p_j)`` with ``B_i(p) = (3 (M_i . u) u - M_i) / d^3``, where
``p_j = R L_se[:, j] + t`` and ``m_j = R M_se[:, j]`` are sensor coil j's position and moment
in the source frame and ``d u = p_j - L_so[:, i]``. The default ``gain = 1/250`` is ILEMT's
convention: it stands in for mu0/(4 pi) so that fitted source and sensor gains stay near 1.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass, field

import numpy as np

from .._errors import InputError
from ..geometry import check_pose_vectors, check_poses, pose_from_vector
from ._dipole_kernel import dipole_batch, dipole_batch_jac, pack_model
from ._protocol import ModelJacobians

__all__ = [
    "ILEMT_GAIN",
    "CouplingJacobians",
    "DipoleModel",
    "coupling",
    "coupling_jacobian_pose",
    "coupling_jacobians",
]

#: ILEMT's fixed coupling scale, C = B . m / 250 (docs/ilemt-data.md#dipole-model).
ILEMT_GAIN = 1.0 / 250.0


def _coil_array(a, name: str) -> np.ndarray:
    arr = np.asarray(a)
    if arr.dtype.kind not in "iuf":
        raise TypeError(f"expected `{name}` to be real numbers, got dtype {arr.dtype}")
    if arr.ndim != 2 or arr.shape[0] != 3 or arr.shape[1] < 1:
        raise InputError(f"expected `{name}` to have shape (3, n_coils) with n_coils >= 1, "
                         f"got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"expected `{name}` to be finite, got NaN or inf")
    out = np.ascontiguousarray(arr, dtype=np.float64)
    out.setflags(write=False)
    return out


@dataclass(frozen=True, eq=False)
class DipoleModel:
    """Dipole source and sensor coils; columns are coils.

    Attributes
    ----------
    L_so, M_so : ndarray, shape (3, n_source)
        Source coil positions (m) and moments (gain units) in source coordinates.
    L_se, M_se : ndarray, shape (3, n_sensor)
        Sensor coil positions (m) and moments (gain units) in sensor coordinates.
    gain : float
        Overall coupling scale (``1/250`` in ILEMT calibrations).
    """

    L_so: np.ndarray
    M_so: np.ndarray
    L_se: np.ndarray
    M_se: np.ndarray
    gain: float = ILEMT_GAIN
    kind: str = field(default="dipole", init=False)

    def __post_init__(self):
        for name in ("L_so", "M_so", "L_se", "M_se"):
            object.__setattr__(self, name, _coil_array(getattr(self, name), name))
        if self.L_so.shape != self.M_so.shape:
            raise InputError(f"expected `L_so` and `M_so` of equal shape, got {self.L_so.shape} "
                             f"and {self.M_so.shape}")
        if self.L_se.shape != self.M_se.shape:
            raise InputError(f"expected `L_se` and `M_se` of equal shape, got {self.L_se.shape} "
                             f"and {self.M_se.shape}")
        g = float(self.gain)
        if not np.isfinite(g) or g == 0.0:
            raise InputError(f"expected a finite non-zero `gain`, got {self.gain!r}")
        object.__setattr__(self, "gain", g)

    @property
    def n_source(self) -> int:
        return self.L_so.shape[1]

    @property
    def n_sensor(self) -> int:
        return self.L_se.shape[1]

    @property
    def is_concentric(self) -> bool:
        """True when every source and sensor coil sits at its frame origin (L = 0)."""
        return not (np.any(self.L_so) or np.any(self.L_se))

    @classmethod
    def concentric(cls, M_so=None, M_se=None, gain: float = ILEMT_GAIN) -> DipoleModel:
        """Concentric coils at the origins; identity moments by default (ideal tri-axial)."""
        M_so = np.eye(3) if M_so is None else np.asarray(M_so, dtype=np.float64)
        M_se = np.eye(3) if M_se is None else np.asarray(M_se, dtype=np.float64)
        return cls(np.zeros_like(M_so), M_so, np.zeros_like(M_se), M_se, gain)

    def replace(self, **changes) -> DipoleModel:
        """A copy with some of L_so, M_so, L_se, M_se, gain replaced."""
        return dataclasses.replace(self, **changes)

    def coupling(self, poses) -> np.ndarray:
        """Couplings for poses ``(N, 4, 4)`` -> ``(N, n_source, n_sensor)``; see :func:`coupling`."""
        return coupling(self, poses)

    # -- the coupling-model interface (openemt.field.CouplingModel) ------------------------
    @property
    def dof(self) -> int:
        """6 with two or more sensor coils of non-parallel moments, else 5 (no roll)."""
        if self.n_sensor < 2:
            return 5
        return 6 if np.linalg.matrix_rank(self.M_se, tol=1e-9 * np.abs(self.M_se).max()) >= 2 \
            else 5

    @property
    def params(self) -> np.ndarray:
        """``[L_so | M_so | L_se | M_se]``, coil by coil (3 numbers per coil)."""
        return np.concatenate([np.asarray(getattr(self, n)).T.ravel() for n in _PARAM_BLOCKS])

    def param_slices(self) -> dict:
        """Slice of each block (``L_so``, ``M_so``, ``L_se``, ``M_se``) in :attr:`params`."""
        return _param_layout(self.n_source, self.n_sensor)[0]

    @property
    def parameter_groups(self) -> dict:
        """The paper's named groups (docs/paper-procedure.md#parameter-groups) as indices into
        :attr:`params`."""
        return _param_layout(self.n_source, self.n_sensor)[1]

    @property
    def gauge(self) -> np.ndarray:
        """The reference (last) coil of each side at its origin with its moment along +z
        (docs/paper-procedure.md#gauge)."""
        return _param_layout(self.n_source, self.n_sensor)[2]

    @property
    def fit_groups(self) -> tuple:
        """Groups a calibration fits by default: coil positions and moments."""
        return ("d_so_pos", "d_so_mo", "d_se_pos", "d_se_mo")

    @property
    def fixed_groups(self) -> tuple:
        """Groups held by default beside the gauge (ILEMT's): the source Z gain (a common scale
        of source and sensor moments is not observable) and the X coils' Y components."""
        return ("d_so_z_gain", "d_so_y_co", "d_se_y_co")

    cold_start = "kim18"
    solver_family = "dipole"

    def with_params(self, x) -> DipoleModel:
        return DipoleModel(gain=self.gain, **self.split_params(x))

    def split_params(self, x) -> dict:
        """A parameter-length vector (e.g. standard errors) -> ``{'L_so': (3, n_so), ...}``."""
        x = np.asarray(x, dtype=np.float64)
        return {k: np.ascontiguousarray(x[s].reshape(-1, 3).T)
                for k, s in self.param_slices().items()}

    def parameter_unit(self, i: int) -> tuple:
        """Report unit and scale of parameter ``i`` (positions in mm, moments in gain units)."""
        return ("mm", 1e3) if self.parameter_label(i).startswith("L") else ("gain", 1.0)

    def parameter_label(self, i: int) -> str:
        for name, s in self.param_slices().items():
            if s.start <= i < s.stop:
                k = i - s.start
                return f"{name}[{k % 3}, {k // 3}]"
        raise InputError(f"expected a parameter index below {self.params.size}, got {i}")

    def jacobians(self, poses, params: bool = True):
        """:class:`~openemt.field.ModelJacobians` (pose and, unless ``params`` is False,
        parameter derivatives)."""
        from ._protocol import ModelJacobians

        jac = coupling_jacobians(self, poses)
        return ModelJacobians(jac.C, jac.d_translation, jac.d_rotation,
                              param_jacobian(self, jac) if params else None)

    def packed(self):
        """The arrays of the compiled dipole kernel."""
        return pack_model(self)

    def describe(self) -> dict:
        """JSON-able summary for ``openemt info``."""
        return {"model_kind": self.kind, "n_source": self.n_source, "n_sensor": self.n_sensor,
                "dof": self.dof, "concentric": bool(self.is_concentric), "gain": self.gain,
                "source_gains": np.linalg.norm(self.M_so, axis=0),
                "sensor_gains": np.linalg.norm(self.M_se, axis=0)}


_PARAM_BLOCKS = ("L_so", "M_so", "L_se", "M_se")


@functools.cache
def _param_layout(ns: int, ne: int):
    """Slices, named groups and gauge of the dipole parameter vector of ``ns`` x ``ne`` coils.

    * the **reference coil** of each side is its last coil (the Z coil of a tri-axial set): its
      position is held at the frame origin and its moment along +z, ``[0, 0, k]``;
    * the **y component of coil 0's moment** (``M[1, 0]``) is its own group
      (``d_so_y_co``/``d_se_y_co``), which fixes the rotation of the frame about z;
    * ``d_so_z_gain`` (the source reference gain) is a group of its own because a common scale
      of source and sensor moments is not observable (calibration modes hold it).
    """
    sizes = {"L_so": 3 * ns, "M_so": 3 * ns, "L_se": 3 * ne, "M_se": 3 * ne}
    slices, start = {}, 0
    for name in _PARAM_BLOCKS:
        slices[name] = slice(start, start + sizes[name])
        start += sizes[name]

    def idx(name, coil, comp=None):
        s = slices[name]
        comps = np.arange(3) if comp is None else np.atleast_1d(comp)
        return np.array([s.start + 3 * i + a for i in np.atleast_1d(coil) for a in comps],
                        dtype=np.int64)

    g, gauge = {}, []
    for side, n in (("so", ns), ("se", ne)):
        L, M = f"L_{side}", f"M_{side}"
        ref, others = n - 1, np.arange(n - 1)
        g[f"d_{side}_pos"] = idx(L, others)
        g[f"d_{side}_z_gain"] = idx(M, ref, 2)
        g[f"d_{side}_mo"] = np.concatenate([idx(M, others), g[f"d_{side}_z_gain"]])
        g[f"d_{side}_y_co"] = idx(M, 0, 1) if n > 1 else np.zeros(0, dtype=np.int64)
        gauge += [idx(L, ref), idx(M, ref, [0, 1])]
    for v in g.values():
        v.setflags(write=False)
    gauge_arr = np.unique(np.concatenate(gauge))
    gauge_arr.setflags(write=False)
    return slices, g, gauge_arr


def param_jacobian(model: DipoleModel, jac) -> np.ndarray:
    """``(N, n_so, n_se, n_params)`` derivative of the couplings with respect to ``params``
    from :func:`coupling_jacobians`'s per-coil gradients (C[i, j] depends on source coil i and
    sensor coil j only)."""
    n, ns, ne = jac.C.shape
    sl = model.param_slices()
    J = np.zeros((n, ns, ne, sl["M_se"].stop))
    for name, d, by_source in (("L_so", jac.d_L_so, True), ("M_so", jac.d_M_so, True),
                               ("L_se", jac.d_L_se, False), ("M_se", jac.d_M_se, False)):
        s = sl[name]
        blk = J[..., s].reshape(n, ns, ne, -1, 3)
        if by_source:
            for i in range(ns):
                blk[:, i, :, i, :] = d[:, i, :, :]
        else:
            for j in range(ne):
                blk[:, :, j, j, :] = d[:, :, j, :]
        J[..., s] = blk.reshape(n, ns, ne, -1)
    return J


@dataclass(frozen=True, eq=False)
class CouplingJacobians:
    """Couplings and their analytic derivatives for a batch of poses.

    All derivative arrays have shape ``(N, n_source, n_sensor, 3)``; entry ``[k, i, j, :]`` is
    the gradient of ``C[k, i, j]`` with respect to a 3-vector:

    - ``d_translation``: the pose translation t (source frame);
    - ``d_rotation``: a small rotation ``phi`` applied as ``R -> exp([phi]x) R`` (source frame);
    - ``d_L_so`` / ``d_M_so``: source coil i's position / moment (C[i, j] depends on coil i only);
    - ``d_L_se`` / ``d_M_se``: sensor coil j's position / moment, in sensor coordinates.
    """

    C: np.ndarray
    d_translation: np.ndarray
    d_rotation: np.ndarray
    d_L_so: np.ndarray
    d_M_so: np.ndarray
    d_L_se: np.ndarray
    d_M_se: np.ndarray

    pose_vector = ModelJacobians.pose_vector


def _split(poses):
    P = check_poses(poses, batch=True)
    if not np.all(np.isfinite(P)):
        raise InputError("expected finite `poses`, got NaN or inf")
    return np.ascontiguousarray(P[:, :3, :3]), np.ascontiguousarray(P[:, :3, 3])


def coupling(model: DipoleModel, poses) -> np.ndarray:
    """Predicted couplings ``(N, n_source, n_sensor)`` for sensor poses ``(N, 4, 4)``.

    A source and sensor coil at the same point (distance 0) have no defined dipole coupling:
    that entry is NaN (never an exception), so the sample is flagged and the batch goes on.

    References
    ----------
    MacLachlan et al. 2025, eqs. 3-5; docs/ilemt-data.md#dipole-model.
    """
    R, t = _split(poses)
    C = np.empty((R.shape[0], model.n_source, model.n_sensor))
    dipole_batch(pack_model(model), R, t, C)
    return C


def coupling_jacobians(model: DipoleModel, poses) -> CouplingJacobians:
    """Couplings and analytic derivatives with respect to the pose and every model parameter."""
    R, t = _split(poses)
    n, ns, ne = R.shape[0], model.n_source, model.n_sensor
    C = np.empty((n, ns, ne))
    dt, dphi, dMso, dm = (np.empty((n, ns, ne, 3)) for _ in range(4))
    dipole_batch_jac(pack_model(model), R, t, C, (dt, dphi, dMso, dm))
    # p_j = R L_se_j + t, m_j = R M_se_j: gradients in sensor coordinates are R^T g
    d_L_se = np.einsum("kba,kijb->kija", R, dt)
    d_M_se = np.einsum("kba,kijb->kija", R, dm)
    return CouplingJacobians(C=C, d_translation=dt, d_rotation=dphi, d_L_so=-dt, d_M_so=dMso,
                             d_L_se=d_L_se, d_M_se=d_M_se)


def coupling_jacobian_pose(model: DipoleModel, pose_vectors) -> tuple[np.ndarray, np.ndarray]:
    """Couplings ``(N, n_so, n_se)`` and their Jacobian ``(N, n_so, n_se, 6)`` with respect to
    the pose vector ``[x, y, z, rx, ry, rz]``."""
    v = check_pose_vectors(pose_vectors)
    if v.ndim != 2:
        raise InputError(f"expected `pose_vectors` to have shape (N, 6), got {v.shape}")
    jac = coupling_jacobians(model, pose_from_vector(v))
    return jac.C, jac.pose_vector(v[:, 3:])


def check_dipole_model(model, what: str = "model"):
    """``model`` if it is a :class:`~openemt.field.DipoleModel` (what the dipole kernels take),
    else a TypeError naming ``what``."""
    if not isinstance(model, DipoleModel):
        raise TypeError(f"expected `{what}` to be a DipoleModel, got {type(model).__name__}")
    return model
