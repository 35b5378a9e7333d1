"""``openemt calibrate DATASET``: fit a calibration (one mode) starting from another calibration
(the workflow is :func:`openemt.calibrate.calibrate_dataset`)."""

from __future__ import annotations

import sys

__all__ = ["register", "run"]


def register(sub) -> None:
    from ..calibrate import CalibrateOptions
    from ._common import add_command

    add_command(
        sub, "calibrate", run, CalibrateOptions,
        description="Fit a calibration (MacLachlan et al. 2025, §VI) to DATASET, starting from "
                    "--from CAL, and score it on rows it did not fit. DATASET is an ILEMT "
                    "folder, a dataset file (.h5) or a CSV export.")


def run(args) -> int:
    from .._compile_notice import announce_compile
    from ..calibrate import CalibrateOptions, calibrate_dataset
    from ..simulate import nominal_calibration
    from ._common import emit, options_from, stage

    result = calibrate_dataset(
        options_from(CalibrateOptions, args), stage=lambda text: stage(args, text),
        compiling=lambda what, kernels: announce_compile(args, what, kernels=kernels),
        nominal=nominal_calibration)
    emit(args, result.to_dict(), result.lines())
    if not args.output and not args.quiet:
        print("note: the calibration was not written: no -o given (add -o CAL.json to keep it)",
              file=sys.stderr)
    return 0
