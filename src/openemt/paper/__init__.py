"""Reproductions of the published tables on ILEMT folders and the characterizations behind the
report (the HTML document itself is built by :mod:`openemt.report`).

These orchestrate :mod:`openemt.calibrate`, :mod:`openemt.solve` and :mod:`openemt.evaluate`;
see docs/paper-reproductions.md. Each reproduction returns a result dataclass whose
``to_dict()`` is the JSON the ``openemt reproduce`` commands print.
"""

from ._characterization import (
    CalibrationCharacterization,
    PaperCharacterization,
    accuracy_row,
    characterize_calibration,
    characterize_paper_run,
)
from ._parameters import coil_name, parameter_rows
from ._reasons import explain_rows
from ._run import PaperRun, load_paper_run, sequence_steps
from ._simstudies import DipoleCost, ParameterRecovery, dipole_cost, parameter_recovery
from ._simulated import parameters_against_truth, truth_comparison_rows
from ._table2 import (
    TABLE2_PAPER,
    TABLE2_PAPER_COLUMNS,
    Table2Column,
    Table2Reproduction,
    identify_table2_column,
    reproduce_table2,
    table2_row,
    table2_tests,
)
from ._table3 import (
    TABLE3_COLUMNS,
    TABLE3_PAPER,
    TABLE3_ROWS,
    Table3Reproduction,
    reproduce_table3,
    table3_test_masks,
)
from ._table4 import (
    FIXTURE_MOMENT_M,
    TABLE4_PAPER,
    FixtureRefit,
    Table4Reproduction,
    Table4Result,
    refit_fixtures,
    reproduce_table4,
    sweep_test,
)
from ._workflow import TABLES, ReproduceOptions, Reproduction, improved_lines, reproduce

__all__ = [
    "TABLES",
    "ReproduceOptions",
    "Reproduction",
    "improved_lines",
    "reproduce",
    "DipoleCost",
    "ParameterRecovery",
    "dipole_cost",
    "parameter_recovery",
    "FIXTURE_MOMENT_M",
    "TABLE2_PAPER",
    "TABLE2_PAPER_COLUMNS",
    "TABLE3_COLUMNS",
    "TABLE3_PAPER",
    "TABLE3_ROWS",
    "TABLE4_PAPER",
    "CalibrationCharacterization",
    "FixtureRefit",
    "PaperCharacterization",
    "PaperRun",
    "Table2Column",
    "Table2Reproduction",
    "Table3Reproduction",
    "Table4Reproduction",
    "Table4Result",
    "accuracy_row",
    "characterize_calibration",
    "characterize_paper_run",
    "explain_rows",
    "identify_table2_column",
    "load_paper_run",
    "coil_name",
    "parameter_rows",
    "parameters_against_truth",
    "refit_fixtures",
    "reproduce_table2",
    "reproduce_table3",
    "reproduce_table4",
    "sequence_steps",
    "sweep_test",
    "table2_row",
    "table2_tests",
    "table3_test_masks",
    "truth_comparison_rows",
]
