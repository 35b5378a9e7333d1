"""Shared pieces of the command layer: JSON/human output, progress bars, error handling."""

from __future__ import annotations

import json
import sys
from collections.abc import Iterable

__all__ = ["add_actions", "add_command", "add_common", "add_options", "emit", "options_from", "progress",
           "run_workflow", "say", "stage", "workflow_command"]


def add_command(sub, name: str, func=None, options=None, only=None, **kwargs):
    """Add command (or sub-command) ``name`` to ``sub`` with its one-line help, the options of
    the dataclass ``options`` or of each of a tuple of them (:func:`add_options`; ``only``
    these fields), ``--json`` / ``--quiet`` and ``func``."""
    from . import COMMANDS

    kwargs.setdefault("help", COMMANDS[name][1] if name in COMMANDS else None)
    p = sub.add_parser(name, **kwargs)
    for cls in options if isinstance(options, tuple) else (options,):
        if cls is not None:
            add_options(p, cls, only=only)
    if func is not None:
        add_common(p)
        p.set_defaults(func=func)
    return p


class _Say:
    """What a workflow says while it runs (stage lines, the compile notice), on stderr."""

    def __init__(self, args):
        self.args = args

    def __call__(self, text: str) -> None:
        if text.strip():
            stage(self.args, text.rstrip("\n"))

    write, flush = __call__, lambda self: None  # a stream too, for the compile notice


def say(args):
    """The ``say`` callable a workflow reports its stages to: None with ``--quiet``."""
    return None if getattr(args, "quiet", False) else _Say(args)


def run_workflow(args, workflow, options_cls, **values) -> int:
    """Call ``workflow(options, say=...)`` with the options record built from ``args`` and print
    its result: ``to_dict()`` with ``--json``, its ``lines()`` on stderr. Returns the result's
    ``exit_status`` (default 0)."""
    result = workflow(options_from(options_cls, args, **values), say=say(args))
    emit(args, result.to_dict(), result.lines())
    return getattr(result, "exit_status", 0)


def workflow_command(name: str, package: str, options: str, workflow: str):
    """``register(sub)`` of a command that is one workflow of ``openemt.<package>``: the
    options record ``options`` as its options, :func:`run_workflow` of ``workflow`` as what it
    runs (both imported when the command is registered)."""
    def register(sub) -> None:
        import importlib

        mod = importlib.import_module(f"openemt.{package}")
        cls, run = getattr(mod, options), getattr(mod, workflow)
        add_command(sub, name, lambda args: run_workflow(args, run, cls), cls)

    return register


def add_actions(parser, actions, *, watch_compiles: bool = False) -> None:
    """Sub-commands ``ACTION`` of ``parser``, one per ``(name, help, options record,
    workflow)``: the record's fields as options; running one calls ``workflow(options)`` and
    prints its result (:func:`emit`) and, unless ``--quiet``, its ``warnings``. With
    ``watch_compiles`` a first run's numba compile is said on stderr when it starts
    (:func:`openemt._compile_notice.watch_compiles`)."""
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    for name, help_, options, workflow in actions:
        a = sub.add_parser(name, help=help_)
        add_options(a, options)
        add_common(a)
        a.set_defaults(func=lambda args, o=options, w=workflow: _run_action(
            args, o, w, watch_compiles))


def _run_action(args, options, workflow, watch: bool = False) -> int:
    import contextlib

    if watch:
        from .._compile_notice import watch_compiles

        context = watch_compiles(args, "kernels")
    else:
        context = contextlib.nullcontext()
    with context:
        result = workflow(options_from(options, args))
    emit(args, result.to_dict(), result.lines())
    if not getattr(args, "quiet", False):
        for w in getattr(result, "warnings", ()):
            print(f"warning: {w}", file=sys.stderr)
    return 0


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

    A field ``max_rms_mm`` becomes ``--max-rms-mm``; metadata ``help``, ``choices``,
    ``metavar``, ``required``, ``action`` and ``flag`` (other names) are passed on,
    ``positional`` (``optional``) makes a positional argument, ``cli=False`` leaves it out. A
    ``bool`` defaulting to True gets ``--no-...``. tests/test_cli_common.py shows it.
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
        if nargs and "action" not in meta:
            kw["nargs"] = nargs
        for key in ("choices", "metavar", "required", "action"):
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


def emit(args, summary: dict, human: Iterable[str] = ()) -> None:
    """Print the summary: JSON on stdout with ``--json``; human lines on stderr unless quiet."""
    if getattr(args, "json", False):
        from .._result import json_ready

        sys.stdout.write(json.dumps(json_ready(summary), indent=2) + "\n")
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
