"""Shared pieces of the command layer: JSON/human output, progress bars, error handling."""

from __future__ import annotations

import json
import sys
from collections.abc import Iterable
from typing import Any

import numpy as np

__all__ = ["add_common", "add_options", "emit", "options_from", "progress", "stage", "to_jsonable",
           "write_solved"]


def add_common(parser) -> None:
    """Add the flags every command has (``--json``, ``--quiet``)."""
    parser.add_argument("--json", action="store_true",
                        help="print a machine-readable JSON summary on stdout")
    parser.add_argument("--quiet", action="store_true",
                        help="no progress bars or human-readable summary on stderr")


def _option_type(hint):
    """(type, nargs) of a field's annotation: ``X | None`` is X, ``tuple[X, ...]`` is nargs."""
    import types
    import typing

    args = [a for a in typing.get_args(hint) if a is not type(None)]
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType) and len(args) == 1:
        return _option_type(args[0])
    if origin in (tuple, list):
        return (args[0] if args else str), "+"
    return hint, None


def add_options(parser, options_cls, *, only=None, skip=(), **help_overrides) -> None:
    """Add one command-line option per field of the dataclass ``options_cls`` (a workflow's
    options record), so that the defaults and help texts are written once, in the library.

    A field ``max_rms_mm`` becomes ``--max-rms-mm``; its help is ``metadata["help"]`` (or a
    keyword of the same name here), ``metadata["choices"]``, ``["metavar"]`` and ``["flag"]``
    (another option name, or a tuple of names such as ``("-o", "--output")``) are passed on, ``metadata["positional"]`` makes it a positional
    argument, and ``metadata["cli"] = False`` leaves it out. A ``bool`` field defaulting to
    False is a switch; one defaulting to True gets ``--no-...``. The default shown is the
    field's. ``only`` / ``skip`` pick fields by name. :func:`options_from` builds the record.

    Examples
    --------
    >>> import argparse, dataclasses
    >>> @dataclasses.dataclass(frozen=True)
    ... class Opts:
    ...     max_rms_mm: float = dataclasses.field(default=2.0, metadata={"help": "limit"})
    ...     robust: bool = False
    >>> p = argparse.ArgumentParser()
    >>> add_options(p, Opts)
    >>> options_from(Opts, p.parse_args(["--max-rms-mm", "3", "--robust"]))
    Opts(max_rms_mm=3.0, robust=True)
    """
    import dataclasses
    import typing

    hints = typing.get_type_hints(options_cls)
    for f in dataclasses.fields(options_cls):
        meta = f.metadata
        if (only is not None and f.name not in only) or f.name in skip or \
                meta.get("cli", True) is False or not f.init:
            continue
        default = f.default if f.default is not dataclasses.MISSING else (
            f.default_factory() if f.default_factory is not dataclasses.MISSING else None)
        kind, nargs = _option_type(hints[f.name])
        kw = {"help": help_overrides.get(f.name, meta.get("help", "")), "dest": f.name}
        flags = meta.get("flag", "--" + f.name.replace("_", "-"))
        flags = (flags,) if isinstance(flags, str) else tuple(flags)
        if kind is bool:
            if default:
                kw["help"] = kw["help"] or f"(default on; --no-{f.name.replace('_', '-')})"
                parser.add_argument(*("--no-" + g[2:] for g in flags), action="store_false",
                                    **kw)
            else:
                parser.add_argument(*flags, action="store_true", **kw)
            continue
        kw.update(type=kind if callable(kind) and kind is not typing.Any else None)
        if kw["type"] is None:
            del kw["type"]
        if nargs:
            kw["nargs"] = nargs
        for key in ("choices", "metavar"):
            if key in meta:
                kw[key] = meta[key]
        if meta.get("positional"):
            del kw["dest"]
            if default is not None or meta.get("optional"):
                kw["nargs"] = kw.get("nargs") and "*" or "?"
            parser.add_argument(f.name, default=default, **kw)
        else:
            parser.add_argument(*flags, default=default, **kw)


def options_from(options_cls, args, **values):
    """The options record ``options_cls`` from the parsed ``args`` (fields that the parser
    has), with ``values`` given explicitly taking precedence."""
    import dataclasses

    given = {f.name: getattr(args, f.name) for f in dataclasses.fields(options_cls)
             if f.init and hasattr(args, f.name)}
    for name, v in given.items():
        if isinstance(v, list):
            given[name] = tuple(v)
    return options_cls(**{**given, **values})


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
