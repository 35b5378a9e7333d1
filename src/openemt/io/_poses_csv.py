"""Generic CSV of tracker poses (optionally with reference poses), and static averaging.

For trackers that give only poses (NDI Aurora, Polhemus, ...). One row per sample; the header
names the columns (case-insensitive, any order, extra columns ignored)::

    pose_id,time,x_mm,y_mm,z_mm,qw,qx,qy,qz,ref_x_mm,ref_y_mm,ref_z_mm,ref_qw,ref_qx,ref_qy,ref_qz

* position: ``x, y, z`` with an optional unit suffix ``_m`` or ``_mm`` (no suffix: metres,
  unless ``length_unit`` says otherwise);
* orientation, one of: rotation vector ``rx, ry, rz`` (suffix ``_rad`` or ``_deg``; no suffix:
  radians) or scalar-first quaternion ``qw, qx, qy, qz``; none: position-only rows (identity
  rotation, ``has_orientation`` False);
* reference pose: the same columns with the prefix ``ref_``;
* ``pose_id`` (or ``group``): label of the static pose a sample belongs to; ``time`` or
  ``time_s`` (s); ``frame``: the tracker's frame number; ``sensor``: the sensor's name (a
  several-sensor ``openemt track --log`` CSV); any other numeric column (``status``, ...) is
  kept in ``PoseTable.columns``.

Rows of the wrong length (a truncated last row) and rows with empty or non-finite pose values
are read as NaN rows and listed by line number (``PoseTable.bad_lines``,
``PoseTable.nonfinite_lines``), so the callers can count and report them.

:func:`average_static` averages the samples of each static pose and reports their jitter.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from .._atomic import atomic_path
from .._errors import InputError
from ..geometry import check_poses, pose_from_rt, vector_from_pose
from ._safefile import read_text

__all__ = ["PoseTable", "StaticAverage", "average_static", "import_poses_csv", "read_poses_csv",
           "write_poses_csv"]

_LEN = {"m": 1.0, "mm": 1e-3}
_ANG = {"rad": 1.0, "deg": np.pi / 180}


@dataclass(frozen=True, eq=False)
class PoseTable:
    """Poses read from a CSV file.

    Attributes
    ----------
    poses : ndarray, shape (N, 4, 4)
        Measured poses (m).
    reference : ndarray, shape (N, 4, 4) or None
        Reference (ground-truth) poses if the file has ``ref_`` columns.
    group : ndarray of str, shape (N,) or None
        Static-pose label per row (``pose_id`` column).
    time : ndarray, shape (N,) or None
    has_orientation, reference_has_orientation : bool
        False when the file gives positions only (rotations are then identity).
    source : str
        File the table was read from.
    frame : ndarray of int, shape (N,) or None
        Tracker frame numbers (``frame`` column; -1 where empty).
    bad_lines : tuple of int
        Line numbers of rows with the wrong number of fields (kept as NaN rows).
    nonfinite_lines : tuple of int
        Line numbers of the other rows with a missing or non-finite pose value.
    sensor : ndarray of str, shape (N,) or None
        ``sensor`` column.
    columns : dict of str -> ndarray, shape (N,)
        The other numeric columns by header name (NaN where empty or not a number).
    """

    poses: np.ndarray
    reference: np.ndarray | None = None
    group: np.ndarray | None = None
    time: np.ndarray | None = None
    has_orientation: bool = True
    reference_has_orientation: bool = False
    source: str = ""
    frame: np.ndarray | None = None
    bad_lines: tuple = ()
    nonfinite_lines: tuple = ()
    sensor: np.ndarray | None = None
    columns: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.poses)


@dataclass(frozen=True, eq=False)
class StaticAverage:
    """Per-pose averages of static recordings and their jitter.

    Attributes
    ----------
    labels : ndarray, shape (G,)
        Group labels, in order of first appearance.
    poses : ndarray, shape (G, 4, 4)
        Mean pose of each group: mean position, chordal-L2 mean rotation
        (``scipy Rotation.mean``).
    counts : ndarray of int, shape (G,)
    jitter_trans_rms, jitter_trans_max : ndarray, shape (G,)
        RMS and max distance (m) of the samples from the mean position.
    jitter_rot_rms, jitter_rot_max : ndarray, shape (G,)
        RMS and max angle (rad) of the samples from the mean rotation.
    """

    labels: np.ndarray
    poses: np.ndarray
    counts: np.ndarray
    jitter_trans_rms: np.ndarray
    jitter_trans_max: np.ndarray
    jitter_rot_rms: np.ndarray
    jitter_rot_max: np.ndarray

    def summary(self) -> dict:
        """Overall jitter in mm/deg: RMS over all samples and the worst group maximum."""
        n = self.counts.astype(float)
        return {
            "n_groups": len(self.labels), "n_samples": int(n.sum()),
            "jitter_trans_rms_mm": float(1e3 * np.sqrt(np.sum(n * self.jitter_trans_rms ** 2)
                                                       / n.sum())),
            "jitter_trans_max_mm": float(1e3 * self.jitter_trans_max.max()),
            "jitter_rot_rms_deg": float(np.rad2deg(np.sqrt(np.sum(n * self.jitter_rot_rms ** 2)
                                                           / n.sum()))),
            "jitter_rot_max_deg": float(np.rad2deg(self.jitter_rot_max.max())),
        }


def average_static(poses, groups=None) -> StaticAverage:
    """Average static recordings per pose and report their jitter.

    Parameters
    ----------
    poses : array_like, shape (N, 4, 4)
        Samples (non-finite rows are ignored).
    groups : array_like, shape (N,), optional
        Label of the static pose each sample belongs to; ``None``: all samples are one pose.

    Returns
    -------
    StaticAverage
    """
    P = check_poses(poses, "poses", batch=True)
    g = np.zeros(len(P), dtype=int) if groups is None else np.asarray(groups)
    if g.shape != (len(P),):
        raise InputError(f"expected `groups` of shape ({len(P)},), got {g.shape}")
    ok = np.all(np.isfinite(P), axis=(1, 2))
    P, g = P[ok], g[ok]
    if len(P) == 0:
        raise InputError("expected at least one finite pose to average, got none")
    _, first = np.unique(g, return_index=True)
    labels = g[np.sort(first)]
    out = {k: [] for k in ("P", "n", "tr", "tm", "rr", "rm")}
    for lab in labels:
        sel = P[g == lab]
        t = sel[:, :3, 3]
        rot = Rotation.from_matrix(sel[:, :3, :3])
        mean_rot = rot.mean()
        mean_t = t.mean(axis=0)
        dt = np.linalg.norm(t - mean_t, axis=1)
        dr = np.linalg.norm((mean_rot.inv() * rot).as_rotvec(), axis=-1)
        out["P"].append(pose_from_rt(mean_rot.as_matrix(), mean_t))
        out["n"].append(len(sel))
        out["tr"].append(np.sqrt(np.mean(dt ** 2)))
        out["tm"].append(dt.max())
        out["rr"].append(np.sqrt(np.mean(dr ** 2)))
        out["rm"].append(dr.max())
    return StaticAverage(labels=labels, poses=np.stack(out["P"]),
                         counts=np.array(out["n"], dtype=np.int64),
                         jitter_trans_rms=np.array(out["tr"]), jitter_trans_max=np.array(out["tm"]),
                         jitter_rot_rms=np.array(out["rr"]), jitter_rot_max=np.array(out["rm"]))


def _find(cols: dict, name: str, suffixes: dict):
    """Column index and unit factor for ``name`` (with optional unit suffix), else (None, None)."""
    if name in cols:
        return cols[name], None
    for suf, fac in suffixes.items():
        if f"{name}_{suf}" in cols:
            return cols[f"{name}_{suf}"], fac
    return None, None


def _poses_from_columns(cols, data, prefix, length_unit, angle_unit, path):
    idx, facs = [], []
    for a in "xyz":
        i, f = _find(cols, f"{prefix}{a}", _LEN)
        if i is None:
            return None, False
        idx.append(i)
        facs.append(_LEN[length_unit] if f is None else f)
    if len(set(facs)) != 1:
        raise InputError(f"expected one length unit for the {prefix or 'measured '}position in "
                         f"{path}, got several")
    t = data[:, idx] * facs[0]
    q_idx = [cols.get(f"{prefix}q{a}") for a in "wxyz"]
    r_idx = [_find(cols, f"{prefix}r{a}", _ANG) for a in "xyz"]
    if all(i is not None for i in q_idx):
        q = data[:, q_idx]
        norm = np.linalg.norm(q, axis=1, keepdims=True)
        bad = ~(norm[:, 0] > 0)
        q = np.where(bad[:, None], [1.0, 0, 0, 0], q / np.where(norm > 0, norm, 1.0))
        R = Rotation.from_quat(q, scalar_first=True).as_matrix()
        R[bad] = np.nan
        return pose_from_rt(R, t), True
    if all(i is not None for i, _ in r_idx):
        fac = {_ANG[angle_unit] if f is None else f for _, f in r_idx}
        if len(fac) != 1:
            raise InputError(f"expected one angle unit for the {prefix or 'measured '}rotation in "
                             f"{path}, got several")
        rv = data[:, [i for i, _ in r_idx]] * fac.pop()
        rv_ok = np.where(np.isfinite(rv), rv, 0.0)
        R = Rotation.from_rotvec(rv_ok).as_matrix()
        R[~np.all(np.isfinite(rv), axis=1)] = np.nan
        return pose_from_rt(R, t), True
    return pose_from_rt(np.broadcast_to(np.eye(3), (len(t), 3, 3)), t), False


def read_poses_csv(path, *, length_unit: str = "m", angle_unit: str = "rad") -> PoseTable:
    """Read a generic pose CSV (see the module docstring for the columns).

    Parameters
    ----------
    path : path-like
    length_unit : {"m", "mm"}
        Unit of position columns without a unit suffix.
    angle_unit : {"rad", "deg"}
        Unit of rotation-vector columns without a unit suffix.

    Returns
    -------
    PoseTable
        Poses in metres. Empty fields read as NaN. A row with fewer (or more, ignoring empty
        trailing fields) fields than the header, e.g. a truncated last row, is kept as a NaN
        row and its line number is listed in ``bad_lines``; rows with any non-finite pose
        value are listed in ``nonfinite_lines``.
    """
    if length_unit not in _LEN:
        raise InputError(f"expected length_unit in {sorted(_LEN)}, got {length_unit!r}")
    if angle_unit not in _ANG:
        raise InputError(f"expected angle_unit in {sorted(_ANG)}, got {angle_unit!r}")
    path = Path(path)
    text = read_text(path, "a pose CSV file")
    numbered = [(k, ln) for k, ln in enumerate(text.splitlines(), 1)
                if ln.strip() and not ln.lstrip().startswith("#")]
    if not numbered:
        raise InputError(f"expected a header line in {path}, got an empty file")
    delim = "\t" if "\t" in numbered[0][1] else ","
    rows = list(csv.reader([ln for _, ln in numbered], delimiter=delim))
    header = [h.strip().lower() for h in rows[0]]
    while header and not header[-1]:
        header.pop()
    cols = {h: i for i, h in enumerate(header)}
    body = rows[1:]
    line_no = [k for k, _ in numbered[1:]]
    gcol = cols.get("pose_id", cols.get("group"))
    tcol = cols.get("time", cols.get("time_s", cols.get("t")))
    fcol = cols.get("frame")
    scol = cols.get("sensor")
    num_idx = [i for i, h in enumerate(header) if i not in (gcol, scol)]
    data = np.full((len(body), len(header)), np.nan)
    bad = []
    for r, row in enumerate(body):
        while len(row) > len(header) and not row[-1].strip():
            row.pop()
        if len(row) != len(header):
            bad.append(line_no[r])
            continue
        for i in num_idx:
            if row[i].strip():
                try:
                    data[r, i] = float(row[i])
                except ValueError:
                    if header[i] in _ALL_POSE_NAMES:
                        raise InputError(f"expected a number in column {header[i]!r} on line "
                                         f"{line_no[r]} of {path}, got {row[i]!r}") from None
    P, has_rot = _poses_from_columns(cols, data, "", length_unit, angle_unit, path)
    if P is None:
        raise InputError(f"expected columns x, y, z (optionally _m/_mm) in {path}, "
                         f"got {', '.join(header)}")
    Pref, ref_rot = _poses_from_columns(cols, data, "ref_", length_unit, angle_unit, path)
    group, sensor = (None if c is None else np.array(
        [row[c].strip() if c < len(row) else "" for row in body], dtype=str)
        for c in (gcol, scol))
    time = data[:, tcol] if tcol is not None else None
    frame = None
    if fcol is not None:
        f = data[:, fcol]
        frame = np.where(np.isfinite(f) & (np.abs(f) < 2.0**62), f, -1).astype(np.int64)
    finite = np.all(np.isfinite(P), axis=(1, 2))
    if Pref is not None:
        finite &= np.all(np.isfinite(Pref), axis=(1, 2))
    bad_set = set(bad)
    nonfinite = [line_no[r] for r in np.flatnonzero(~finite) if line_no[r] not in bad_set]
    return PoseTable(poses=P, reference=Pref, group=group, time=time, has_orientation=has_rot,
                     reference_has_orientation=bool(Pref is not None and ref_rot),
                     source=str(path), frame=frame, bad_lines=tuple(bad),
                     nonfinite_lines=tuple(int(v) for v in nonfinite), sensor=sensor,
                     columns={h: data[:, i] for i, h in enumerate(header)
                              if i in num_idx and h not in _ALL_POSE_NAMES})


_ALL_POSE_NAMES = {f"{p}{n}{s}" for p in ("", "ref_") for n in
                   ("x", "y", "z", "rx", "ry", "rz", "qw", "qx", "qy", "qz")
                   for s in ("", "_m", "_mm", "_rad", "_deg")} | {"time", "t"}


def write_poses_csv(path, poses, reference=None, group=None, time=None, frame=None,
                    columns=None) -> Path:
    """Write poses (and reference poses) as CSV in metres and rotation vectors (rad), atomically.

    Columns: ``[pose_id,][frame,][time,]x_m,y_m,z_m,rx_rad,ry_rad,rz_rad[,ref_x_m,...,
    ref_rz_rad]`` and then ``columns`` (name -> one value per row, written with ``str``);
    numbers use shortest round-trip precision. Returns the path.
    """
    P = check_poses(poses, "poses", batch=True)
    names = ["x_m", "y_m", "z_m", "rx_rad", "ry_rad", "rz_rad"]
    blocks = [vector_from_pose(P)]
    header = list(names)
    if reference is not None:
        D = check_poses(reference, "reference")
        if D.shape != P.shape:
            raise InputError(f"expected `reference` of shape {P.shape}, got {D.shape}")
        blocks.append(vector_from_pose(D))
        header += ["ref_" + n for n in names]
    num = np.hstack(blocks)
    pre_h, pre = [], []
    if frame is not None:
        fr = np.asarray(frame).astype(np.int64).reshape(-1)
        if fr.shape != (len(P),):
            raise InputError(f"expected `frame` of shape ({len(P)},), got {fr.shape}")
    if time is not None:
        pre_h.append("time")
        pre.append(np.asarray(time, dtype=float).reshape(-1))
    if group is not None:
        g = np.asarray(group).astype(str)
        if g.shape != (len(P),):
            raise InputError(f"expected `group` of shape ({len(P)},), got {g.shape}")
    post = {str(k): np.asarray(v).reshape(-1) for k, v in (columns or {}).items()}
    for k, v in post.items():
        if v.shape != (len(P),):
            raise InputError(f"expected column `{k}` of shape ({len(P)},), got {v.shape}")
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow((["pose_id"] if group is not None else [])
                   + (["frame"] if frame is not None else []) + pre_h + header + list(post))
        for k in range(len(P)):
            row = [str(g[k])] if group is not None else []
            row += [str(int(fr[k]))] if frame is not None else []
            row += [repr(float(c[k])) for c in pre]
            row += [repr(float(v)) for v in num[k]]
            row += [str(v[k]) for v in post.values()]
            w.writerow(row)
    return path


def import_poses_csv(paths, *, average: bool = False, length_unit: str = "m",
                     angle_unit: str = "rad"):
    """Read pose CSV files into a pose dataset (see :func:`openemt.io.pose_dataset`).

    Reference columns (``ref_``) go to ``extra/reference_poses``, a ``frame`` column to
    ``extra/frame``. With ``average``, the samples of each ``pose_id`` (or, without that
    column, of each file) are averaged into one row, in order of appearance.

    Returns
    -------
    (Dataset, dict)
        The dataset and a JSON-able summary (per file: rows, rows with the wrong field count
        and rows with missing values, by line number). Rows with the wrong field count or a
        non-finite pose are not imported.
    """
    from ._pose_dataset import pose_dataset

    paths = [Path(p) for p in paths]
    if not paths:
        raise InputError("expected at least one pose CSV file, got none")
    P, D, frames, fidx, per_file = [], [], [], [], []
    jit = {"n_averaged": [], "jitter_trans_rms": [], "jitter_rot_rms": []}
    has_ref = None
    for i, path in enumerate(paths):
        t = read_poses_csv(path, length_unit=length_unit, angle_unit=angle_unit)
        ref = t.reference is not None
        if has_ref is None:
            has_ref = ref
        elif ref != has_ref:
            raise InputError(f"expected every file {'with' if has_ref else 'without'} ref_ "
                             f"columns, got {path} {'with' if ref else 'without'}")
        ok = np.all(np.isfinite(t.poses), axis=(1, 2))
        if ref:
            ok &= np.all(np.isfinite(t.reference), axis=(1, 2))
        info = {"file": str(path), "n_rows": len(t), "n_valid": int(ok.sum()),
                "n_bad_rows": len(t.bad_lines), "bad_lines": list(t.bad_lines[:20]),
                "n_nonfinite_rows": len(t.nonfinite_lines),
                "nonfinite_lines": list(t.nonfinite_lines[:20])}
        per_file.append(info)
        Pm = t.poses[ok]
        Pd = t.reference[ok] if ref else None
        fr = t.frame[ok] if t.frame is not None else np.full(int(ok.sum()), -1)
        if average:
            groups = t.group[ok] if t.group is not None else None
            if not len(Pm):
                raise InputError(f"expected at least one complete row to average in {path}, "
                                 f"got none")
            a = average_static(Pm, groups)
            if ref:
                Pd = average_static(Pd, groups).poses
            g = np.zeros(len(Pm), int) if groups is None else groups
            fr = np.array([fr[np.flatnonzero(g == lab)[0]] for lab in a.labels])
            Pm = a.poses
            jit["n_averaged"].append(a.counts)
            jit["jitter_trans_rms"].append(a.jitter_trans_rms)
            jit["jitter_rot_rms"].append(a.jitter_rot_rms)
            info["jitter_trans_sd_mm"] = float(1e3 * np.sqrt(np.mean(a.jitter_trans_rms ** 2)))
            info["jitter_rot_sd_deg"] = float(np.rad2deg(np.sqrt(np.mean(a.jitter_rot_rms ** 2))))
        P.append(Pm)
        if ref:
            D.append(Pd)
        frames.append(fr)
        fidx.append(np.full(len(Pm), i))
    extra = {"frame": np.concatenate(frames).astype(np.int64)}
    if has_ref:
        extra["reference_poses"] = np.concatenate(D)
    if average:
        extra.update({k: np.concatenate(v) for k, v in jit.items()})
    ds = pose_dataset(np.concatenate(P), file_index=np.concatenate(fidx).astype(np.int64),
                      files=[p.name for p in paths], extra=extra,
                      meta={"format": "pose-csv", "averaged_static": bool(average),
                            "provenance": {"importer": "openemt.io.import_poses_csv",
                                           "inputs": [str(p) for p in paths]}})
    summary = {"n_samples": ds.n_samples, "averaged_static": bool(average),
               "has_reference": bool(has_ref),
               "n_bad_rows": int(sum(f["n_bad_rows"] for f in per_file)),
               "n_nonfinite_rows": int(sum(f["n_nonfinite_rows"] for f in per_file)),
               "files": per_file}
    return ds, summary
