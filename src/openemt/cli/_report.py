"""``openemt report``: one self-contained HTML report (tables and figures embedded) of an
ILEMT folder's paper reproduction, of a calibration on a test dataset, or of a finite-coil board
calibration on grid data (docs/paper-reproductions.md#openemt-report, docs/planar.md#reports).
"""

from ._common import workflow_command

register = workflow_command("report", "report", "ReportOptions", "write_report")
