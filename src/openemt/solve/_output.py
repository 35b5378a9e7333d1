"""Solved poses on disk: one HDF5 file written block by block (``openemt solve -o``).

Layout: root attributes ``schema = "openemt.poses"``, ``schema_version``, ``openemt_version``,
``n_samples``, ``solver``, ``status_names`` (JSON list, index = code), ``meta`` (JSON); datasets
``poses`` (N, 4, 4), ``pose_vectors`` (N, 6), ``status`` (N,) int8, ``residual`` (N,),
``iterations`` (N,) int32, ``relative_residual`` (N,) (the residual the status is judged by;
absent from files written before it existed).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .. import __version__
from .._errors import InputError
from ._result import SolveResult, Status

__all__ = ["POSES_SCHEMA", "POSES_SCHEMA_VERSION", "PoseLayout", "read_poses"]

POSES_SCHEMA = "openemt.poses"
POSES_SCHEMA_VERSION = 1
_FIELDS = {"poses": ((4, 4), np.float64), "pose_vectors": ((6,), np.float64),
           "status": ((), np.int8), "residual": ((), np.float64),
           "iterations": ((), np.int32), "relative_residual": ((), np.float64)}
_UNITS = {"poses": "homogeneous 4x4, translation in m (sensor frame -> source frame)",
          "pose_vectors": "m, m, m, rad, rad, rad ([x, y, z] and rotation vector)",
          "status": "openemt.solve.Status code (see attribute status_names)",
          "residual": "sum of squared coupling residuals / spectral norm of C",
          "iterations": "solver iterations",
          "relative_residual": "||C_pred - C_meas||_F / ||C_meas||_F (unit-free)"}


def _write_header(f, n_samples: int, solver: str, meta: dict | None) -> None:
    f.attrs["schema"] = POSES_SCHEMA
    f.attrs["schema_version"] = POSES_SCHEMA_VERSION
    f.attrs["openemt_version"] = __version__
    f.attrs["n_samples"] = int(n_samples)
    f.attrs["solver"] = solver
    f.attrs["status_names"] = json.dumps([s.name.lower() for s in Status])
    f.attrs["meta"] = json.dumps(meta or {})


class PoseLayout:
    """The poses file (the layout of the module docstring), laid out at once with contiguous
    datasets whose storage is allocated up front, so that any process can write any block of
    rows (:meth:`write`) into the closed file without the HDF5 library: what
    :func:`openemt.solve.solve_to_file` and its Dask workers do. Picklable (offsets and dtypes
    only).

    ``PoseLayout.build(n, solver, meta)`` is the ``build`` callable of
    :func:`openemt.io._h5write.atomic_h5_layout`.
    """

    def __init__(self, offsets: dict):
        self.offsets = offsets                   # name -> (byte offset or None, row shape)

    @staticmethod
    def build(n_samples: int, solver: str, meta: dict | None = None):
        from ..io._h5write import contiguous_dataset

        def make(f) -> PoseLayout:
            _write_header(f, n_samples, solver, meta)
            offsets = {}
            for name, (shape, dtype) in _FIELDS.items():
                offsets[name] = (contiguous_dataset(f, name, (int(n_samples),) + shape, dtype,
                                                    _UNITS[name])[1], shape)
            return PoseLayout(offsets)

        return make

    def write(self, path, start: int, result: SolveResult) -> None:
        """Write ``result``'s rows at rows ``start:start + len(result)`` of the file
        ``path`` (the layout's temporary file)."""
        from ..io._h5write import write_at

        if not len(result):
            return
        for name, (offset, shape) in self.offsets.items():
            dtype = np.dtype(_FIELDS[name][1]).newbyteorder("<") \
                if np.dtype(_FIELDS[name][1]).itemsize > 1 else np.dtype(_FIELDS[name][1])
            v = getattr(result, name)
            a = np.full((len(result),) + shape, np.nan, dtype) if v is None else \
                np.asarray(v).astype(dtype, copy=False)
            row_bytes = dtype.itemsize * int(np.prod(shape, dtype=np.int64))
            write_at(path, offset + start * row_bytes, a)


def read_poses(path) -> SolveResult:
    """Read a poses file written by ``openemt solve``."""
    from ..io._h5safe import check_rows, open_h5

    path = Path(path)
    with open_h5(path, f"an openemt poses HDF5 file (schema {POSES_SCHEMA!r})") as f:
        schema = f.attrs.get("schema")
        if isinstance(schema, bytes):
            schema = schema.decode()
        if schema != POSES_SCHEMA:
            raise InputError(f"expected an openemt poses file (schema {POSES_SCHEMA!r}), got "
                             f"schema {schema!r} in {path.name}")
        shape = getattr(f.get("poses"), "shape", None)
        if not shape:
            raise InputError(f"expected an openemt poses file with a `poses` array, got "
                             f"{'none' if shape is None else 'a scalar'} in {path.name}")
        check_rows(f, path.name, shape[0], {k: v[0] for k, v in _FIELDS.items()},
                   reference="poses")
        fields = {name: f[name][()] for name in _FIELDS if name in f}
        fields.setdefault("relative_residual", None)
        return SolveResult(**fields, solver=str(f.attrs["solver"]))
