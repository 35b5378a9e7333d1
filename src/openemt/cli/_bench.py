"""``openemt bench NAME``: benchmarks that print JSON (speed and accuracy targets live here).

Each benchmark is a module of :mod:`openemt.bench` (listed in its ``BENCHMARKS``) with
``add_arguments(parser)`` and ``run(args) -> dict``; the dict is the JSON summary.
"""

from __future__ import annotations

import importlib
import json

from .._result import json_ready
from ._common import add_command, emit


def register(sub) -> None:
    bsub = add_command(sub, "bench").add_subparsers(dest="bench", metavar="NAME")
    bsub.required = True
    # reached by name: bench is the layer above the command line
    for name, help_ in importlib.import_module("openemt.bench").BENCHMARKS.items():
        mod = importlib.import_module(f"openemt.bench._{name}")
        mod.add_arguments(add_command(bsub, name, _runner(mod), help=help_))


def _runner(mod):
    def run(args) -> int:
        summary = mod.run(args)
        # without --json the same summary goes to stderr, readable
        emit(args, summary, json.dumps(json_ready(summary), indent=2).splitlines())
        return 0

    return run
