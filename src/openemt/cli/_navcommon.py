"""Pieces shared by the navigation commands (``pivot``, ``spin``, ``register``, ``assess``):
the unit options and the tool-calibration file they write."""

from __future__ import annotations

import json
from pathlib import Path

__all__ = ["add_units", "write_json"]


def add_units(p, *, angles: bool = True) -> None:
    """``--length-unit`` (and ``--angle-unit``) of CSV columns without a unit suffix."""
    p.add_argument("--length-unit", choices=("m", "mm"), default="m",
                   help="unit of CSV position columns without a _m/_mm suffix (default m)")
    if angles:
        p.add_argument("--angle-unit", choices=("rad", "deg"), default="rad",
                       help="unit of CSV rotation-vector columns without a _rad/_deg suffix")


def write_json(path, doc: dict) -> None:
    """Write a JSON document atomically (NaN written as null)."""
    from ..io import atomic_path
    from ._common import to_jsonable

    with atomic_path(path) as tmp:
        Path(tmp).write_text(json.dumps(to_jsonable(doc), indent=1) + "\n")
