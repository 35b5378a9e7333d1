"""``openemt datasets``: list the data sets bundled with openemt, and verify their checksums."""

from __future__ import annotations

from ._common import add_command, run_workflow


def register(sub) -> None:
    from ..datasets import DatasetsOptions

    add_command(sub, "datasets", run, DatasetsOptions)


def run(args) -> int:
    from ..datasets import DatasetsOptions, check_datasets

    return run_workflow(args, check_datasets, DatasetsOptions)
