"""``openemt report``: one self-contained HTML report (tables and figures embedded) of a
calibration and characterization run.

* ``openemt report ILEMT_DIR -o report.html``: import the folder, run the paper's calibration
  sequence once, reproduce MacLachlan et al. 2025, Tables II-IV with figures and the main
  calibration's parameters;
* ``openemt report TEST.h5 --calibration CAL.json -o report.html`` (or ``--dataset TEST.h5``):
  characterise a calibration on a test dataset against the rig kinematics (``--reference
  kinematics``, the default) or the dataset's reference poses (``--reference poses``):
  accuracy, per-fixture errors, error-vector and sweep plots, parameters with standard errors;
* ``openemt report GRID --calibration BOARD_CAL.json [--holdout checkerboard] -o report.html``
  with a finite-coil (board) calibration: grid data with known positions and axes solved with
  the 5-DOF solver, scored as the planar calibration scores it (docs/planar.md#reports).
"""

from __future__ import annotations

from ._common import add_command, run_workflow


def register(sub) -> None:
    from ..report import ReportOptions

    add_command(sub, "report", run, ReportOptions)


def run(args) -> int:
    from ..report import ReportOptions, write_report

    return run_workflow(args, write_report, ReportOptions)
