"""Couplings with poses as CSV, for spreadsheets and other tools (``docs/data-format.md``).

One row per sample. The first line is a comment that says what the pose columns hold::

    # openemt couplings csv v1; pose=truth; units: m, rad (rotation vector); C[i,j] = source i into sensor j
    x,y,z,rx,ry,rz,c_0_0,c_0_1,...,c_2_2[,c_0_0_im,...],stage_x,...,stage_c,source_fixture,sensor_fixture,pattern,file

``pose=truth``: ``x..rz`` is the ground-truth sensor pose in the source frame (Dataset.poses);
``pose=stage``: no ground truth is known and ``x..rz`` is the stage transform as a pose vector.
Numbers are written with shortest round-trip precision, so values read back exactly.
"""

from __future__ import annotations

import csv
import re
from pathlib import Path

import numpy as np

from .._atomic import atomic_path
from .._errors import InputError
from ..geometry import pose_from_vector, stage_transform, vector_from_pose
from ._dataset import Dataset
from ._safefile import read_text

__all__ = ["export_csv", "import_csv"]

_MAGIC = "# openemt couplings csv v1"
_POSE_COLS = ["x", "y", "z", "rx", "ry", "rz"]
_STAGE_COLS = ["stage_x", "stage_y", "stage_z", "stage_a", "stage_b", "stage_c"]
_STR_COLS = ["source_fixture", "sensor_fixture", "pattern", "file"]
_C_RE = re.compile(r"c_(\d+)_(\d+)(_im)?$")


def export_csv(ds: Dataset, path) -> Path:
    """Write couplings with poses as CSV (atomically). Returns the path written.

    Sign vectors, ``extra`` arrays, ``stage_logged`` and ``meta`` are not part of the CSV;
    use the HDF5 dataset file for a complete copy.
    """
    if not isinstance(ds, Dataset):
        raise TypeError(f"expected a Dataset, got {type(ds).__name__}")
    kind = "truth" if ds.poses is not None else "stage"
    P = ds.poses if ds.poses is not None else stage_transform(ds.stage)
    pv = vector_from_pose(P) if len(P) else np.zeros((0, 6))
    C = ds.couplings
    n_so, n_se = ds.n_source, ds.n_sensor
    c_names = [f"c_{i}_{j}" for i in range(n_so) for j in range(n_se)]
    cplx = np.iscomplexobj(C)
    header = _POSE_COLS + c_names + ([c + "_im" for c in c_names] if cplx else []) \
        + _STAGE_COLS + _STR_COLS
    flat = C.reshape(len(C), -1)
    files = ds.file_names()
    path = Path(path)
    with atomic_path(path, suffix=".csv") as tmp, open(tmp, "w", newline="",
                                                        encoding="utf-8") as fh:
        fh.write(f"{_MAGIC}; pose={kind}; units: m, rad (rotation vector); "
                 "C[i,j] = source i into sensor j\n")
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(header)
        for k in range(len(C)):
            row = [repr(float(v)) for v in pv[k]]
            if cplx:
                row += [repr(float(v)) for v in flat[k].real]
                row += [repr(float(v)) for v in flat[k].imag]
            else:
                row += [repr(float(v)) for v in flat[k]]
            row += [repr(float(v)) for v in ds.stage[k]]
            row += [ds.source_fixture[k], ds.sensor_fixture[k], ds.pattern[k], files[k]]
            w.writerow(row)
    return path


