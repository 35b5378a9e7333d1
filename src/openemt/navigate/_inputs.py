"""Tool poses or points from any file the navigation commands take.

* ``.h5``: an ``openemt solve`` poses file (samples not ``converged`` read as NaN, left out and
  counted by the fits) or a dataset with poses (``openemt import ndi|poses``, a simulation);
* ``.fcsv`` / ``.mrk.json``: 3D Slicer markups (positions only, :mod:`._markups`);
* anything else: a pose CSV (:func:`openemt.io.read_poses_csv`: ``x, y, z`` with an optional
  ``_m``/``_mm`` suffix, rotation vector or quaternion columns, ``pose_id`` groups).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["ToolPoses", "read_points_csv", "read_tool_poses"]


@dataclass(frozen=True, eq=False)
class ToolPoses:
    """Poses read by :func:`read_tool_poses`.

    Attributes
    ----------
    poses : ndarray, shape (N, 4, 4)
        In metres; NaN rows for samples that failed or could not be read.
    has_orientation : bool
        False for position-only inputs (rotations are then identity).
    groups : ndarray or None
        Label of the repeated sample group per row (``pose_id`` column, or markups labels
        that repeat), None if every row is its own point.
    kind : str
        ``poses-h5``, ``dataset``, ``csv`` or ``markups``.
    """

    poses: np.ndarray
    has_orientation: bool
    groups: np.ndarray | None
    kind: str


def _is_h5(path) -> bool:
    return str(path).lower().endswith((".h5", ".hdf5"))


def read_tool_poses(path, *, length_unit: str = "m", angle_unit: str = "rad") -> ToolPoses:
    """Read tool poses (see the module docstring); ``length_unit`` and ``angle_unit`` apply to
    CSV columns without a unit suffix."""
    from ._markups import is_markups_path, read_markups

    path = Path(path)
    if _is_h5(path):
        from ..io import read_pose_dataset
        from ..io._h5safe import open_h5
        from ..solve import read_poses
        from ..solve._output import POSES_SCHEMA

        if not path.is_file():
            raise FileNotFoundError(f"expected a poses or dataset file, got missing file "
                                    f"{str(path)!r}")
        with open_h5(path, "an openemt poses file or pose dataset") as f:   # checked first
            schema = f.attrs.get("schema")
        if isinstance(schema, bytes):
            schema = schema.decode()
        if schema == POSES_SCHEMA:
            res = read_poses(path)
            P = np.array(res.poses, dtype=np.float64)
            P[~res.converged] = np.nan
            return ToolPoses(P, True, None, "poses-h5")
        ds = read_pose_dataset(path)
        return ToolPoses(np.asarray(ds.poses, dtype=np.float64), True, None, "dataset")
    if is_markups_path(path):
        m = read_markups(path)
        P = np.tile(np.eye(4), (len(m.points), 1, 1))
        P[:, :3, 3] = m.points
        repeated = len(np.unique(m.labels)) < len(m.labels)
        return ToolPoses(P, False, m.labels if repeated else None, "markups")
    from ..io import read_poses_csv

    t = read_poses_csv(path, length_unit=length_unit, angle_unit=angle_unit)
    return ToolPoses(t.poses, t.has_orientation, t.group, "csv")


def read_points_csv(path, *, length_unit: str = "m") -> np.ndarray:
    """Positions (N, 3) in metres from a CSV with ``x, y, z`` columns (suffix ``_m``/``_mm``,
    see :func:`openemt.io.read_poses_csv`); a row that is not finite is refused."""
    from .._errors import InputError
    from ..io import read_poses_csv

    t = read_poses_csv(path, length_unit=length_unit)
    bad = list(t.bad_lines) + list(t.nonfinite_lines)
    if bad:
        raise InputError(f"expected finite x, y, z on every row of {path}, got missing or "
                         f"non-finite values on lines {', '.join(map(str, sorted(bad)[:10]))}")
    return t.poses[:, :3, 3].copy()
