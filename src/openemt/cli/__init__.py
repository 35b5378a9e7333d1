"""The ``openemt`` command: a thin layer that parses, calls the library and prints.

Each command lives in its own module exposing ``register(subparsers)``; the parser it adds
sets ``func(args) -> int``. Bad input raises ``ValueError``/``TypeError``/``OSError`` (or
``InputError``) inside the library; ``main`` turns that into one ``error:`` line and exit 2.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from .. import __version__

__all__ = ["build_parser", "main"]

#: Command modules, in the order they appear in ``openemt --help``.
COMMAND_MODULES = (
    "demo",
    "simulate",
    "import_",
    "info",
    "solve",
    "calibrate",
    "correct",
    "reproduce",
    "report",
    "track",
    "bench",
    "datasets",
)


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, exit 2 (argparse's own convention)
        self.print_usage(sys.stderr)
        print(f"error: {message}", file=sys.stderr)
        raise SystemExit(2)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="openemt",
                     description="Open software stack for electromagnetic trackers.")
    parser.add_argument("--version", action="version", version=f"openemt {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    for name in COMMAND_MODULES:
        importlib.import_module(f"openemt.cli._{name}").register(sub)
    return parser


def main(argv=None) -> int:
    """Run the CLI; returns the exit status (0 ok, 2 bad input, 1 other failure)."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130
    except (ValueError, TypeError, KeyError, OSError) as exc:
        msg = " ".join(str(exc).split()) or type(exc).__name__
        print(f"error: {msg}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
