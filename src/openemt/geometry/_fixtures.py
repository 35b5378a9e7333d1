"""Named manual-fixture rotations, stage transforms and the ground-truth kinematic chain.

Fixture codes such as ``ZoutYup`` name the mover axes that point "out" (fixture +Y, from source
towards sensor) and "up" (fixture +Z); "in"/"down" mean the negative axis (docs/ilemt-data.md#fixtures).
"""

from __future__ import annotations

import re

import numpy as np

from .._errors import InputError
from ._pose import check_poses, pose_from_rt, pose_from_vector, rotation_x, rotation_y, rotation_z

__all__ = [
    "FIXTURE_CODE_RE",
    "SENSOR_FIXTURES",
    "SOURCE_FIXTURES",
    "fixture_axes",
    "ground_truth_poses",
    "sensor_fixture_rotation",
    "source_fixture_rotation",
    "stage_joint",
    "stage_transform",
]

FIXTURE_CODE_RE = re.compile(r"^([XYZ])(out|in)([XYZ])(up|down)$")

#: Source-fixture codes used by the ILEMT apparatus (MacLachlan et al. 2025), home first.
SOURCE_FIXTURES = ("YoutZup", "XoutZup", "ZoutYup", "XinYup")
#: Sensor-fixture codes used by the ILEMT apparatus (MacLachlan et al. 2025), home first.
SENSOR_FIXTURES = ("YoutZup", "ZinYup", "ZinXdown")

_AXIS = {"X": 0, "Y": 1, "Z": 2}


def fixture_axes(code: str) -> np.ndarray:
    """``A(code) = [out x up | out | up]``: fixture X, Y, Z axes (columns) in mover axes.

    Accepts any code of the form ``<axis><out|in><axis><up|down>`` with two different axes,
    e.g. ``YoutZup``, ``ZinXdown``. Raises ``ValueError`` for anything else.
    """
    m = FIXTURE_CODE_RE.match(code) if isinstance(code, str) else None
    if m is None or m.group(1) == m.group(3):
        raise InputError(
            "expected a fixture code like 'YoutZup' or 'ZinXdown' (<X|Y|Z><out|in><X|Y|Z><up|down>, "
            f"two different axes), got {code!r}"
        )
    out = np.zeros(3)
    up = np.zeros(3)
    out[_AXIS[m.group(1)]] = 1.0 if m.group(2) == "out" else -1.0
    up[_AXIS[m.group(3)]] = 1.0 if m.group(4) == "up" else -1.0
    return np.column_stack([np.cross(out, up), out, up])


def source_fixture_rotation(code: str) -> np.ndarray:
    """Known source-fixture motion ``so_J`` (3x3) for a fixture code: ``A(code)``."""
    return fixture_axes(code)


def sensor_fixture_rotation(code: str) -> np.ndarray:
    """Known sensor-fixture rotation ``S`` (3x3) for a fixture code: ``A(code).T``."""
    return fixture_axes(code).T


def stage_transform(stage) -> np.ndarray:
    """Stage vectors ``(..., 6)`` -> poses ``(..., 4, 4)``.

    ``stage = [x, y, z, a, b, c]`` in metres and radians; the rotation is ``Rz(c) Ry(b) Rx(a)``
    (fixed-axis Z-Y-X Euler angles, docs/ilemt-data.md#ground-truth) and the translation is not rotated.
    """
    s = np.asarray(stage, dtype=np.float64)
    if s.ndim < 1 or s.shape[-1] != 6:
        raise InputError(f"expected `stage` to have shape (..., 6), got {s.shape}")
    R = rotation_z(s[..., 5]) @ rotation_y(s[..., 4]) @ rotation_x(s[..., 3])
    return pose_from_rt(R, s[..., :3])


def stage_joint(stage, sensor_codes) -> np.ndarray:
    """The stage-and-sensor-fixture joint ``st_J = [[Rz(theta) Ry Rx S(code), t], [0, 1]]``.

    Parameters
    ----------
    stage : ndarray, shape (N, 6)
        Stage vectors in metres and radians (compensated, if compensation applies).
    sensor_codes : sequence of str, length N, or a single str
        Sensor-fixture code of each row.
    """
    T = stage_transform(stage)
    n = T.shape[0]
    codes = [sensor_codes] * n if isinstance(sensor_codes, str) else list(sensor_codes)
    if len(codes) != n:
        raise InputError(f"expected {n} sensor-fixture codes, got {len(codes)}")
    out = T.copy()
    out[:, :3, :3] = T[:, :3, :3] @ _rotations_per_row(codes, sensor_fixture_rotation)
    return out


def _rotations_per_row(codes, rotation_of) -> np.ndarray:
    """(N, 3, 3) rotations of per-row fixture codes, each distinct code converted once."""
    codes = np.asarray(codes, dtype=str)
    R = np.empty((codes.size, 3, 3))
    for c in np.unique(codes):
        R[codes == c] = rotation_of(str(c))
    return R


def ground_truth_poses(source_fixture, stage_fixture, sensor_fixture, source_codes, stage,
                       sensor_codes) -> np.ndarray:
    """Ground truth ``P = F_so . so_J . F_st . st_J . F_se`` (MacLachlan et al. 2025, eq. 6), shape (N, 4, 4).

    Parameters
    ----------
    source_fixture, stage_fixture, sensor_fixture : ndarray, shape (6,) or (4, 4)
        Fixture transforms F_so, F_st, F_se as pose vectors or poses.
    source_codes, sensor_codes : sequence of str, length N (or one str for all rows)
        Manual source- and sensor-fixture codes of each row.
    stage : ndarray, shape (N, 6)
        Stage vectors in metres and radians.
    """
    def as_pose(f, name):
        f = np.asarray(f, dtype=np.float64)
        if f.shape == (6,):
            return pose_from_vector(f)
        return check_poses(f, name)

    F_so = as_pose(source_fixture, "source_fixture")
    F_st = as_pose(stage_fixture, "stage_fixture")
    F_se = as_pose(sensor_fixture, "sensor_fixture")
    st_J = stage_joint(stage, sensor_codes)
    n = st_J.shape[0]
    codes = [source_codes] * n if isinstance(source_codes, str) else list(source_codes)
    if len(codes) != n:
        raise InputError(f"expected {n} source-fixture codes, got {len(codes)}")
    so_J = np.zeros((n, 4, 4))
    so_J[:, 3, 3] = 1.0
    so_J[:, :3, :3] = _rotations_per_row(codes, source_fixture_rotation)
    return F_so @ so_J @ F_st @ st_J @ F_se
