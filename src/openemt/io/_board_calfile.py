"""Finite-coil (board) calibrations: the ``kind = "finite"`` model block of an
``openemt.calibration`` file (docs/calibration-format.md#finite-coil-board-calibrations).

The model block embeds the board geometry (the board file's content, docs/planar.md#board-file)
with the fitted per-coil ``gains``, ``offsets`` (m) and ``tilts`` (rotation vectors, rad);
``standard_errors``, ``stats`` (fit status, residuals, per-coil residual in percent of the
coil's peak, held-out accuracy) and ``provenance`` are as for dipole calibrations.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import __version__
from .._atomic import atomic_path
from .._errors import InputError
from ._calibration import CALIBRATION_SCHEMA
from ._jsontext import free_to_json

__all__ = ["BoardCalibration", "board_calibration_from_dict", "board_calibration_to_dict",
           "is_board_calibration", "write_board_calibration"]

_UNITS = {"model.offsets": "m", "model.tilts": "rotation vector, rad",
          "model.gains": "measured coupling units per tesla of the 1 A coil field",
          "model.board": "SI (m, rad)", "stats": "SI unless the key says otherwise"}


@dataclass(frozen=True, eq=False)
class BoardCalibration:
    """A fitted board model (:class:`openemt.board.PlanarModel`) with its fit record."""

    model: object
    mode: str = "planar"
    standard_errors: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)
    provenance: dict = field(default_factory=dict)
    kind: str = "finite"

    def __getattr__(self, name):
        # only reached for attributes a BoardCalibration lacks: those of a dipole calibration
        from ..board._model import dipole_only

        raise dipole_only(name)

    @property
    def n_source(self) -> int:
        return self.model.n_coils

    @property
    def n_sensor(self) -> int:
        return 1

    def info(self) -> dict:
        """Summary for ``openemt info``."""
        m = self.model
        return {"kind": "calibration", "model_kind": "finite", "mode": self.mode,
                "board": m.board.name, "n_source": m.n_coils, "n_sensor": 1,
                "concentric": False, "linear_correction": False,
                "sensor_length_m": m.sensor_length, "gains": m.gains.tolist(),
                "offsets_mm": (m.offsets * 1e3).tolist(),
                "tilts_deg": np.degrees(m.tilts).tolist(),
                "standard_errors": sorted(self.standard_errors), "stats": self.stats}


def is_board_calibration(doc) -> bool:
    """True for the document of a finite-coil calibration (``model.kind == "finite"``)."""
    return (isinstance(doc, dict) and isinstance(doc.get("model"), dict)
            and doc["model"].get("kind") == "finite")


def _free(v):

    return free_to_json(v)


def board_calibration_to_dict(cal: BoardCalibration) -> dict:

    m = cal.model
    return {
        "schema": CALIBRATION_SCHEMA,
        "schema_version": 1,
        "written_by": f"openemt {__version__}",
        "units": _UNITS,
        "mode": cal.mode,
        "model": {"kind": "finite", "n_source": m.n_coils, "n_sensor": 1,
                  "board": m.board.to_dict(), "gains": m.gains.tolist(),
                  "offsets": m.offsets.tolist(), "tilts": m.tilts.tolist()},
        "standard_errors": _free(cal.standard_errors),
        "stats": _free(cal.stats),
        "provenance": _free(cal.provenance),
    }


def board_calibration_from_dict(doc: dict, source: str = "") -> BoardCalibration:
    """Validate and read the document of a finite-coil calibration."""
    from ..board import PlanarModel, board_from_dict

    w = f"{source}: " if source else ""
    if doc.get("schema") != CALIBRATION_SCHEMA:
        raise InputError(f"{w}expected schema {CALIBRATION_SCHEMA!r}, got {doc.get('schema')!r}")
    if doc.get("schema_version") != 1:
        raise InputError(f"{w}expected schema_version 1 for a finite-coil calibration, got "
                         f"{doc.get('schema_version')!r}")
    m = doc["model"]
    board = board_from_dict(m.get("board"), f"{source} model.board" if source else "model.board")
    n = board.n_coils
    arrays = {}
    for key, shape in (("gains", (n,)), ("offsets", (n, 3)), ("tilts", (n, 3))):
        try:
            a = np.asarray(m.get(key), dtype=np.float64)
        except (TypeError, ValueError):
            a = np.empty(0)
        if a.shape != shape or not np.all(np.isfinite(a)):
            raise InputError(f"{w}expected model.{key} of shape {shape} (finite numbers), got "
                             f"{json.dumps(m.get(key))[:60]}")
        arrays[key] = a
    model = PlanarModel(board, arrays["gains"], arrays["offsets"], arrays["tilts"])
    se = doc.get("standard_errors") or {}
    out = {}
    for k, v in se.items():
        out[k] = np.array([np.nan if x is None else x for x in np.ravel(v)],
                          dtype=np.float64).reshape(np.shape(v))
    for key in ("stats", "provenance"):
        if not isinstance(doc.get(key, {}), dict):
            raise InputError(f"{w}expected {key} to be an object, got {doc.get(key)!r}")
    return BoardCalibration(model, str(doc.get("mode", "planar")), out,
                            dict(doc.get("stats", {})), dict(doc.get("provenance", {})))


def write_board_calibration(cal: BoardCalibration, path) -> Path:
    """Write a finite-coil calibration file atomically."""
    path = Path(path)
    with atomic_path(path) as tmp:
        Path(tmp).write_text(json.dumps(board_calibration_to_dict(cal), indent=1) + "\n",
                             encoding="utf-8")
    return path
