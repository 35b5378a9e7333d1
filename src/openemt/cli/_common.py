"""Shared pieces of the command layer: JSON/human output, progress bars, error handling."""

from __future__ import annotations

import json
import sys
from collections.abc import Iterable
from typing import Any

import numpy as np

__all__ = ["add_common", "emit", "progress", "stage", "to_jsonable", "write_solved"]


def add_common(parser) -> None:
    """Add the flags every command has (``--json``, ``--quiet``)."""
    parser.add_argument("--json", action="store_true",
                        help="print a machine-readable JSON summary on stdout")
    parser.add_argument("--quiet", action="store_true",
                        help="no progress bars or human-readable summary on stderr")


def to_jsonable(obj: Any) -> Any:
    """Convert numpy scalars/arrays and paths inside ``obj`` to plain JSON types."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    if hasattr(obj, "__fspath__"):
        return str(obj)
    return obj


def emit(args, summary: dict, human: Iterable[str] = ()) -> None:
    """Print the summary: JSON on stdout with ``--json``; human lines on stderr unless quiet."""
    if getattr(args, "json", False):
        sys.stdout.write(json.dumps(to_jsonable(summary), indent=2) + "\n")
        sys.stdout.flush()
    if not getattr(args, "quiet", False):
        for line in human:
            print(line, file=sys.stderr)


def stage(args, text: str) -> None:
    """Say on stderr what the command does next, before it does it (not with ``--quiet``).

    A plain line, so it also shows when stderr is not a terminal (where :func:`progress`
    draws no bar); written through tqdm so an open bar is redrawn below it.
    """
    if getattr(args, "quiet", False):
        return
    from tqdm.auto import tqdm

    tqdm.write(text, file=sys.stderr)
    sys.stderr.flush()


def progress(iterable=None, *, total=None, desc: str = "", args=None, unit: str = "it"):
    """A tqdm progress bar on stderr (disabled by ``--quiet`` or when stderr is not a TTY)."""
    from tqdm.auto import tqdm

    disable = bool(getattr(args, "quiet", False)) or not sys.stderr.isatty()
    return tqdm(iterable, total=total, desc=desc, file=sys.stderr, disable=disable, unit=unit,
                leave=False)


def write_solved(args, n: int, solver: str, meta: dict, chunks):
    """Write the ``(start, SolveResult)`` blocks of ``chunks`` to the poses file ``args.output``
    (atomically, with a progress bar); returns the :class:`~openemt.solve._output.PoseWriter`,
    whose status counts outlive the file. Used by ``solve`` for every kind of calibration."""
    from ..io import atomic_h5
    from ..solve._output import PoseWriter

    with atomic_h5(args.output) as f:
        writer = PoseWriter(f, n, solver, meta)
        with progress(total=n, desc="solve", args=args, unit="pose") as bar:
            for start, res in chunks:
                writer.write(start, res)
                bar.update(len(res))
    return writer
