"""Shared test fixtures. Real-data tests read the bundled ILEMT folder through ``ilemt_dir``."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import settings

from openemt import datasets

# Property tests draw fresh random inputs on every local run. Under CI (the CI environment
# variable set, as .ci/run does) they draw a fixed, reproducible set per test instead, so a
# run can be repeated exactly; exploration continues in local runs.
settings.register_profile("ci", derandomize=True, database=None, print_blob=True)
if os.environ.get("CI"):
    settings.load_profile("ci")


@pytest.fixture(scope="session")
def ilemt_dir() -> Path:
    """The real ILEMT "concentric source" folder cal_9_15_premo_cmu (read-only)."""
    return datasets.path("cal_9_15_premo_cmu")


@pytest.fixture
def cli():
    """``openemt.cli.main``: ``cli([...])`` runs a command in this process and returns its
    exit code."""
    from openemt.cli import main

    return main


@pytest.fixture
def run_cli(capsys):
    """``run_cli(*argv) -> (code, stdout, stderr)``: a command run in this process, its
    arguments turned into strings."""
    from openemt.cli import main

    def run(*argv):
        code = main([str(a) for a in argv])
        out, err = capsys.readouterr()
        return code, out, err

    return run
