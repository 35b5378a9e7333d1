"""Calibration files: schema-versioned JSON (``docs/calibration-format.md``).

Numbers are written with Python's shortest round-trip ``repr``, so float64 values read back
bit-for-bit. ``read_calibration`` also accepts ILEMT ``.mat`` calibrations.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .. import __version__
from .._atomic import atomic_path
from .._errors import InputError
from ..field import DipoleModel
from ._board_calfile import BOARD_UNITS, board_model_block, board_model_from_block
from ._calibration import (
    CALIBRATION_SCHEMA,
    Calibration,
    check_correction_matrix,
    check_model_moments,
)
from ._jsontext import free_to_json as _free_to_json
from ._jsontext import load_json_file

__all__ = [
    "CALIBRATION_SCHEMA",
    "CALIBRATION_SCHEMA_VERSION",
    "calibration_from_dict",
    "calibration_to_dict",
    "read_calibration",
    "write_calibration",
]

CALIBRATION_SCHEMA_VERSION = 1
#: most source or sensor coils of a dipole calibration (docs/robustness.md, "Bounded work")
MAX_CALIBRATION_COILS = 64

_UNITS_COMMON = {
    "fixtures": "pose vector [x, y, z, rx, ry, rz]: m and rotation vector in rad",
    "linear_correction": "homogeneous 4x4 acting on positions [x, y, z, 1] in m",
    "stats": "SI (m, rad) unless the key says otherwise",
}
_UNITS = {
    "model.L_so": "m", "model.L_se": "m",
    "model.M_so": "gain units (coil moment relative to model.gain)",
    "model.M_se": "gain units (coil moment relative to model.gain)",
    "model.gain": "coupling scale (ILEMT: 1/250)",
    **_UNITS_COMMON,
}


# -- encoding --------------------------------------------------------------------------------
def _arr_to_json(a) -> list | float | None:
    a = np.asarray(a, dtype=np.float64)
    return _free_to_json(a.tolist())




def _dipole_block(m) -> dict:
    return {
        "kind": "dipole",
        "n_source": m.n_source,
        "n_sensor": m.n_sensor,
        "gain": m.gain,
        "L_so": _arr_to_json(m.L_so),
        "M_so": _arr_to_json(m.M_so),
        "L_se": _arr_to_json(m.L_se),
        "M_se": _arr_to_json(m.M_se),
    }


def calibration_to_dict(cal: Calibration) -> dict:
    """The JSON document of a calibration (plain dicts/lists, see docs/calibration-format.md)."""
    if not isinstance(cal, Calibration):
        raise TypeError(f"expected a Calibration, got {type(cal).__name__}")
    kind = cal.model.kind
    if kind not in MODEL_CODECS:
        raise InputError(f"expected a calibration of a model kind in {sorted(MODEL_CODECS)}, "
                         f"got {kind!r}")
    return {
        "schema": CALIBRATION_SCHEMA,
        "schema_version": CALIBRATION_SCHEMA_VERSION,
        "written_by": f"openemt {__version__}",
        "units": dict(MODEL_CODECS[kind][2]),
        "mode": cal.mode,
        "model": MODEL_CODECS[kind][0](cal.model),
        "fixtures": {
            "source": _arr_to_json(cal.source_fixture),
            "stage": _arr_to_json(cal.stage_fixture),
            "sensor": _arr_to_json(cal.sensor_fixture),
        },
        "linear_correction": (None if cal.linear_correction is None
                              else _arr_to_json(cal.linear_correction)),
        "free": list(cal.free),
        "frozen": list(cal.frozen),
        "standard_errors": {k: _arr_to_json(v) for k, v in cal.standard_errors.items()},
        "stats": _free_to_json(dict(cal.stats)),
        "provenance": _free_to_json(dict(cal.provenance)),
        "extra": _free_to_json(dict(cal.extra)),
    }


# -- decoding --------------------------------------------------------------------------------
def _where(src: str) -> str:
    return f"calibration file {src}: " if src else "calibration: "


def _array(doc, key: str, shape, src: str, allow_nan: bool = False) -> np.ndarray:
    """Nested list -> float64 array of the given shape (None entries -> NaN if allowed)."""
    try:
        a = np.array(doc, dtype=np.float64) if allow_nan else np.array(doc)
    except (TypeError, ValueError):
        a = None
    if a is None or a.dtype == object or (a.dtype.kind not in "iuf" and not allow_nan):
        raise InputError(f"{_where(src)}expected `{key}` as a list of numbers of shape "
                         f"{_shape_text(shape)}, got {_describe(doc)}")
    a = a.astype(np.float64)
    if shape is not None and (len(shape) != a.ndim or any(
            s is not None and s != n for s, n in zip(shape, a.shape))):
        raise InputError(f"{_where(src)}expected `{key}` of shape {_shape_text(shape)}, "
                         f"got shape {a.shape}")
    if not allow_nan and not np.all(np.isfinite(a)):
        raise InputError(f"{_where(src)}expected finite numbers in `{key}`, got null/NaN")
    return a


def _shape_text(shape) -> str:
    if shape is None:
        return "(any)"
    return "(" + ", ".join("n" if s is None else str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"


def _describe(v) -> str:
    text = json.dumps(v) if not isinstance(v, str) else repr(v)
    return f"{type(v).__name__} {text[:40]}"


def _get(doc: dict, key: str, src: str, kinds, path: str | None = None):
    name = path or key
    if key not in doc:
        raise InputError(f"{_where(src)}expected field `{name}`, got no such field "
                         f"(fields: {sorted(doc)})")
    v = doc[key]
    if kinds is not None and not isinstance(v, kinds):
        want = " or ".join(k.__name__ if k is not type(None) else "null" for k in
                           (kinds if isinstance(kinds, tuple) else (kinds,)))
        raise InputError(f"{_where(src)}expected `{name}` to be {want}, got {_describe(v)}")
    return v


def calibration_from_dict(doc, source: str = "") -> Calibration:
    """Validate a calibration JSON document and build the :class:`Calibration`."""
    src = source
    if not isinstance(doc, dict):
        raise InputError(f"{_where(src)}expected a JSON object, got {_describe(doc)}")
    schema = doc.get("schema")
    if schema != CALIBRATION_SCHEMA:
        raise InputError(f"{_where(src)}expected schema {CALIBRATION_SCHEMA!r}, got {schema!r}")
    version = doc.get("schema_version")
    if not isinstance(version, int) or isinstance(version, bool) or not (
            1 <= version <= CALIBRATION_SCHEMA_VERSION):
        raise InputError(f"{_where(src)}expected schema_version 1..{CALIBRATION_SCHEMA_VERSION}, "
                         f"got {version!r}")
    model = _get(doc, "model", src, dict)
    kind = model.get("kind", "dipole")
    if not isinstance(kind, str) or kind not in MODEL_CODECS:
        raise InputError(f"{_where(src)}expected `model.kind` in {sorted(MODEL_CODECS)}, got "
                         f"{kind!r}")
    dm = MODEL_CODECS[kind][1](model, src)
    arrays = dm.split_params(dm.params)
    if kind != "dipole" and "fixtures" not in doc:
        doc = {**doc, "fixtures": {k: [0.0] * 6 for k in ("source", "stage", "sensor")}}
    fix = _get(doc, "fixtures", src, dict)
    fixtures = {f"{k}_fixture": _array(_get(fix, k, src, list, f"fixtures.{k}"), f"fixtures.{k}",
                                       (6,), src)
                for k in ("source", "stage", "sensor")}
    L = doc.get("linear_correction")
    if L is not None:
        L = check_correction_matrix(_array(L, "linear_correction", (4, 4), src),
                                    where=_where(src))
    se_doc = doc.get("standard_errors") or {}
    if not isinstance(se_doc, dict):
        raise InputError(f"{_where(src)}expected `standard_errors` to be an object, "
                         f"got {_describe(se_doc)}")
    std = {str(k): _array(v, f"standard_errors.{k}", None, src, allow_nan=True)
           for k, v in se_doc.items()}
    blocks = {**arrays, **{name: np.zeros(6) for name in (
        "source_fixture", "stage_fixture", "sensor_fixture", "F_so", "F_st", "F_se")}}
    for k, v in std.items():
        ref = blocks.get(k)
        if ref is None:
            raise InputError(f"{_where(src)}expected `standard_errors` blocks among "
                             f"{', '.join(blocks)}, got `{k}`")
        if v.shape != np.shape(ref):
            raise InputError(f"{_where(src)}expected `standard_errors.{k}` of shape "
                             f"{np.shape(ref)} (as {'model.' + k if k in arrays else 'a fixture'}"
                             f"), got shape {v.shape}")
        if np.any(v < 0):
            raise InputError(f"{_where(src)}expected standard errors >= 0 (or null) in "
                             f"`standard_errors.{k}`, got {v[v < 0].min():g}")
    for name in ("free", "frozen"):
        v = doc.get(name) or []
        if not isinstance(v, list) or not all(isinstance(x, str) for x in v):
            raise InputError(f"{_where(src)}expected `{name}` to be a list of strings, "
                             f"got {_describe(v)}")
    for name in ("stats", "provenance", "extra"):
        v = doc.get(name)
        if v is not None and not isinstance(v, dict):
            raise InputError(f"{_where(src)}expected `{name}` to be an object, got {_describe(v)}")
    mode = doc.get("mode") or ""
    if not isinstance(mode, str):
        raise InputError(
            f"{_where(src)}expected `mode` to be a string, got {_describe(mode)}")
    return Calibration(model=dm, linear_correction=L, mode=mode,
                       free=tuple(doc.get("free") or ()), frozen=tuple(doc.get("frozen") or ()),
                       standard_errors=std, stats=dict(doc.get("stats") or {}),
                       provenance=dict(doc.get("provenance") or {}),
                       extra=dict(doc.get("extra") or {}), **fixtures)


def _dipole_from_block(model: dict, src: str) -> DipoleModel:
    gain = _get(model, "gain", src, (int, float), "model.gain")
    arrays = {}
    for key, rows in (("L_so", 3), ("M_so", 3), ("L_se", 3), ("M_se", 3)):
        arrays[key] = _array(_get(model, key, src, list, f"model.{key}"), f"model.{key}",
                             (rows, None), src)
        if arrays[key].shape[1] > MAX_CALIBRATION_COILS:
            raise InputError(f"{_where(src)}expected `model.{key}` with at most "
                             f"{MAX_CALIBRATION_COILS} columns (coils), got "
                             f"{arrays[key].shape[1]}")
    for n_key, coil_key in (("n_source", "L_so"), ("n_sensor", "L_se")):
        if n_key in model and model[n_key] != arrays[coil_key].shape[1]:
            raise InputError(f"{_where(src)}expected `model.{n_key}` = {arrays[coil_key].shape[1]} "
                             f"(columns of model.{coil_key}), got {model[n_key]!r}")
    try:
        dm = DipoleModel(gain=float(gain), **arrays)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{_where(src)}{exc}") from None
    check_model_moments(dm, _where(src))
    return dm


def _octupole_block(m) -> dict:
    return {**_dipole_block(m.dipole), "kind": "octupole", "k_so": _arr_to_json(m.k_so),
            "k_se": _arr_to_json(m.k_se)}


def _octupole_from_block(model: dict, src: str):
    from ..field import OctupoleModel

    dm = _dipole_from_block(model, src)
    k = {key: _array(_get(model, key, src, list, f"model.{key}"), f"model.{key}", (n,), src)
         for key, n in (("k_so", dm.n_source), ("k_se", dm.n_sensor))}
    return OctupoleModel(dm, **k)


def _board_from_block(model: dict, src: str):
    try:
        return board_model_from_block(model, _where(src))
    except (TypeError, AttributeError) as exc:
        raise InputError(f"{_where(src)}expected a finite-coil model block, got {exc}") from None


#: The one registry of model blocks: ``model.kind`` -> (encode, decode, units). Every other
#: part of openemt works through the model interface (:class:`openemt.field.CouplingModel`).
MODEL_CODECS = {"dipole": (_dipole_block, _dipole_from_block, _UNITS),
                "octupole": (_octupole_block, _octupole_from_block,
                             {**_UNITS, "model.k_so": "m^2", "model.k_se": "m^2"}),
                "finite": (board_model_block, _board_from_block,
                           {**_UNITS_COMMON, **BOARD_UNITS})}


# -- files -------------------------------------------------------------------------------------
def _is_numeric_list(v) -> bool:
    return isinstance(v, list) and all(
        x is None or (isinstance(x, (int, float)) and not isinstance(x, bool))
        or _is_numeric_list(x) for x in v)


def _dumps(v, level: int = 0) -> str:
    """JSON with objects indented and numeric arrays kept on one line (matrices row by row)."""
    pad = "  " * (level + 1)
    if isinstance(v, dict):
        if not v:
            return "{}"
        items = [f"{pad}{json.dumps(k)}: {_dumps(x, level + 1)}" for k, x in v.items()]
        return "{\n" + ",\n".join(items) + "\n" + "  " * level + "}"
    if _is_numeric_list(v) and v and all(isinstance(x, list) for x in v):
        rows = [json.dumps(x, allow_nan=False) for x in v]
        return "[\n" + ",\n".join(pad + r for r in rows) + "\n" + "  " * level + "]"
    return json.dumps(v, allow_nan=False)


def write_calibration(cal: Calibration, path) -> Path:
    """Write a calibration as JSON (atomically). Returns the path written."""
    doc = calibration_to_dict(cal)
    text = _dumps(doc) + "\n"
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path


def read_calibration(path) -> Calibration:
    """Read a calibration: openemt JSON, or an ILEMT ``.mat`` file (by suffix).

    Raises ``FileNotFoundError`` for a missing file and ``ValueError`` with a one-line message
    naming the field, what was expected and what arrived for an invalid one.

    Examples
    --------
    >>> import pathlib, tempfile
    >>> import openemt
    >>> folder = openemt.datasets.path("cal_9_15_premo_cmu")
    >>> xyz = openemt.read_calibration(folder / "output" / "XYZ_hr_cal.mat")  # ILEMT .mat
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     path = openemt.write_calibration(xyz, pathlib.Path(tmp) / "xyz.json")
    ...     back = openemt.read_calibration(path)  # openemt JSON
    >>> back.mode, back.model.n_source, bool((back.model.M_so == xyz.model.M_so).all())
    ('XYZ', 3, True)
    """
    path = Path(path)
    if path.suffix.lower() == ".mat":
        from ._ilemt_mat import read_ilemt_calibration
        return read_ilemt_calibration(path)
    if not path.exists():
        raise FileNotFoundError(f"expected a calibration file (.json or ILEMT .mat), "
                                f"got missing file {str(path)!r}")
    doc = load_json_file(path, "an openemt calibration JSON file")
    return calibration_from_dict(doc, path.name)
