"""JSON documents from files, read defensively: UTF-8 checked, nesting bounded, errors one line.

Python's ``json`` parser recurses once per nesting level, so a file of ten thousand ``[`` ends
in ``RecursionError``; openemt's documents are a few levels deep, and anything deeper than
:data:`MAX_JSON_DEPTH` is refused before parsing.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from .._errors import InputError
from ._safefile import MAX_JSON_BYTES, read_text

__all__ = ["MAX_JSON_DEPTH", "MAX_JSON_ITEMS", "free_to_json", "json_depth", "load_json_file",
           "loads_json"]

#: deepest nesting of arrays/objects accepted in a JSON document (openemt writes at most ~5)
MAX_JSON_DEPTH = 64
#: most values in a JSON document, counted by its separators before parsing (a thin-plate-spline
#: correction of 100,000 pairs holds ~600,000 numbers)
MAX_JSON_ITEMS = 2_000_000


def json_depth(text: str) -> int:
    """Deepest nesting of ``[``/``{`` in JSON text, ignoring brackets inside strings."""
    depth = deepest = 0
    in_string = escaped = False
    for ch in text:
        if in_string:
            if escaped:
                escaped = False
            elif ch == "\\":
                escaped = True
            elif ch == '"':
                in_string = False
        elif ch == '"':
            in_string = True
        elif ch in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif ch in "]}":
            depth -= 1
    return deepest


def loads_json(text: str, what: str, where: str):
    """Parse JSON ``text`` (a ``what`` from ``where``); one-line :class:`InputError` otherwise.

    Nesting deeper than :data:`MAX_JSON_DEPTH` and more than :data:`MAX_JSON_ITEMS` values
    (counted by the ``,`` separators, strings included, so the count is an upper bound) are
    refused before parsing."""
    n_items = text.count(",") + 1
    if n_items > MAX_JSON_ITEMS:
        raise InputError(f"expected {what} of at most {MAX_JSON_ITEMS} values, got up to "
                         f"{n_items} in {where}")
    if text.count("[") + text.count("{") > MAX_JSON_DEPTH:
        depth = json_depth(text)
        if depth > MAX_JSON_DEPTH:
            raise InputError(f"expected {what} nested at most {MAX_JSON_DEPTH} levels deep, got "
                             f"{depth} levels in {where}")
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"expected {what}, got invalid JSON in {where} (line {exc.lineno}: "
                         f"{exc.msg})") from None


def load_json_file(path, what: str, max_bytes: int = MAX_JSON_BYTES):
    """Read and parse a JSON file (a regular file of at most ``max_bytes``,
    :func:`~openemt.io._safefile.read_text`); the errors name the file and say what was
    expected."""
    return loads_json(read_text(path, what, max_bytes), what, Path(path).name)


def free_to_json(v):
    """Free-form values (stats, provenance, extra) -> JSON types; non-finite floats -> null."""
    if isinstance(v, dict):
        return {str(k): free_to_json(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [free_to_json(x) for x in v]
    if isinstance(v, np.ndarray):
        if v.dtype.kind == "c":
            return {"real": free_to_json(v.real.tolist()), "imag": free_to_json(v.imag.tolist())}
        return free_to_json(v.tolist())
    if isinstance(v, np.generic):
        return free_to_json(v.item())
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, (bool, int, str)) or v is None:
        return v
    if hasattr(v, "__fspath__"):
        return str(v)
    raise TypeError(f"expected JSON-serialisable calibration metadata, got {type(v).__name__}")
