"""Sets of sensor orientations a map is computed over (docs/design.md#orientations)."""

from __future__ import annotations

import numpy as np

from .._errors import InputError

__all__ = ["ORIENTATIONS", "map_poses", "orientation_set"]

#: ``down``: the sensor's z axis along the board's -z (the grid of docs/planar.md); ``axes``:
#: along +-x, +-y, +-z; ``sphere``: ``n`` directions spread evenly over the sphere (Fibonacci).
ORIENTATIONS = ("down", "axes", "sphere")


def _to_direction(d: np.ndarray) -> np.ndarray:
    """The smallest rotation taking the z axis to unit ``d`` (about x by pi for -z)."""
    z = np.array([0.0, 0.0, 1.0])
    c = float(d @ z)
    if c < -1 + 1e-12:
        return np.diag([1.0, -1.0, -1.0])
    v = np.cross(z, d)
    K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + K + K @ K / (1 + c)


def orientation_set(name: str, n: int = 12) -> np.ndarray:
    """Sensor rotations ``(K, 3, 3)`` (sensor z axis to each direction of the set)."""
    if name == "down":
        dirs = np.array([[0.0, 0.0, -1.0]])
    elif name == "axes":
        dirs = np.concatenate([np.eye(3), -np.eye(3)])
    elif name == "sphere":
        if int(n) < 1 or int(n) > 500:
            raise InputError(f"expected between 1 and 500 orientations, got {n}")
        k = np.arange(int(n)) + 0.5
        zc = 1 - 2 * k / int(n)
        phi = np.pi * (1 + 5 ** 0.5) * k
        r = np.sqrt(1 - zc ** 2)
        dirs = np.column_stack([r * np.cos(phi), r * np.sin(phi), zc])
    else:
        raise InputError(f"expected orientations in {list(ORIENTATIONS)}, got {name!r}")
    return np.stack([_to_direction(d / np.linalg.norm(d)) for d in dirs])


def map_poses(points, rotations) -> np.ndarray:
    """Poses ``(n_points * n_orientations, 4, 4)``, orientation fastest."""
    n, k = len(points), len(rotations)
    P = np.zeros((n, k, 4, 4))
    P[:, :, :3, :3] = rotations[None]
    P[:, :, :3, 3] = points[:, None]
    P[:, :, 3, 3] = 1.0
    return P.reshape(-1, 4, 4)
