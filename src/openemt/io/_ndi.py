"""NDI Toolbox (Track) tab-separated exports: per-tool poses of NDI Aurora / Polaris trackers.

The header has one block of columns per tool. A block starts at the tool's port column and
holds the fields of that tool::

    Tools <TAB> Port 10: NDI-MF2 610066   T6d0-S00108  s/n:37B31800 Channel:0 <TAB> Frame <TAB>
    Face <TAB> State <TAB> Q0 <TAB> Qx <TAB> Qy <TAB> Qz <TAB> Tx <TAB> Ty <TAB> Tz <TAB> Error
    <TAB> Markers <TAB> Port 11: ... <TAB> Frame ...

The port column is named by the tool's full port label (``Port 10: ...``, ``Port 1: CAMP
OT-Sensor-2013-05-08  s/n:38A1FC00``; inner spaces kept as written) or just ``Port``. Each row
starts with the tool count and repeats the same fields per tool: the label (or port), frame
number, face, state, a scalar-first unit quaternion (Q0 = w), the translation in mm, the RMS
fit error (mm) and the marker count. A tool pose maps tool (sensor) coordinates into the field
generator / camera frame, the openemt convention.

Rows whose ``State`` is not ``OK`` (``Missing``, ``Too Few Markers``, ``Out of Volume``, ...;
their pose fields hold the sentinel ``-3.697314E28`` or nothing) are skipped and counted per
state. A row whose field count differs from the header's (a truncated last row, a damaged
line) is not used and is reported with its line number in :attr:`NdiRecording.bad_rows`.
A byte-order mark, CRLF line ends and trailing tabs are accepted; comma-separated files with
the same header are accepted too. See docs/correction.md#importers-openemtio.
"""

from __future__ import annotations

import re
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from .._errors import InputError
from ..geometry import pose_from_rt
from ._poses_csv import StaticAverage, average_static
from ._safefile import MAX_TEXT_BYTES, read_limited

__all__ = ["SENTINEL_ABS", "NdiRecording", "NdiTool", "ToolNotFoundError", "import_ndi",
           "read_ndi_tsv", "write_ndi_tsv"]

_FIELDS = ("frame", "face", "state", "q0", "qx", "qy", "qz", "tx", "ty", "tz", "error",
           "markers")
_REQUIRED = ("state", "q0", "qx", "qy", "qz", "tx", "ty", "tz")
#: A port column: ``Port`` alone or a full label ``Port 10: ...`` / ``Port 10A``.
_PORT_RE = re.compile(r"^port(?:\s+([0-9]+[a-z]?)\b\s*:?.*)?$", re.IGNORECASE | re.DOTALL)
#: Pose fields larger than this are NDI's "no value" sentinel (-3.697314E28).
SENTINEL_ABS = 1e20
#: Number of bad line numbers listed in a summary (all are counted).
_MAX_LISTED = 20


class ToolNotFoundError(InputError, KeyError):
    """No tool (or more than one) matches the requested port or label."""

    __str__ = InputError.__str__


def _norm_label(s: str) -> str:
    return " ".join(str(s).split()).lower()


