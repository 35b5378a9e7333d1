"""``openemt report``: one self-contained HTML report (tables and figures embedded) of an
ILEMT folder's paper reproduction, of a calibration on a test dataset, or of a finite-coil board
calibration on grid data (docs/paper-reproductions.md#openemt-report, docs/planar.md#reports).
"""

from __future__ import annotations

from ._common import add_command, run_workflow


def register(sub) -> None:
    from ..report import ReportOptions

    add_command(sub, "report", run, ReportOptions)


def run(args) -> int:
    from ..report import ReportOptions, write_report

    return run_workflow(args, write_report, ReportOptions)
