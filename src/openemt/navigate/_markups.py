"""3D Slicer markups point lists: ``.fcsv`` of every Slicer version and ``.mrk.json``.

``.fcsv`` is CSV after ``#`` header lines:

* Slicer 3 / 4.0-4.2 fiducial lists: ``# Fiducial List file ...``, ``# version = 2``,
  ``# columns = label,x,y,z,sel,vis``;
* Slicer 4.3 and later markups: ``# Markups fiducial file version = 4.4`` (4.6, 4.10, 4.11,
  5.x ...), ``# CoordinateSystem = 0`` (0: RAS, 1: LPS; 4.11 and later write ``RAS`` or
  ``LPS``), ``# columns = id,x,y,z,ow,ox,oy,oz,vis,sel,lock,label,desc,associatedNodeID``.

Without a ``# columns`` line the version's default columns are used. ``.mrk.json`` (Slicer 4.11
and later) holds ``markups``, each with ``coordinateSystem`` (default LPS), ``coordinateUnits``
(mm) and ``controlPoints`` with ``position`` and ``positionStatus``; points whose status is not
``defined`` are left out and counted. Every node's points are read, in file order.

Positions are returned in metres in RAS (LPS files have x and y negated), with the labels.
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._errors import InputError

__all__ = ["MAX_MARKUPS_BYTES", "MarkupPoints", "is_markups_path", "read_markups", "write_markups"]

#: Largest markups file read (bytes), checked before parsing.
MAX_MARKUPS_BYTES = 64 << 20

_DEFAULT_COLUMNS = {
    "fiducial-list": ["label", "x", "y", "z", "sel", "vis"],
    "markups": ["id", "x", "y", "z", "ow", "ox", "oy", "oz", "vis", "sel", "lock", "label",
                "desc", "associatednodeid"],
}
_SYSTEMS = {"0": "RAS", "1": "LPS", "ras": "RAS", "lps": "LPS"}
_UNITS = {"mm": 1e-3, "m": 1.0, "um": 1e-6}


@dataclass(frozen=True, eq=False)
class MarkupPoints:
    """Points read from a markups file.

    Attributes
    ----------
    points : ndarray, shape (N, 3)
        Positions in RAS (m).
    labels : ndarray of str, shape (N,)
    coordinate_system : str
        The file's system (``RAS`` or ``LPS``).
    version : str
        The file's format version (``fcsv 4.6``, ``fiducial-list 2``, ``mrk.json 1.0.3``, ...).
    n_undefined : int
        Control points left out because their position is not defined.
    """

    points: np.ndarray
    labels: np.ndarray
    coordinate_system: str
    version: str
    n_undefined: int = 0


def is_markups_path(path) -> bool:
    """True for ``.fcsv`` and ``.mrk.json`` (or ``.json``) files."""
    name = str(path).lower()
    return name.endswith((".fcsv", ".mrk.json"))


def _system(value: str, where: str) -> str:
    s = _SYSTEMS.get(str(value).strip().lower())
    if s is None:
        raise InputError(f"expected CoordinateSystem 0, 1, RAS or LPS in {where}, got {value!r}")
    return s


def _ras(points: np.ndarray, system: str) -> np.ndarray:
    return points * [-1.0, -1.0, 1.0] if system == "LPS" else points


def _read_fcsv(path: Path) -> MarkupPoints:
    from ..io._safefile import read_text

    text = read_text(path, "a markups .fcsv file", MAX_MARKUPS_BYTES)
    kind, version, system, columns = None, "", "RAS", None
    data_lines = []
    for k, line in enumerate(text.splitlines(), 1):
        s = line.strip()
        if not s:
            continue
        if s.startswith("#"):
            body = s.lstrip("#").strip()
            m = re.match(r"markups fiducial file version\s*=\s*(\S+)", body, re.I)
            if m:
                kind, version = "markups", m.group(1)
                continue
            if re.match(r"fiducial list file", body, re.I):
                kind = kind or "fiducial-list"
                continue
            key, eq, value = body.partition("=")
            key = key.strip().lower()
            if not eq:
                continue
            if key == "version" and kind == "fiducial-list":
                version = value.strip()
            elif key == "coordinatesystem":
                system = _system(value, str(path))
            elif key == "columns":
                columns = [c.strip().lower() for c in value.split(",")]
            continue
        data_lines.append((k, line))
    if kind is None and columns is None:
        raise InputError(f"expected a 3D Slicer markups file (a '# Markups fiducial file "
                         f"version' or '# Fiducial List file' header, or '# columns'), got "
                         f"none in {path}")
    columns = columns or _DEFAULT_COLUMNS[kind or "markups"]
    try:
        ix = [columns.index(a) for a in "xyz"]
    except ValueError:
        raise InputError(f"expected columns x, y, z in {path}, got {', '.join(columns)}") \
            from None
    il = columns.index("label") if "label" in columns else None
    pts, labels = [], []
    for (k, _), row in zip(data_lines, csv.reader([ln for _, ln in data_lines])):
        if len(row) <= max(ix):
            raise InputError(f"expected {len(columns)} fields on line {k} of {path}, got "
                             f"{len(row)}")
        try:
            p = [float(row[i]) for i in ix]
        except ValueError:
            raise InputError(f"expected numbers x, y, z on line {k} of {path}, got "
                             f"{', '.join(row[i] for i in ix)}") from None
        if not np.all(np.isfinite(p)):
            raise InputError(f"expected finite x, y, z on line {k} of {path}, got {p}")
        pts.append(p)
        labels.append(row[il].strip() if il is not None and il < len(row) else str(len(pts)))
    if not pts:
        raise InputError(f"expected at least one point in {path}, got none")
    v = f"{'fiducial-list' if kind == 'fiducial-list' else 'fcsv'} {version or '?'}"
    return MarkupPoints(points=_ras(1e-3 * np.array(pts), system), labels=np.array(labels),
                        coordinate_system=system, version=v)


def _read_mrk_json(path: Path) -> MarkupPoints:
    from ..io._jsontext import load_json_file

    doc = load_json_file(path, "a 3D Slicer .mrk.json markups file")
    if not isinstance(doc, dict) or not isinstance(doc.get("markups"), list):
        raise InputError(f"expected a JSON object with a 'markups' list in {path}, got "
                         f"{type(doc).__name__ if not isinstance(doc, dict) else 'no such list'}")
    schema = str(doc.get("@schema", ""))
    m = re.search(r"markups-schema-v([\d.]+?)\.json", schema)
    version = f"mrk.json {m.group(1) if m else '?'}"
    pts, labels, undefined, systems = [], [], 0, set()
    for j, node in enumerate(doc["markups"]):
        if not isinstance(node, dict) or not isinstance(node.get("controlPoints", []), list):
            raise InputError(f"expected markups[{j}] to be an object with a 'controlPoints' "
                             f"list in {path}, got {type(node).__name__}")
        system = _system(node.get("coordinateSystem", "LPS"), str(path))
        systems.add(system)
        unit = str(node.get("coordinateUnits", "mm")).lower()
        if unit not in _UNITS:
            raise InputError(f"expected coordinateUnits in {sorted(_UNITS)} in {path}, got "
                             f"{unit!r}")
        for i, cp in enumerate(node.get("controlPoints", [])):
            status = cp.get("positionStatus", "defined") if isinstance(cp, dict) else None
            if status != "defined":
                undefined += 1
                continue
            pos = cp.get("position")
            try:
                p = np.asarray(pos, dtype=np.float64)
            except (TypeError, ValueError):
                p = np.zeros(0)
            if p.shape != (3,) or not np.all(np.isfinite(p)):
                raise InputError(f"expected 3 finite numbers as markups[{j}].controlPoints[{i}]"
                                 f".position in {path}, got {pos!r}")
            pts.append(_ras(p * _UNITS[unit], system))
            labels.append(str(cp.get("label", len(pts))))
    if not pts:
        raise InputError(f"expected at least one defined control point in {path}, got none")
    return MarkupPoints(points=np.array(pts), labels=np.array(labels),
                        coordinate_system="/".join(sorted(systems)), version=version,
                        n_undefined=undefined)


def read_markups(path) -> MarkupPoints:
    """Read a 3D Slicer markups file (``.fcsv`` or ``.mrk.json``; see the module docstring)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"expected a markups file, got missing file {str(path)!r}")
    if str(path).lower().endswith(".fcsv"):
        return _read_fcsv(path)
    return _read_mrk_json(path)