@dataclass(frozen=True, eq=False)
class NdiTool:
    """Valid samples of one tool (port).

    Attributes
    ----------
    port : str
        Port number as written (``"10"``, ``"10A"``).
    frame : ndarray of int, shape (N,)
        Tracker frame numbers (-1 if missing).
    face : ndarray of int, shape (N,)
    poses : ndarray, shape (N, 4, 4)
        Tool pose in the field-generator (or camera) frame (m).
    error : ndarray, shape (N,)
        NDI's per-frame RMS fit error, converted to metres (NaN if absent).
    markers : ndarray of int, shape (N,)
    line : ndarray of int, shape (N,)
        1-based line number in the file of each sample.
    n_rows : int
        Rows of the right length read for this tool (valid + skipped).
    skipped : dict
        Count of skipped rows per state (``{"Missing": 3, "Too Few Markers": 2}``).
    label : str
        Full port label (``"Port 10: NDI-MF2 610066 ..."``), as in the file.
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
    label: str = ""

    @property
    def n_skipped(self) -> int:
        return int(sum(self.skipped.values()))

    def average(self) -> StaticAverage:
        """Treat the recording as one static pose: mean pose and jitter."""
        return average_static(self.poses)


@dataclass(frozen=True, eq=False)
class NdiRecording:
    """All tools of one NDI Toolbox export.

    Attributes
    ----------
    tools : tuple of NdiTool
    source : str
        The file read.
    bad_rows : tuple of dict
        Rows not used because their field count (or a number in them) is wrong:
        ``{"line", "fields", "expected", "reason"}``, in file order.
    """

    tools: tuple
    source: str = ""
    bad_rows: tuple = ()

    def tool(self, key) -> NdiTool:
        """The tool named by port number (``"10"``, ``10``, ``"10A"``), ``"Port 10"`` or its
        full label (inner whitespace and case ignored)."""
        k = _norm_label(key)
        if k.startswith("port ") and ":" not in k:
            k = k[5:].strip()
        hits = [t for t in self.tools if t.port.lower() == k or _norm_label(t.label) == k]
        if len(hits) == 1:
            return hits[0]
        names = [f"{t.port} ({t.label})" if t.label and t.label != t.port else t.port
                 for t in self.tools]
        what = "one" if not hits else f"{len(hits)} (use the full label)"
        raise ToolNotFoundError(f"expected a tool port or label among {names} in "
                                f"{self.source}, got {str(key)!r} matching {what}")

    def summary(self) -> dict:
        return {"source": self.source,
                "n_bad_rows": len(self.bad_rows),
                "bad_lines": [b["line"] for b in self.bad_rows[:_MAX_LISTED]],
                "tools": [{"port": t.port, "label": t.label, "n_rows": t.n_rows,
                           "n_valid": len(t.poses), "n_skipped": t.n_skipped,
                           "skipped": dict(t.skipped)}
                          for t in self.tools]}


def _num(s: str) -> float:
    s = s.strip()
    return float(s) if s else float("nan")


def _header(lines, path):
    for i, ln in enumerate(lines):
        delim = "\t" if "\t" in ln else ","
        cells = [c.strip() for c in ln.split(delim)]
        if any(_PORT_RE.match(c) for c in cells):
            while cells and not cells[-1]:
                cells.pop()
            return i, delim, cells
    raise InputError(f"expected an NDI Toolbox header with a 'Port' column in {path}, got none")


def _blocks(cells, path):
    starts = [i for i, c in enumerate(cells) if _PORT_RE.match(c)]
    lower = [c.lower() for c in cells]
    blocks = []
    for b, s in enumerate(starts):
        end = starts[b + 1] if b + 1 < len(starts) else len(cells)
        cols = {}
        for j in range(s + 1, end):
            if lower[j] in _FIELDS and lower[j] not in cols:
                cols[lower[j]] = j
        missing = [f for f in _REQUIRED if f not in cols]
        if missing:
            raise InputError(f"expected columns {', '.join(_REQUIRED)} after the port column "
                             f"{cells[s]!r} in {path}, got no {', '.join(missing)} for tool "
                             f"block {b + 1}")
        m = _PORT_RE.match(cells[s])
        blocks.append({"start": s, "cols": cols, "label": cells[s] if m.group(1) else "",
                       "port": m.group(1) or "", "rows": [], "n": 0, "skipped": Counter(),
                       "row_ports": Counter()})
    return blocks


def read_ndi_tsv(path) -> NdiRecording:
    """Read an NDI Toolbox TSV export (any number of tools).

    Parameters
    ----------
    path : path-like

    Returns
    -------
    NdiRecording
        One :class:`NdiTool` per port block, holding only rows with ``State == OK``
        (case-insensitive) and finite, non-sentinel pose fields; the other rows are counted
        per state in ``NdiTool.skipped``. Rows of the wrong length are listed in
        ``NdiRecording.bad_rows`` with their line number.

    Raises
    ------
    InputError
        No header with a port column, a tool block without the pose columns, or a zero
        quaternion in an ``OK`` row.
    """
    path = Path(path)
    data = read_limited(path, "an NDI Toolbox export (TSV)", MAX_TEXT_BYTES)
    lines = data.decode("utf-8-sig", errors="replace").splitlines()
    hdr_i, delim, cells = _header(lines, path)
    blocks = _blocks(cells, path)
    width = len(cells)
    bad = []
    for ln_no, ln in enumerate(lines[hdr_i + 1:], start=hdr_i + 2):
        if not ln.strip():
            continue
        parts = ln.split(delim)
        while len(parts) > width and not parts[-1].strip():
            parts.pop()  # trailing tabs
        if len(parts) != width:
            bad.append({"line": ln_no, "fields": len(parts), "expected": width,
                        "reason": "truncated row" if len(parts) < width else "too many fields"})
            continue
        parsed = []
        for blk in blocks:
            s, cols = blk["start"], blk["cols"]
            label = parts[s].strip()
            state = parts[cols["state"]].strip()
            if blk["label"] and label and _norm_label(label) != _norm_label(blk["label"]):
                bad.append({"line": ln_no, "fields": len(parts), "expected": width,
                            "reason": f"tool label {label!r} differs from the header's"})
                parsed = None
                break
            if not label or state.lower() != "ok":
                parsed.append((blk, state or "Missing", None))
                continue
            try:
                vals = {f: _num(parts[j]) for f, j in cols.items() if f != "state"}
            except ValueError:
                bad.append({"line": ln_no, "fields": len(parts), "expected": width,
                            "reason": "non-numeric tool field"})
                parsed = None
                break
            pose_vals = [vals[f] for f in ("q0", "qx", "qy", "qz", "tx", "ty", "tz")]
            if not all(np.isfinite(v) and abs(v) < SENTINEL_ABS for v in pose_vals):
                parsed.append((blk, "OK without a pose", None))
                continue
            parsed.append((blk, "OK", (ln_no, label, vals)))
        if parsed is None:
            continue
        for blk, state, row in parsed:
            blk["n"] += 1
            if row is None:
                blk["skipped"][state] += 1
            else:
                blk["rows"].append(row)
                blk["row_ports"][row[1]] += 1

    tools = []
    for b, blk in enumerate(blocks):
        port = blk["port"]
        if not port:
            port = (blk["row_ports"].most_common(1)[0][0] if blk["row_ports"]
                    else f"tool{b + 1}")
        rows = blk["rows"]
        n = len(rows)

        def col(name, default=np.nan, rows=rows):
            return np.array([r[2].get(name, default) for r in rows], dtype=float)

        q = np.stack([col("q0"), col("qx"), col("qy"), col("qz")], axis=1).reshape(n, 4)
        t = np.stack([col("tx"), col("ty"), col("tz")], axis=1).reshape(n, 3) * 1e-3
        norm = np.linalg.norm(q, axis=1)
        if n and not np.all(norm > 0):
            k = int(np.flatnonzero(~(norm > 0))[0])
            raise InputError(f"expected a non-zero quaternion on line {rows[k][0]} of {path}, "
                             f"got {q[k].tolist()}")
        R = (Rotation.from_quat(q / norm[:, None], scalar_first=True).as_matrix() if n
             else np.zeros((0, 3, 3)))

        def icol(name, col=col, rows=rows):
            v = col(name)
            # a count or a number: an integer (missing or non-finite: -1); another number
            # (a fraction, or beyond int64) is refused rather than cast to garbage
            bad = np.isfinite(v) & ((v != np.round(v)) | (np.abs(v) >= 2.0 ** 63))
            if bad.any():
                k = int(np.flatnonzero(bad)[0])
                raise InputError(f"expected an integer {name} on line {rows[k][0]} of {path}, "
                                 f"got {float(v[k])!r}")
            return np.where(np.isfinite(v), v, -1).astype(np.int64)

        tools.append(NdiTool(port=port, frame=icol("frame"), face=icol("face"),
                             poses=pose_from_rt(R, t), error=col("error") * 1e-3,
                             markers=icol("markers"),
                             line=np.array([r[0] for r in rows], dtype=np.int64),
                             n_rows=int(blk["n"]), skipped=dict(blk["skipped"]),
                             label=blk["label"] or port))
    return NdiRecording(tools=tuple(tools), source=str(path), bad_rows=tuple(bad))


_SENTINEL_TEXT = "-3.697314E28"


def write_ndi_tsv(path, tools, *, errors=None, first_frame: int = 1) -> Path:
    """Write poses as an NDI Toolbox TSV export in the layout :func:`read_ndi_tsv` reads.

    Parameters
    ----------
    path : path-like
        File to write (atomically: a temporary file renamed on success).
    tools : dict of str -> ndarray, shape (N, 4, 4)
        Port label (``"Port 10: ..."``, ``"Port 1"``) -> tool poses in the tracker's frame (m),
        the same N rows for every tool. A row with a non-finite pose is written as
        ``Missing`` (NDI's sentinel in the pose fields).
    errors : dict of str -> ndarray, shape (N,), optional
        RMS fit error of each tool and row (m; written in mm). Default 0.
    first_frame : int
        Frame number of the first row (frames count up by one).

    Returns
    -------
    Path
    """
    from .._atomic import atomic_path

    labels = list(tools)
    if not labels:
        raise InputError("expected at least one tool to write, got none")
    P = {lab: np.asarray(tools[lab], dtype=np.float64) for lab in labels}
    n = len(P[labels[0]])
    for lab in labels:
        if P[lab].shape != (n, 4, 4):
            raise InputError(f"expected poses of shape ({n}, 4, 4) for tool {lab!r}, got "
                             f"{P[lab].shape}")
        if not _PORT_RE.match(lab.strip()):
            raise InputError(f"expected a port label like 'Port 10' or 'Port 10: ...', got "
                             f"{lab!r}")
    head = ["Tools"]
    for lab in labels:
        head += [lab, "Frame", "Face", "State", "Q0", "Qx", "Qy", "Qz", "Tx", "Ty", "Tz",
                 "Error", "Markers"]
    cols = {}
    for lab in labels:
        ok = np.all(np.isfinite(P[lab].reshape(n, 16)), axis=1)
        q = np.full((n, 4), np.nan)
        if ok.any():
            q[ok] = Rotation.from_matrix(P[lab][ok, :3, :3]).as_quat(scalar_first=True)
        err = np.zeros(n) if errors is None or lab not in errors else \
            np.asarray(errors[lab], dtype=np.float64).reshape(n)
        cols[lab] = (ok, q, P[lab][:, :3, 3] * 1e3, err * 1e3)
    lines = ["\t".join(head)]
    for k in range(n):
        cells = [str(len(labels))]
        for lab in labels:
            ok, q, t, err = cols[lab]
            cells += [lab, str(first_frame + k), "0"]
            if ok[k]:
                cells += (["OK"] + [f"{v:.6f}" for v in q[k]] + [f"{v:.4f}" for v in t[k]]
                          + [f"{err[k]:.4f}", "0"])
            else:
                cells += ["Missing"] + [_SENTINEL_TEXT] * 8 + ["0"]
        lines.append("\t".join(cells))
    path = Path(path)
    with atomic_path(path, suffix=".tsv") as tmp:
        Path(tmp).write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def import_ndi(paths, *, tool=None, average: bool = False):
    """Read NDI Toolbox exports of one tool into a pose dataset.

    Parameters
    ----------
    paths : sequence of path-like
        Export files, in order.
    tool : str or int, optional
        Port number (``10``) or label of the tool; required when a file holds several tools.
    average : bool
        Treat each file as one static pose: one row per file (in the order given), the mean
        pose, with the jitter in ``extra`` (``n_averaged``, ``jitter_trans_rms`` in m,
        ``jitter_rot_rms`` in rad).

    Returns
    -------
    (Dataset, dict)
        The pose dataset (:func:`openemt.io.pose_dataset`) and a JSON-able summary: per file
        the tool, rows read, valid rows, skipped rows per state and the bad rows' line numbers.
    """
    from ._pose_dataset import pose_dataset

    paths = [Path(p) for p in paths]
    if not paths:
        raise InputError("expected at least one NDI export file, got none")
    P, frames, err, fidx, files, per_file = [], [], [], [], [], []
    jit = {"n_averaged": [], "jitter_trans_rms": [], "jitter_rot_rms": []}
    skipped = Counter()
    labels = set()
    for i, path in enumerate(paths):
        rec = read_ndi_tsv(path)
        if tool is None:
            if len(rec.tools) != 1:
                names = [f"{t.port} ({t.label})" for t in rec.tools]
                raise InputError(f"expected --tool PORT_OR_LABEL for {path}, which holds "
                                 f"{len(rec.tools)} tools: {names}")
            t = rec.tools[0]
        else:
            t = rec.tool(tool)
        labels.add(t.label)
        skipped.update(t.skipped)
        info = {"file": str(path), "port": t.port, "label": t.label, "n_rows": t.n_rows,
                "n_valid": len(t.poses), "skipped": dict(t.skipped),
                "n_bad_rows": len(rec.bad_rows),
                "bad_lines": [b["line"] for b in rec.bad_rows[:_MAX_LISTED]]}
        files.append(path.name)
        if average:
            if not len(t.poses):
                raise InputError(f"expected at least one OK sample of tool {t.port} to average "
                                 f"in {path}, got none ({dict(t.skipped)})")
            a = t.average()
            P.append(a.poses)
            frames.append(t.frame[:1])
            err.append([np.nanmean(t.error)] if np.isfinite(t.error).any() else [np.nan])
            jit["n_averaged"].append(a.counts)
            jit["jitter_trans_rms"].append(a.jitter_trans_rms)
            jit["jitter_rot_rms"].append(a.jitter_rot_rms)
            fidx.append([i])
            info["jitter_trans_sd_mm"] = float(1e3 * a.jitter_trans_rms[0])
            info["jitter_rot_sd_deg"] = float(np.rad2deg(a.jitter_rot_rms[0]))
        else:
            P.append(t.poses)
            frames.append(t.frame)
            err.append(t.error)
            fidx.append(np.full(len(t.poses), i))
        per_file.append(info)
    extra = {"frame": np.concatenate(frames).astype(np.int64),
             "error": np.concatenate([np.asarray(e, float) for e in err])}
    if average:
        extra.update({k: np.concatenate(v) for k, v in jit.items()})
    ds = pose_dataset(np.concatenate(P), file_index=np.concatenate(fidx).astype(np.int64),
                      files=files, extra=extra,
                      meta={"format": "ndi-tsv", "tool": sorted(labels),
                            "averaged_static": bool(average),
                            "units": {"poses": "m", "error": "m", "jitter_trans_rms": "m",
                                      "jitter_rot_rms": "rad"},
                            "provenance": {"importer": "openemt.io.import_ndi",
                                           "inputs": [str(p) for p in paths]}})
    summary = {"n_samples": ds.n_samples, "averaged_static": bool(average),
               "skipped": dict(skipped), "n_skipped": int(sum(skipped.values())),
               "n_bad_rows": int(sum(f["n_bad_rows"] for f in per_file)), "files": per_file}
    return ds, summary