def import_csv(path) -> Dataset:
    """Read a couplings CSV written by :func:`export_csv` (or any CSV with the same columns).

    Required columns: ``x, y, z, rx, ry, rz`` and ``c_<i>_<j>`` for every source i and sensor j
    (``c_<i>_<j>_im`` optional). With ``pose=truth`` (or no comment line) the pose columns
    become ``Dataset.poses``. ``stage_*`` columns become the stage (zeros when absent); missing
    string columns become empty strings.
    """
    path = Path(path)
    lines = read_text(path, "a couplings CSV file").splitlines()
    kind = "truth"
    comments = [ln for ln in lines if ln.lstrip().startswith("#")]
    numbered = [(k, ln) for k, ln in enumerate(lines, 1)
                if ln.strip() and not ln.lstrip().startswith("#")]
    rows_text = [ln for _, ln in numbered]
    for c in comments:
        m = re.search(r"pose=(\w+)", c)
        if m:
            kind = m.group(1)
    if kind not in ("truth", "stage"):
        raise InputError(f"{path.name}: expected pose=truth or pose=stage in the comment line, "
                         f"got pose={kind}")
    if not rows_text:
        raise InputError(f"{path.name}: expected a CSV header line, got an empty file")
    reader = csv.reader(rows_text)
    header = [h.strip() for h in next(reader)]
    col = {h: i for i, h in enumerate(header)}
    missing = [c for c in _POSE_COLS if c not in col]
    if missing:
        raise InputError(f"{path.name}: expected columns {_POSE_COLS}, got header without {missing}")
    idx = [(int(m.group(1)), int(m.group(2)), bool(m.group(3)))
           for m in (_C_RE.match(h) for h in header) if m]
    if not idx:
        raise InputError(f"{path.name}: expected coupling columns c_<i>_<j>, got none in the header")
    n_so = 1 + max(i for i, _, _ in idx)
    n_se = 1 + max(j for _, j, _ in idx)
    for i in range(n_so):
        for j in range(n_se):
            if f"c_{i}_{j}" not in col:
                raise InputError(f"{path.name}: expected column c_{i}_{j} "
                                 f"({n_so} x {n_se} couplings), got none")
    cplx = any(im for _, _, im in idx)
    data = list(reader)
    n = len(data)
    num = np.empty((n, len(header)), dtype=np.float64)
    num_cols = [k for k, h in enumerate(header) if h not in _STR_COLS]
    strs = {h: [] for h in _STR_COLS if h in col}
    for r, row in enumerate(data):
        if len(row) != len(header):
            raise InputError(f"{path.name}: line {numbered[r + 1][0]}: expected {len(header)} "
                             f"fields, got {len(row)}")
        for k in num_cols:
            try:
                num[r, k] = float(row[k])
            except ValueError:
                raise InputError(f"{path.name}: line {numbered[r + 1][0]}: column "
                                 f"{header[k]!r}: expected a number, got {row[k][:30]!r}") from None
        for h, values in strs.items():
            values.append(row[col[h]])
    C = np.empty((n, n_so, n_se), dtype=np.complex128 if cplx else np.float64)
    for i in range(n_so):
        for j in range(n_se):
            v = num[:, col[f"c_{i}_{j}"]]
            if cplx:
                im = f"c_{i}_{j}_im"
                v = v.astype(np.complex128)
                v.imag = num[:, col[im]] if im in col else 0.0
            C[:, i, j] = v
    pv = num[:, [col[c] for c in _POSE_COLS]]
    if all(c in col for c in _STAGE_COLS):
        stage = num[:, [col[c] for c in _STAGE_COLS]]
    else:
        stage = np.zeros((n, 6))
    for name, cols, v in (("pose", _POSE_COLS, pv), ("stage", _STAGE_COLS, stage)):
        bad = ~np.isfinite(v)
        if bad.any():
            r, k = np.argwhere(bad)[0]
            raise InputError(f"{path.name}: line {numbered[r + 1][0]}: column {cols[k]!r}: "
                             f"expected a finite {name} value, got {v[r, k]!r}")
    poses = pose_from_vector(pv) if kind == "truth" else None
    file_col = strs.get("file", [""] * n)
    files = list(dict.fromkeys(f for f in file_col if f))
    fidx = {f: i for i, f in enumerate(files)}
    file_index = np.array([fidx.get(f, -1) for f in file_col], dtype=np.int64)
    return Dataset(
        couplings=C, stage=stage,
        source_fixture=np.array(strs.get("source_fixture", [""] * n), dtype=str),
        sensor_fixture=np.array(strs.get("sensor_fixture", [""] * n), dtype=str),
        pattern=np.array(strs.get("pattern", [""] * n), dtype=str),
        file_index=file_index, files=tuple(files), poses=poses,
        meta={"format": "openemt-csv", "file": path.name, "pose_columns": kind},
    )
