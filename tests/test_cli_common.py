"""``add_options`` / ``options_from``: a command's options built from its workflow's options
dataclass (defaults and help written once, in the library)."""

import argparse
import dataclasses

import pytest

from openemt.cli._common import add_options, options_from


@dataclasses.dataclass(frozen=True)
class Opts:
    output: str = dataclasses.field(default=None, metadata={"flag": ("-o", "--output"),
                                                            "required": True, "help": "out"})
    max_rms_mm: float = dataclasses.field(default=2.0, metadata={"help": "limit"})
    robust: bool = False
    clip: bool = True
    spec: tuple[str, ...] | None = dataclasses.field(default=None,
                                                     metadata={"action": "append"})
    hidden: int = dataclasses.field(default=0, metadata={"cli": False})


def test_options_round_trip():
    p = argparse.ArgumentParser()
    add_options(p, Opts)
    got = options_from(Opts, p.parse_args(["-o", "x", "--max-rms-mm", "3", "--robust",
                                           "--no-clip", "--spec", "a", "--spec", "b"]),
                       hidden=4)
    assert got == Opts(output="x", max_rms_mm=3.0, robust=True, clip=False, spec=("a", "b"),
                       hidden=4)
    assert options_from(Opts, p.parse_args(["-o", "y"])) == Opts(output="y")
    with pytest.raises(SystemExit):
        p.parse_args(["--robust"])  # -o is required
    assert "--hidden" not in p.format_help() and "limit" in p.format_help()
