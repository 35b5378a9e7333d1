"""Pose datasets: tracker poses without couplings, stored in the ordinary dataset file.

Importers of trackers that only give poses (NDI Aurora and Polaris exports, pose CSV files,
robot logs) write an openemt dataset (docs/data-format.md) whose couplings have shape
``(N, 0, 0)`` and whose ``poses`` hold the tracked poses (tool in the tracker's frame, m).
Per-row extras:

* ``extra/frame`` (int64): the tracker's frame number (-1: none);
* ``extra/reference_poses`` (N, 4, 4): reference poses given in the same file (pose CSV
  ``ref_`` columns), in the reference tracker's frame;
* ``extra/n_averaged``, ``extra/jitter_trans_rms`` (m), ``extra/jitter_rot_rms`` (rad): for
  static recordings averaged into one row;
* ``extra/error`` (m): NDI's RMS fit error of the tool.

``meta["kind"] == "poses"`` marks such a file; ``meta["tool"]`` names the tool.
"""

from __future__ import annotations

import numpy as np

from .._errors import InputError
from ._dataset import Dataset
from ._hdf5 import read_dataset

__all__ = ["pose_dataset", "read_pose_dataset"]


def pose_dataset(poses, *, file_index, files, extra=None, meta=None) -> Dataset:
    """A :class:`Dataset` holding poses only (couplings of shape (N, 0, 0)).

    Parameters
    ----------
    poses : ndarray, shape (N, 4, 4)
        Tool poses in the tracker's frame (m).
    file_index : array_like of int, shape (N,)
        Index into ``files`` of the file each row came from.
    files : sequence of str
    extra : dict of str -> ndarray (first axis N), optional
    meta : dict, optional
        JSON-able description; ``kind`` is set to ``"poses"``.
    """
    P = np.asarray(poses, dtype=np.float64)
    if P.ndim != 3 or P.shape[1:] != (4, 4):
        raise InputError(f"expected poses of shape (N, 4, 4), got {P.shape}")
    n = len(P)
    return Dataset(couplings=np.zeros((n, 0, 0)), stage=np.zeros((n, 6)), source_fixture="",
                   sensor_fixture="", pattern="",
                   file_index=np.asarray(file_index, dtype=np.int64), files=tuple(files),
                   poses=P, extra=dict(extra or {}), meta={**(meta or {}), "kind": "poses"})


def read_pose_dataset(path) -> Dataset:
    """Read a dataset file that holds poses (a pose import, a simulation with truth, ...)."""
    ds = read_dataset(path)
    if ds.poses is None:
        raise InputError(f"expected a dataset with poses in {path} (from 'openemt import ndi' "
                         f"or 'openemt import poses'), got one without poses")
    return ds
