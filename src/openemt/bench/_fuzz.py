"""``openemt bench fuzz``: the long fuzz run of every reader, the CLI and every solver.

The harness is test infrastructure and lives beside the tests (``tests/openemt_fuzz`` of a
source checkout), not in the installed package; this entry point finds it there. From an
installed copy without the source tree the command says so in one line.
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

from .._errors import InputError

__all__ = ["add_arguments", "run"]


def _harness():
    """The harness package of the source checkout this copy runs from, or None."""
    tests = Path(__file__).resolve().parents[3] / "tests"
    if not (tests / "openemt_fuzz" / "__init__.py").is_file():
        return None
    if str(tests) not in sys.path:
        sys.path.insert(0, str(tests))
    return importlib.import_module("openemt_fuzz")


def add_arguments(parser) -> None:
    harness = _harness()
    if harness is not None:
        harness.add_arguments(parser)


def run(args) -> dict:
    harness = _harness()
    if harness is None:
        raise InputError("expected the fuzz harness of a source checkout (tests/openemt_fuzz "
                         "beside src/), got an installed copy without it: run "
                         "`openemt bench fuzz` from a clone of the repository")
    return harness.run(args)
