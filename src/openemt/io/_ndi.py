"""NDI Toolbox (Track) tab-separated exports: per-tool poses of NDI Aurora / Polaris trackers.

The header has one block of columns per tool, each starting at ``Port``::

    [Tools,] Port, Frame, Face, State, Q0, Qx, Qy, Qz, Tx, Ty, Tz, Error, Markers[, ...]

with scalar-first unit quaternions (Q0 = w) and translations in mm; a tool pose maps tool
(sensor) coordinates into the field generator (source) frame, the openemt convention. Rows
whose ``State`` is not ``OK`` (``Missing``, ``Out of Volume``, ...) are skipped and counted per
state. Comma-separated files with the same header are accepted too.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from .._errors import InputError
from ..geometry import pose_from_rt
from ._poses_csv import StaticAverage, average_static

__all__ = ["NdiRecording", "NdiTool", "read_ndi_tsv"]

_FIELDS = ("frame", "face", "state", "q0", "qx", "qy", "qz", "tx", "ty", "tz", "error",
           "markers")
_REQUIRED = ("state", "q0", "qx", "qy", "qz", "tx", "ty", "tz")


@dataclass(frozen=True, eq=False)
class NdiTool:
    """Valid samples of one tool (port).

    Attributes
    ----------
    port : str
    frame : ndarray of int, shape (N,)
        Tracker frame numbers (-1 if missing).
    face : ndarray of int, shape (N,)
    poses : ndarray, shape (N, 4, 4)
        Tool pose in the field-generator frame (m).
    error : ndarray, shape (N,)
        NDI's per-frame RMS fit error, converted to metres (NaN if absent).
    markers : ndarray of int, shape (N,)
    line : ndarray of int, shape (N,)
        1-based line number in the file of each sample.
    n_rows : int
        Data rows read for this tool (valid + skipped).
    skipped : dict
        Count of skipped rows per state (``{"Missing": 3, ...}``).
    """

    port: str
    frame: np.ndarray
    face: np.ndarray
    poses: np.ndarray
    error: np.ndarray
    markers: np.ndarray
    line: np.ndarray
    n_rows: int
    skipped: dict = field(default_factory=dict)

    @property
    def n_skipped(self) -> int:
        return int(sum(self.skipped.values()))

    def average(self) -> StaticAverage:
        """Treat the recording as one static pose: mean pose and jitter."""
        return average_static(self.poses)


@dataclass(frozen=True, eq=False)
class NdiRecording:
    """All tools of one NDI Toolbox export."""

    tools: tuple
    source: str = ""

    def tool(self, port) -> NdiTool:
        """The tool on ``port`` (e.g. ``"10A"``)."""
        for t in self.tools:
            if t.port == str(port):
                return t
        raise KeyError(f"expected a port in {[t.port for t in self.tools]}, got {port!r}")

    def summary(self) -> dict:
        return {"source": self.source,
                "tools": [{"port": t.port, "n_rows": t.n_rows, "n_valid": len(t.poses),
                           "n_skipped": t.n_skipped, "skipped": dict(t.skipped)}
                          for t in self.tools]}


def _num(s: str) -> float:
    s = s.strip()
    return float(s) if s else float("nan")


def read_ndi_tsv(path) -> NdiRecording:
    """Read an NDI Toolbox TSV export.

    Parameters
    ----------
    path : path-like

    Returns
    -------
    NdiRecording
        One :class:`NdiTool` per ``Port`` block, holding only rows with ``State == OK``
        (case-insensitive); the other rows are counted in ``NdiTool.skipped``.
    """
    path = Path(path)
    with open(path, newline="") as fh:
        lines = fh.read().splitlines()
    hdr_i = next((i for i, ln in enumerate(lines)
                  if "port" in [c.strip().lower() for c in ln.replace("\t", ",").split(",")]),
                 None)
    if hdr_i is None:
        raise InputError(f"expected an NDI Toolbox header with a 'Port' column in {path}, "
                         f"got none")
    delim = "\t" if "\t" in lines[hdr_i] else ","
    header = [c.strip().lower() for c in lines[hdr_i].split(delim)]
    starts = [i for i, c in enumerate(header) if c == "port"]
    blocks = []
    for b, s in enumerate(starts):
        end = starts[b + 1] if b + 1 < len(starts) else len(header)
        cols = {}
        for j in range(s + 1, end):
            if header[j] in _FIELDS and header[j] not in cols:
                cols[header[j]] = j
        missing = [f for f in _REQUIRED if f not in cols]
        if missing:
            raise InputError(f"expected columns {', '.join(_REQUIRED)} after Port in {path}, "
                             f"got no {', '.join(missing)} for tool block {b + 1}")
        blocks.append((s, cols))

    acc = [{"port": Counter(), "rows": [], "n": 0, "skipped": Counter()} for _ in blocks]
    for ln_no, ln in enumerate(lines[hdr_i + 1:], start=hdr_i + 2):
        if not ln.strip():
            continue
        parts = ln.split(delim)
        for a, (s, cols) in zip(acc, blocks):
            need = max(cols.values())
            a["n"] += 1
            if len(parts) <= need or not parts[s].strip():
                state = parts[cols["state"]].strip() if len(parts) > cols["state"] else ""
                a["skipped"][state or "Missing"] += 1
                continue
            state = parts[cols["state"]].strip()
            if state.lower() != "ok":
                a["skipped"][state or "Missing"] += 1
                continue
            try:
                vals = {f: _num(parts[j]) for f, j in cols.items() if f != "state"}
            except ValueError:
                raise InputError(f"expected numbers in the tool fields on line {ln_no} of "
                                 f"{path}, got {ln[:60]!r}") from None
            a["port"][parts[s].strip()] += 1
            a["rows"].append((ln_no, vals))

    tools = []
    for b, a in enumerate(acc):
        port = a["port"].most_common(1)[0][0] if a["port"] else f"tool{b + 1}"
        rows = a["rows"]
        n = len(rows)

        def col(name, default=np.nan, rows=rows):
            return np.array([r[1].get(name, default) for r in rows], dtype=float)

        q = np.stack([col("q0"), col("qx"), col("qy"), col("qz")], axis=1).reshape(n, 4)
        t = np.stack([col("tx"), col("ty"), col("tz")], axis=1).reshape(n, 3) * 1e-3
        norm = np.linalg.norm(q, axis=1)
        if n and not np.all(np.isfinite(norm) & (norm > 0)):
            bad = int(np.flatnonzero(~(np.isfinite(norm) & (norm > 0)))[0])
            raise InputError(f"expected a non-zero quaternion on line {rows[bad][0]} of {path}, "
                             f"got {q[bad].tolist()}")
        R = (Rotation.from_quat(q / norm[:, None], scalar_first=True).as_matrix() if n
             else np.zeros((0, 3, 3)))

        def icol(name):
            v = col(name)
            return np.where(np.isfinite(v), v, -1).astype(np.int64)

        tools.append(NdiTool(port=port, frame=icol("frame"), face=icol("face"),
                             poses=pose_from_rt(R, t), error=col("error") * 1e-3,
                             markers=icol("markers"),
                             line=np.array([r[0] for r in rows], dtype=np.int64),
                             n_rows=int(a["n"]), skipped=dict(a["skipped"])))
    return NdiRecording(tools=tuple(tools), source=str(path))
