"""The general dipole coupling model (MacLachlan et al. 2025, §V, eqs. 3-5) for any numbers of coils.

``C[i, j] = gain * m_j . B_i(p_j)`` with ``B_i(p) = (3 (M_i . u) u - M_i) / d^3``, where
``p_j = R L_se[:, j] + t`` and ``m_j = R M_se[:, j]`` are sensor coil j's position and moment
in the source frame and ``d u = p_j - L_so[:, i]``. The default ``gain = 1/250`` is ILEMT's
convention: it stands in for mu0/(4 pi) so that fitted source and sensor gains stay near 1.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from .._errors import InputError
from ..geometry import check_pose_vectors, check_poses, left_jacobian_so3, pose_from_vector
from ._dipole_kernel import dipole_batch, dipole_batch_jac, pack_model

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

    def pose_vector(self, rotvecs) -> np.ndarray:
        """Jacobian with respect to the pose vector ``[x, y, z, rx, ry, rz]``, ``(N, n_so, n_se, 6)``."""
        Jl = left_jacobian_so3(np.asarray(rotvecs, dtype=np.float64))
        d_rv = np.einsum("kija,kab->kijb", self.d_rotation, Jl)
        return np.concatenate([self.d_translation, d_rv], axis=-1)


def _split(poses):
    P = check_poses(poses)
    if P.ndim != 3:
        raise InputError(f"expected `poses` to have shape (N, 4, 4), got {P.shape}")
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
