"""Reference poses with time stamps from a CSV file, read in blocks of rows (bounded memory:
about 100 bytes per row kept, the file itself never held whole), every dropped row counted by
reason."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from .._errors import InputError
from ._gate import MAX_STEP_S, Drops, TimeGate, rigid_rows

__all__ = ["MAX_MEDIAN_STEP_S", "ReferenceTable", "read_reference_csv"]

#: A reference stream samples at least once a second: a median step between time stamps above
#: this (s) is read as times in another unit (milliseconds, say) and refused.
MAX_MEDIAN_STEP_S = 1.0
_BLOCK = 65536          # rows parsed at a time


class ReferenceTable(tuple):
    """``(times (N,), poses (N, 4, 4))`` of a reference CSV; :attr:`drops` counts the rows
    left out, by reason."""

    drops: Drops
    jumped: float | None

    def __new__(cls, t, P, drops, jumped=None):
        self = super().__new__(cls, (t, P))
        self.drops, self.jumped = drops, jumped
        return self


def _fast(lines, delim, header_len):
    """The block as a float array when every row is ``header_len`` numbers (numpy's C parser),
    else None."""
    try:
        out = np.loadtxt(lines, delimiter=delim, ndmin=2, dtype=np.float64, comments=None)
    except ValueError:
        return None
    return out if out.shape == (len(lines), header_len) else None


def _numbers(rows, header_len, drops):
    """Parse a block of CSV rows into a float array (rows that cannot be numbers: NaN rows
    with the reason counted)."""
    out = np.full((len(rows), header_len), np.nan)
    good = np.zeros(len(rows), dtype=bool)
    for r, row in enumerate(rows):
        while len(row) > header_len and not row[-1].strip():
            row.pop()
        if len(row) != header_len:
            drops["wrong_length"] += 1
            continue
        try:
            vals = [float(v) if v.strip() else None for v in row]
        except ValueError:
            drops["not_a_number"] += 1
            continue
        if any(v is None for v in vals):
            drops["empty_field"] += 1
            continue
        out[r] = vals
        good[r] = True
    return out, good


def read_reference_csv(path) -> ReferenceTable:
    """Reference poses with time stamps from a pose CSV.

    The columns are those of :func:`openemt.io.read_poses_csv` (``time`` in seconds of the
    reference's clock, a position and an orientation per row). Rows are read in blocks; a row
    is dropped and counted by reason when it has the wrong length, a field that is empty or not
    a number, a NUL byte, a non-finite value, a zero quaternion (a rotation that is not one), or
    a time stamp that does not continue the stream (:class:`TimeGate`: not increasing, a glitch,
    everything after a jump of the clock). Times whose median step exceeds
    :data:`MAX_MEDIAN_STEP_S` are refused as another unit.
    """
    from ..io._poses_csv import _poses_from_columns

    path = Path(path)
    if not path.is_file():
        raise InputError(f"expected a reference CSV file, got {str(path)!r} (not a regular file)")
    drops = Drops()
    gate = TimeGate(drops)
    ts, Ps = [], []
    with open(path, "rb") as raw:
        text = io.TextIOWrapper(raw, encoding="utf-8", errors="replace", newline="")
        header = None
        steps: list = []
        while True:
            lines = []
            for line in text:
                if "\x00" in line or "\ufffd" in line:
                    drops["nul_or_bad_byte"] += 1
                    continue
                s = line.strip()
                if not s or s.startswith("#"):
                    continue
                lines.append(s)
                if len(lines) >= _BLOCK:
                    break
            if not lines:
                break
            delim = "\t" if "\t" in lines[0] else ","
            if header is None:
                header = [h.strip().lower() for h in next(csv.reader(lines[:1],
                                                                     delimiter=delim))]
                lines = lines[1:]
                while header and not header[-1]:
                    header.pop()
                cols = {h: i for i, h in enumerate(header)}
                tcol = cols.get("time", cols.get("t"))
                if tcol is None:
                    raise InputError(f"expected a `time` column (s) in the reference CSV "
                                     f"{str(path)!r}, got columns {', '.join(header)}")
                probe, has_rot = _poses_from_columns(cols, np.zeros((1, len(header))), "",
                                                     "m", "rad", path)
                if probe is None or not has_rot:
                    raise InputError(f"expected x, y, z and an orientation (qw, qx, qy, qz or "
                                     f"rx, ry, rz) in the reference CSV {str(path)!r}, got "
                                     f"columns {', '.join(header)}")
            data = _fast(lines, delim, len(header)) if lines else np.empty((0, len(header)))
            if data is not None:
                good = np.ones(len(data), dtype=bool)
            else:
                data, good = _numbers(list(csv.reader(lines, delimiter=delim)), len(header),
                                      drops)
            P, _ = _poses_from_columns(cols, data, "", "m", "rad", path)
            t = data[:, tcol]
            fin = good & np.isfinite(t) & np.all(np.isfinite(data), axis=1)
            drops["not_finite"] += int((good & ~fin).sum())
            rigid = rigid_rows(P)
            drops["not_a_rotation"] += int((fin & ~rigid).sum())
            ok = fin & rigid
            t, P = t[ok], P[ok]
            if len(steps) < 1000:
                steps.extend(np.diff(t[:1001]).tolist())
                pos = [s for s in steps if s > 0]
                if len(pos) >= 20 and np.median(pos) > MAX_MEDIAN_STEP_S:
                    raise InputError(
                        f"expected reference times in seconds (a step of at most "
                        f"{MAX_MEDIAN_STEP_S:g} s), got a median step of {np.median(pos):g} "
                        f"in {str(path)!r} (milliseconds? divide the time column by 1000)")
            if gate.last is None and len(t) >= 3:
                # the first rows are not taken on trust: one far from the median of the first
                # nine is a glitch (it would otherwise set the clock that the rest must follow)
                med = np.median(t[:9])
                lead = np.abs(t[:9] - med) > MAX_STEP_S
                first = int(np.argmin(lead)) if not lead.all() else 0
                drops["time_glitch"] += first
                t, P = t[first:], P[first:]
            keep = np.fromiter((gate.take(float(v)) for v in t), dtype=bool, count=len(t))
            ts.append(t[keep])
            Ps.append(P[keep])
            if gate.jumped is not None:
                drops["after_clock_jump"] += sum(1 for _ in text)
                break
        gate.finish()
    if header is None:
        raise InputError(f"expected a header line in the reference CSV {str(path)!r}, got an "
                         f"empty file")
    t = np.concatenate(ts) if ts else np.empty(0)
    P = np.concatenate(Ps) if Ps else np.empty((0, 4, 4))
    if len(t) < 2:
        raise InputError(f"expected at least two usable rows in the reference CSV "
                         f"{str(path)!r}, got {len(t)} (dropped: {drops.to_dict() or 'none'})")
    return ReferenceTable(t, P, drops, gate.jumped)
