"""The command layer starts without importing the numeric stack for --help and --version, and
configures only the command it runs."""

import subprocess
import sys

import pytest

from openemt.cli import COMMANDS, build_parser

_PROBE = """
import sys
from openemt.cli import main
try:
    main({argv!r})
except SystemExit:
    pass
heavy = sorted(m for m in ("numpy", "scipy", "numba", "h5py", "magpylib", "matplotlib", "dask")
               if m in sys.modules)
print("HEAVY=" + ",".join(heavy), file=sys.stderr)
"""


@pytest.mark.parametrize("argv", [["--version"], ["--help"], []])
def test_help_and_version_import_no_numeric_stack(argv):
    out = subprocess.run([sys.executable, "-c", _PROBE.format(argv=argv)], capture_output=True,
                         text=True, timeout=60, check=False)
    line = [s for s in out.stderr.splitlines() if s.startswith("HEAVY=")]
    assert line == ["HEAVY="], out.stderr


def test_every_command_registers_with_the_one_help_text():
    parser = build_parser()  # every command configured
    sub = next(a for a in parser._actions if a.dest == "command")
    assert list(sub.choices) == list(COMMANDS)
    listed = {a.dest: a.help for a in sub._choices_actions}
    assert listed == {name: help_ for name, (_, help_) in COMMANDS.items()}


def test_only_the_named_command_is_configured():
    parser = build_parser("info")
    sub = next(a for a in parser._actions if a.dest == "command")
    assert sub.choices["info"].get_default("func") is not None
    assert sub.choices["solve"].get_default("func") is None
