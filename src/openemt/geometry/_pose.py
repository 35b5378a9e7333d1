"""Batched SE(3) poses: 4x4 homogeneous matrices and [x, y, z, rx, ry, rz] pose vectors.

A pose ``P`` (shape ``(..., 4, 4)``) maps coordinates of a child frame into a parent frame,
``p_parent = P @ p_child``. The tracker output is the sensor's pose in the source frame.
Pose vectors hold a translation in metres and a rotation vector (axis times angle, radians).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from .._errors import InputError

__all__ = [
    "adjoint",
    "check_points",
    "check_pose_vectors",
    "check_poses",
    "compose",
    "error_magnitudes",
    "invert",
    "left_jacobian_so3",
    "nearest_rotation",
    "pose_error",
    "pose_from_rt",
    "pose_from_vector",
    "rotation_x",
    "rotation_y",
    "rotation_z",
    "rotvec_between",
    "skew",
    "vector_from_pose",
]


def _check_last_axis(v, n: int, name: str) -> np.ndarray:
    arr = np.asarray(v)
    if arr.dtype.kind not in "iuf":
        raise TypeError(f"expected `{name}` to be real numbers, got dtype {arr.dtype}")
    if arr.ndim < 1 or arr.shape[-1] != n:
        raise InputError(f"expected `{name}` to have shape (..., {n}), got {arr.shape}")
    return arr.astype(np.float64, copy=False)


def check_pose_vectors(v, name: str = "pose_vectors") -> np.ndarray:
    """Validate pose vectors and return them as float64, shape ``(..., 6)``."""
    return _check_last_axis(v, 6, name)


def check_points(xyz, name: str = "xyz") -> np.ndarray:
    """Validate points and return them as float64, shape ``(..., 3)``."""
    return _check_last_axis(xyz, 3, name)


def check_poses(P, name: str = "poses", *, batch: bool = False) -> np.ndarray:
    """Validate homogeneous poses and return them as float64, shape ``(..., 4, 4)`` (with
    ``batch``: ``(N, 4, 4)``)."""
    arr = np.asarray(P)
    if arr.dtype.kind not in "iuf":
        raise TypeError(f"expected `{name}` to be real numbers, got dtype {arr.dtype}")
    if arr.ndim < 2 or arr.shape[-2:] != (4, 4) or (batch and arr.ndim != 3):
        raise InputError(f"expected `{name}` to have shape {'(N' if batch else '(...'}, 4, 4), "
                         f"got {arr.shape}")
    return arr.astype(np.float64, copy=False)


def _rotations_from_rotvec(rv: np.ndarray) -> np.ndarray:
    flat = np.array(rv.reshape(-1, 3), dtype=np.float64)  # a copy: scipy rejects read-only input
    return Rotation.from_rotvec(flat).as_matrix().reshape(rv.shape[:-1] + (3, 3))


def pose_from_rt(R, t) -> np.ndarray:
    """Assemble poses from rotation matrices ``(..., 3, 3)`` and translations ``(..., 3)``."""
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    batch = np.broadcast_shapes(R.shape[:-2], t.shape[:-1])
    P = np.zeros(batch + (4, 4))
    P[..., :3, :3] = R
    P[..., :3, 3] = t
    P[..., 3, 3] = 1.0
    return P


def pose_from_vector(v) -> np.ndarray:
    """Pose vectors ``(..., 6)`` ``[x, y, z, rx, ry, rz]`` -> poses ``(..., 4, 4)``.

    The rotation vector is converted with scipy's ``Rotation.from_rotvec``; the input rank is
    kept, so ``(6,)`` gives ``(4, 4)`` and ``(N, 6)`` gives ``(N, 4, 4)``.
    """
    v = check_pose_vectors(v)
    return pose_from_rt(_rotations_from_rotvec(v[..., 3:]), v[..., :3])


def vector_from_pose(P) -> np.ndarray:
    """Poses ``(..., 4, 4)`` -> pose vectors ``(..., 6)`` with rotation angle in ``[0, pi]``.

    Rows with a non-finite rotation (e.g. a failed solve) give NaN rotation vectors.
    """
    P = check_poses(P)
    R = P[..., :3, :3].reshape(-1, 3, 3)
    ok = np.all(np.isfinite(R), axis=(1, 2))
    rv = np.full((R.shape[0], 3), np.nan)
    if ok.any():
        rv[ok] = Rotation.from_matrix(R[ok]).as_rotvec()
    return np.concatenate([P[..., :3, 3], rv.reshape(P.shape[:-2] + (3,))], axis=-1)


def compose(*poses) -> np.ndarray:
    """Product ``P1 @ P2 @ ...`` of poses with broadcasting over the batch axes."""
    if not poses:
        raise InputError("expected at least one pose to compose, got none")
    out = check_poses(poses[0])
    for p in poses[1:]:
        out = out @ check_poses(p)
    return out


def invert(P) -> np.ndarray:
    """Inverse of rigid poses ``(..., 4, 4)`` (uses the rotation transpose, not a general inverse)."""
    P = check_poses(P)
    Rt = np.swapaxes(P[..., :3, :3], -1, -2)
    t = -np.einsum("...ij,...j->...i", Rt, P[..., :3, 3])
    return pose_from_rt(Rt, t)


def pose_error(P_measured, P_true) -> np.ndarray:
    """Pose error ``E = inv(P_measured) @ P_true`` (MacLachlan et al. 2025, §VIII), shape ``(..., 4, 4)``."""
    return invert(P_measured) @ check_poses(P_true)


def error_magnitudes(E) -> tuple[np.ndarray, np.ndarray]:
    """Translation magnitude (m) and rotation angle (rad, in [0, pi]) of error poses ``E``."""
    E = check_poses(E)
    trans = np.linalg.norm(E[..., :3, 3], axis=-1)
    # angle from the trace is inaccurate near 0; take it from the rotation vector instead
    rv = vector_from_pose(E)[..., 3:]
    return trans, np.linalg.norm(rv, axis=-1)


def _elementary(theta, i: int, j: int) -> np.ndarray:
    theta = np.asarray(theta, dtype=np.float64)
    c, s = np.cos(theta), np.sin(theta)
    R = np.zeros(theta.shape + (3, 3))
    k = 3 - i - j
    R[..., k, k] = 1.0
    R[..., i, i] = c
    R[..., j, j] = c
    R[..., i, j] = -s
    R[..., j, i] = s
    return R


def rotation_x(theta) -> np.ndarray:
    """Right-handed rotation matrices about X, shape ``theta.shape + (3, 3)``."""
    return _elementary(theta, 1, 2)


def rotation_y(theta) -> np.ndarray:
    """Right-handed rotation matrices about Y, shape ``theta.shape + (3, 3)``."""
    return _elementary(theta, 2, 0)


def rotation_z(theta) -> np.ndarray:
    """Right-handed rotation matrices about Z, shape ``theta.shape + (3, 3)``."""
    return _elementary(theta, 0, 1)


def rotvec_between(a, u) -> np.ndarray:
    """Rotation vectors ``(N, 3)`` of the smallest rotations taking the unit vector ``a`` (3,)
    to each unit vector ``u`` (N, 3); a non-finite ``u`` gives NaN.

    An ``u`` opposite to ``a`` turns by pi about the part of x (y when ``a`` is near x)
    perpendicular to ``a``.

    >>> rotvec_between([0.0, 0.0, 1.0], [[1.0, 0.0, 0.0]]).round(6).tolist()
    [[0.0, 1.570796, 0.0]]
    """
    a = np.asarray(a, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64).reshape(-1, 3)
    axis = np.cross(a, u)
    s = np.linalg.norm(axis, axis=1)
    ang = np.arctan2(s, u @ a)
    e = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e = e - (e @ a) * a
    e /= np.linalg.norm(e)
    with np.errstate(invalid="ignore", divide="ignore"):
        unit = np.where(s[:, None] > 1e-12, axis / s[:, None], e)
    return unit * ang[:, None]


def nearest_rotation(M) -> np.ndarray:
    """The rotation nearest ``M`` (3, 3), or each of ``M`` (N, 3, 3), in the Frobenius norm:
    ``U diag(1, 1, det(U V^T)) V^T`` of the SVD ``M = U S V^T`` (orthogonal Procrustes)."""
    U, _, Vt = np.linalg.svd(np.asarray(M, dtype=np.float64))
    U[..., :, 2] *= np.sign(np.linalg.det(U @ Vt))[..., None]
    return U @ Vt


def skew(w) -> np.ndarray:
    """Cross-product matrices ``[w]x`` of vectors ``(..., 3)``, shape ``(..., 3, 3)``."""
    w = np.asarray(w, dtype=np.float64)
    S = np.zeros(w.shape[:-1] + (3, 3))
    S[..., 0, 1] = -w[..., 2]
    S[..., 0, 2] = w[..., 1]
    S[..., 1, 0] = w[..., 2]
    S[..., 1, 2] = -w[..., 0]
    S[..., 2, 0] = -w[..., 1]
    S[..., 2, 1] = w[..., 0]
    return S


def left_jacobian_so3(rotvec) -> np.ndarray:
    """Left Jacobian of SO(3), shape ``(..., 3, 3)``.

    For ``R(r) = exp([r]x)``, a change ``dr`` of the rotation vector rotates ``R`` by the small
    angle ``phi = J_l(r) @ dr`` in the parent frame: ``R(r + dr) ~= exp([phi]x) @ R(r)``.
    """
    r = np.asarray(rotvec, dtype=np.float64)
    th = np.linalg.norm(r, axis=-1)[..., None, None]
    K = skew(r)
    K2 = K @ K
    small = th < 1e-6
    ths = np.where(small, 1.0, th)
    a = np.where(small, 0.5 - th**2 / 24.0, (1.0 - np.cos(ths)) / ths**2)
    b = np.where(small, 1.0 / 6.0 - th**2 / 120.0, (ths - np.sin(ths)) / ths**3)
    return np.eye(3) + a * K + b * K2


def adjoint(P) -> np.ndarray:
    """Adjoint of poses, shape ``(..., 6, 6)``, acting on twists ordered ``[rho, phi]``.

    A left perturbation ``exp(xi) @ B`` transported through ``P``: ``P @ exp(xi) = exp(Ad_P xi) @ P``.
    """
    P = check_poses(P)
    R = P[..., :3, :3]
    t = P[..., :3, 3]
    A = np.zeros(P.shape[:-2] + (6, 6))
    A[..., :3, :3] = R
    A[..., 3:, 3:] = R
    A[..., :3, 3:] = skew(t) @ R
    return A
