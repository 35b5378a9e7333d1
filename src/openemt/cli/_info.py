"""``openemt info FILE``: summarise any file openemt writes (:func:`openemt.report.describe`)."""

from __future__ import annotations

__all__ = ["register", "run"]


def register(sub) -> None:
    from ._common import add_command

    p = add_command(sub, "info", run,
                    description="Summarise any file openemt writes: datasets, poses, "
                                "calibrations, corrections, raw recordings, live logs, pose "
                                "(pair) CSV files and NDI exports.")
    p.add_argument("path", help="dataset or poses .h5, raw recording or track log (.h5/.csv), "
                                "calibration or correction .json, ILEMT calibration .mat, "
                                "pose or pairs .csv, NDI export .tsv")


def run(args) -> int:
    from ..report import describe
    from ._common import emit

    info = describe(args.path)
    emit(args, info.to_dict(), info.lines())
    return 0
