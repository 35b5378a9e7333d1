"""Board files (TOML or JSON): the geometry of a planar field generator's source coils and its
sensor (docs/planar.md#board-files). The model and its validation live in
:mod:`openemt.board`; this module reads and writes the files."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

from .._atomic import atomic_path
from .._errors import InputError
from ..board import Board, board_from_dict, builtin_board
from ..board._geometry import BUILTIN_BOARDS
from ._jsontext import loads_json
from ._safefile import MAX_CONFIG_BYTES, check_text_nesting, read_limited

__all__ = ["load_board", "read_board", "write_board"]


def read_board(path) -> Board:
    """Read a board file (``.toml`` or ``.json``)."""
    path = Path(path)
    data = read_limited(path, "a board file (.toml or .json)", MAX_CONFIG_BYTES)
    try:
        text = data.decode("utf-8")
        if path.suffix.lower() == ".json":
            doc = loads_json(text, "a JSON board file", path.name)
        else:
            check_text_nesting(text, "a TOML board file", path.name)
            doc = tomllib.loads(text)
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        msg = str(exc).splitlines()[0]
        raise InputError(f"{path.name}: expected a TOML or JSON board file, got {msg}") from None
    return board_from_dict(doc, path.name)


def load_board(board=None) -> Board:
    """A board: a :class:`~openemt.board.Board` as is, a built-in name (default ``anser``) or a
    file path."""
    if isinstance(board, Board):
        return board
    if board is None or str(board) in BUILTIN_BOARDS:
        return builtin_board(board)
    return read_board(board)


def _toml_value(v) -> str:
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    return repr(float(v))


def write_board(board: Board, path) -> Path:
    """Write a board file atomically: TOML, or JSON if ``path`` ends in ``.json``."""
    path = Path(path)
    d = board.to_dict()
    if path.suffix.lower() == ".json":
        text = json.dumps(d, indent=2) + "\n"
    else:
        lines = [f"name = {_toml_value(d['name'])}",
                 f"description = {_toml_value(d['description'])}", ""]
        for c in d["coils"]:
            lines.append("[[coils]]")
            lines += [f"{k} = {_toml_value(v)}" for k, v in c.items()]
            lines.append("")
        lines.append("[sensor]")
        lines += [f"{k} = {_toml_value(v)}" for k, v in d["sensor"].items()]
        text = "\n".join(lines) + "\n"
    with atomic_path(path) as tmp:
        Path(tmp).write_text(text, encoding="utf-8")
    return path
