"""``openemt simulate``: simulate the ILEMT-style calibration apparatus (stage patterns, manual
fixtures) with a finite-coil tracker preset and optional error sources, and write the dataset
as HDF5 (and its truth calibration)."""

from __future__ import annotations

from ._common import add_command, run_workflow


def register(sub) -> None:
    from ..simulate import SimulateOptions

    add_command(sub, "simulate", run, SimulateOptions)


def run(args) -> int:
    from ..simulate import SimulateOptions, write_simulation

    return run_workflow(args, write_simulation, SimulateOptions)
