"""``openemt simulate``: simulate the ILEMT-style calibration apparatus (stage patterns, manual
fixtures) with a finite-coil tracker preset and optional error sources, and write the dataset
as HDF5 (and its truth calibration); or, with ``--motion``, a tracked tool with a tip performing
a pivot, spin, fiducial-touch or grid-visit motion, written as a track log with its truth."""

from __future__ import annotations

from ._common import add_command, add_options, emit, options_from, run_workflow


def register(sub) -> None:
    from ..navigate import MotionOptions
    from ..simulate import SimulateOptions

    add_options(add_command(sub, "simulate", run, SimulateOptions), MotionOptions)


def run(args) -> int:
    from ..navigate import MotionOptions, simulate_tool_session
    from ..simulate import SimulateOptions, write_simulation

    if args.motion:                                    # a tracked tool's motion
        run_ = simulate_tool_session(options_from(MotionOptions, args, output=str(args.output)))
        emit(args, run_.to_dict(), run_.lines)
        return 0
    return run_workflow(args, write_simulation, SimulateOptions)
