"""Simulated recordings with known truth for the navigation fits (tests, docs, examples).

All functions take a ``numpy.random.Generator`` and return SI arrays; noise is isotropic
Gaussian per axis.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ..geometry import pose_from_rt

__all__ = ["simulate_grid_points", "simulate_pivot_poses", "simulate_spin_poses"]


def simulate_pivot_poses(n: int, tip, pivot, rng, *, spread_deg: float = 20.0,
                         noise: float = 2e-4, n_outliers: int = 0,
                         outlier_offset: float = 0.01) -> np.ndarray:
    """Poses (n, 4, 4) of a tool pivoting about ``pivot`` (tracker frame, m) with its tip at
    ``tip`` (tool frame): rotations with ``spread_deg`` RMS per axis about the identity,
    position noise ``noise`` (m per axis); the first ``n_outliers`` poses slipped by about
    ``outlier_offset`` (m)."""
    R = Rotation.from_rotvec(rng.normal(0.0, np.deg2rad(spread_deg), (n, 3)))
    p = np.asarray(pivot, float) - R.apply(np.asarray(tip, float))
    p = p + rng.normal(0.0, noise, (n, 3))
    if n_outliers:
        d = rng.normal(size=(n_outliers, 3))
        p[:n_outliers] += outlier_offset * d / np.linalg.norm(d, axis=1, keepdims=True)
    return pose_from_rt(R.as_matrix(), p)


def simulate_spin_poses(n: int, axis, point, rng, *, start=None, spin_deg: float = 90.0,
                        origin=(0.1, 0.0, 0.2), noise: float = 2e-4,
                        wobble_deg: float = 0.2) -> np.ndarray:
    """Poses (n, 4, 4) of a tool turned by up to +-``spin_deg`` about its ``axis`` (tool frame,
    unit) through ``point`` (tool frame, m); the axis point stays at ``origin`` (tracker frame);
    ``start`` (a scipy ``Rotation``) orients the tool, ``wobble_deg`` and ``noise`` perturb
    the rotations (deg per axis) and positions (m per axis)."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    G = Rotation.from_rotvec([0.3, -0.5, 0.2]) if start is None else start
    th = rng.uniform(-np.deg2rad(spin_deg), np.deg2rad(spin_deg), n)
    R = G * Rotation.from_rotvec(np.outer(th, a)) * Rotation.from_rotvec(
        rng.normal(0.0, np.deg2rad(wobble_deg), (n, 3)))
    p = np.asarray(origin, float) - R.apply(np.asarray(point, float)) + rng.normal(0.0, noise,
                                                                                   (n, 3))
    return pose_from_rt(R.as_matrix(), p)


def simulate_grid_points(nominal, rng, *, transform=None, noise: float = 2e-4,
                         repeats: int = 1, distortion=None):
    """Measured samples of grid points: ``transform`` (4x4, nominal -> tracker) applied to the
    nominal points (M, 3), plus ``distortion(points)`` (m) if given, plus noise per sample.
    Returns (samples (M * repeats, 3) in point-major order, labels (M * repeats,))."""
    nom = np.asarray(nominal, float)
    T = np.eye(4) if transform is None else np.asarray(transform, float)
    true = nom @ T[:3, :3].T + T[:3, 3]
    if distortion is not None:
        true = true + distortion(true)
    pts = np.repeat(true, repeats, axis=0) + rng.normal(0.0, noise, (len(nom) * repeats, 3))
    return pts, np.repeat(np.arange(len(nom)), repeats)
