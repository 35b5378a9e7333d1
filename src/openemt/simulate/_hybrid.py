"""An EM tracker's reported poses beside an optical tracker's: the pose-level simulation behind
``openemt bench hybrid`` and ``openemt simulate --reference optical --format ndi``.

An EM sensor and an optical marker are rigidly joined (X: marker in the sensor's frame) and the
camera sits at Y (camera in the field generator's frame). True sensor poses are uniform in
x 0.05-0.35 m, y and z +-0.15 m with random orientations. The EM tracker reports them with a
smooth field distortion (:func:`field_distortion`, about 1 mm and 0.25 deg RMS at scale 1; 3 mm
and 0.75 deg at :data:`DISTORTION_SCALE`) plus noise (0.1 mm and 0.03 deg per axis); the
optical tracker reports ``Y^-1 A X`` with its own noise (0.15 mm, 0.05 deg per axis).
"""

from __future__ import annotations

import numpy as np

__all__ = ["DISTORTION_SCALE", "EM_NOISE", "OPTICAL_NOISE", "draw_xy", "field_distortion",
           "simulate_hybrid", "simulate_ndi_session"]

#: Distortion scale of the EM tracker (about 3 mm, 0.75 deg RMS).
DISTORTION_SCALE = 3.0
#: EM tracker noise per axis: (m, rad).
EM_NOISE = (1e-4, np.deg2rad(0.03))
#: Optical tracker noise per axis: (m, rad).
OPTICAL_NOISE = (1.5e-4, np.deg2rad(0.05))
#: Port labels of the simulated NDI session: an Aurora sensor and a Polaris marker.
NDI_EM_LABEL = "Port 10: NDI-MF2 610066   T6d0-S00108  s/n:37B31800 Channel:0"
NDI_OPTICAL_LABEL = "Port 1: CAMP OT-Sensor-2013-05-08  s/n:38A1FC00"


def field_distortion(p, scale: float = 1.0):
    """The smooth distortion at true positions ``p`` (N, 3): position offsets (m) and rotation
    offsets (rotation vectors, rad), about 1 mm and 0.25 deg RMS at ``scale`` 1 over the
    volume x 0.05-0.35 m, y and z +-0.15 m."""
    q = (np.asarray(p) - [0.2, 0.0, 0.0]) / 0.15
    dp = 1e-3 * np.stack([1.5 * q[:, 0] ** 2 - 0.8 * q[:, 1] * q[:, 2] + 0.5 * q[:, 0] ** 3,
                          0.7 * q[:, 0] * q[:, 1] + 0.4 * np.sin(2 * q[:, 2]),
                          -0.9 * q[:, 2] * q[:, 0] + 0.6 * q[:, 1] ** 2], axis=1)
    rho = np.deg2rad(0.5) * np.stack([q[:, 1] * q[:, 0], 0.6 * q[:, 2] ** 2 - 0.3,
                                      0.8 * q[:, 0] * q[:, 2] + 0.2 * q[:, 1]], axis=1)
    return scale * dp, scale * rho


def draw_xy(rng):
    """A random marker-in-sensor transform X (within 40 mm) and camera-in-field-generator
    transform Y (about 1.1 m away), each (4, 4)."""
    from scipy.spatial.transform import Rotation

    from ..geometry import pose_from_rt

    X = pose_from_rt(Rotation.random(random_state=rng).as_matrix(), rng.uniform(-0.04, 0.04, 3))
    Y = pose_from_rt(Rotation.random(random_state=rng).as_matrix(),
                     np.array([0.2, -0.6, 0.9]) + rng.uniform(-0.1, 0.1, 3))
    return X, Y


def _noisy(P, sigma_t, sigma_r, rng):
    from scipy.spatial.transform import Rotation

    from ..geometry import pose_from_rt

    n = len(P)
    R = Rotation.from_rotvec(sigma_r * rng.standard_normal((n, 3))).as_matrix()
    return pose_from_rt(R @ P[:, :3, :3], P[:, :3, 3] + sigma_t * rng.standard_normal((n, 3)))


def simulate_hybrid(n: int, X, Y, rng) -> dict:
    """Truth, EM (distorted + noise), EM noise only, and optical poses of ``n`` samples.

    Returns a dict of (n, 4, 4) arrays: ``truth`` (sensor in the field generator's frame),
    ``em`` (what the EM tracker reports), ``em_undistorted`` (the same noise without the
    distortion) and ``optical`` (the marker in the camera's frame, with noise).
    """
    from scipy.spatial.transform import Rotation

    from ..geometry import invert, pose_from_rt

    p = rng.uniform([0.05, -0.15, -0.15], [0.35, 0.15, 0.15], (n, 3))
    truth = pose_from_rt(Rotation.random(n, random_state=rng).as_matrix(), p)
    dp, rho = field_distortion(p, DISTORTION_SCALE)
    distorted = pose_from_rt(Rotation.from_rotvec(rho).as_matrix() @ truth[:, :3, :3], p + dp)
    e_t = EM_NOISE[0] * rng.standard_normal((n, 3))
    e_r = Rotation.from_rotvec(EM_NOISE[1] * rng.standard_normal((n, 3))).as_matrix()
    em = pose_from_rt(e_r @ distorted[:, :3, :3], distorted[:, :3, 3] + e_t)
    em_undistorted = pose_from_rt(e_r @ truth[:, :3, :3], truth[:, :3, 3] + e_t)
    optical = _noisy(invert(Y) @ truth @ X, *OPTICAL_NOISE, rng)
    return {"truth": truth, "em": em, "em_undistorted": em_undistorted, "optical": optical}


def simulate_ndi_session(n: int, *, seed: int = 0) -> tuple[dict, dict]:
    """One simulated NDI Toolbox session: an Aurora sensor rigidly joined to a Polaris marker.

    X (the marker in the sensor's frame) and Y (the camera in the field generator's frame) are
    drawn from ``seed``; the poses come from :func:`simulate_hybrid`.

    Returns
    -------
    tools : dict
        Port label -> poses (n, 4, 4), as :func:`openemt.io.write_ndi_tsv` takes them: the EM
        sensor on port 10 and the optical marker on port 1.
    truth : dict
        ``X``, ``Y`` (4, 4) and the true sensor poses ``poses`` (n, 4, 4).
    """
    from .._errors import InputError

    if int(n) < 1:
        raise InputError(f"expected at least 1 pose, got {n}")
    rng = np.random.default_rng(seed)
    X, Y = draw_xy(rng)
    sim = simulate_hybrid(int(n), X, Y, rng)
    tools = {NDI_EM_LABEL: sim["em"], NDI_OPTICAL_LABEL: sim["optical"]}
    return tools, {"X": X, "Y": Y, "poses": sim["truth"]}
