"""The model block of a finite-coil board calibration (``model.kind = "finite"``,
docs/calibration-format.md#finite-coil-board-calibrations).

The block embeds the board geometry (the board file's content, docs/planar.md#board-file) with
the fitted per-coil ``gains``, ``offsets`` (m) and ``tilts`` (rotation vectors, rad) and the
sensor coils' relative ``sensor_gains`` (absent in files written before multi-coil sensors:
all 1). The rest of the file (fixtures, standard errors, stats, provenance) is every
calibration's (:mod:`openemt.io._calfile`).
"""

from __future__ import annotations

import json

import numpy as np

from .._errors import InputError

__all__ = ["BOARD_UNITS", "board_model_block", "board_model_from_block"]

BOARD_UNITS = {"model.offsets": "m", "model.tilts": "rotation vector, rad",
               "model.gains": "measured coupling units per tesla of the 1 A coil field",
               "model.sensor_gains": "relative gain of each sensor coil (the first is 1)",
               "model.board": "SI (m, rad)"}


def board_model_block(m) -> dict:
    """The JSON model block of a :class:`openemt.board.BoardModel`."""
    return {"kind": "finite", "n_source": m.n_source, "n_sensor": m.n_sensor,
            "board": m.board.to_dict(), "gains": m.gains.tolist(),
            "offsets": m.offsets.tolist(), "tilts": m.tilts.tolist(),
            "sensor_gains": m.sensor_gains.tolist()}


def board_model_from_block(m: dict, where: str = ""):
    """Validate a finite-coil model block and build the :class:`openemt.board.BoardModel`
    (``where`` prefixes error messages)."""
    from ..board import BoardModel, board_from_dict

    board = board_from_dict(m.get("board"), f"{where}model.board")
    n, ne = board.n_coils, board.sensor.n_coils
    arrays = {}
    for key, shape in (("gains", (n,)), ("offsets", (n, 3)), ("tilts", (n, 3)),
                       ("sensor_gains", (ne,))):
        v = m.get(key, [1.0] * ne if key == "sensor_gains" else None)
        try:
            a = np.asarray(v, dtype=np.float64)
        except (TypeError, ValueError):
            a = np.empty(0)
        if a.shape != shape or not np.all(np.isfinite(a)):
            raise InputError(f"{where}expected model.{key} of shape {shape} (finite numbers), "
                             f"got {json.dumps(v)[:60]}")
        arrays[key] = a
    from ._calibration import COUPLING_SCALE_RANGE, MAX_COIL_POSITION_M

    lo, hi = COUPLING_SCALE_RANGE       # as a dipole model's coupling scale
    g = np.abs(np.concatenate([arrays["gains"], arrays["sensor_gains"]]))
    if not (np.all(g >= lo) and np.all(g <= hi)):
        raise InputError(f"{where}expected |model.gains| and |model.sensor_gains| within "
                         f"[{lo:g}, {hi:g}], got {g.min():.3g} .. {g.max():.3g}")
    if np.abs(arrays["offsets"]).max(initial=0.0) > MAX_COIL_POSITION_M:
        raise InputError(f"{where}expected coil `model.offsets` within "
                         f"{MAX_COIL_POSITION_M:g} m, got "
                         f"{np.abs(arrays['offsets']).max():.3g} m")
    for key, want in (("n_source", n), ("n_sensor", ne)):
        if key in m and m[key] != want:
            raise InputError(f"{where}expected model.{key} = {want} (from model.board), got "
                             f"{m[key]!r}")
    return BoardModel(board, **arrays)