def write_markups(path, points, labels) -> Path:
    """Write points (K, 3; m, RAS) with their labels as 3D Slicer markups: ``.fcsv`` (version
    4.11 columns) by that suffix, else ``.mrk.json`` (one fiducial node, RAS, mm)."""
    import json

    P = 1e3 * np.asarray(points, dtype=np.float64).reshape(-1, 3)
    labels = [str(v) for v in labels]
    if str(path).lower().endswith(".fcsv"):
        text = ("# Markups fiducial file version = 4.11\n# CoordinateSystem = RAS\n"
                "# columns = id,x,y,z,ow,ox,oy,oz,vis,sel,lock,label,desc,associatedNodeID\n"
                + "".join(f"{i + 1},{p[0]:.6f},{p[1]:.6f},{p[2]:.6f},0,0,0,1,1,1,0,{lab},,\n"
                          for i, (p, lab) in enumerate(zip(P, labels))))
    else:
        cps = [{"id": str(i + 1), "label": lab, "position": p.tolist(),
                "positionStatus": "defined"} for i, (p, lab) in enumerate(zip(P, labels))]
        text = json.dumps({"@schema": "https://raw.githubusercontent.com/slicer/slicer/master/"
                                      "Modules/Loadable/Markups/Resources/Schema/"
                                      "markups-schema-v1.0.3.json#",
                           "markups": [{"type": "Fiducial", "coordinateSystem": "RAS",
                                        "coordinateUnits": "mm", "controlPoints": cps}]},
                          indent=1) + "\n"
    _text(path, text)
    return Path(path)


def _text(path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (the navigation steps' text outputs)."""
    from .._atomic import atomic_path

    with atomic_path(path) as tmp:
        Path(tmp).write_text(text)
