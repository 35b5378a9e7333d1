"""Reproductions of the published tables on ILEMT folders and the characterizations behind the
report (the HTML document itself is built by :mod:`openemt.report`).

These orchestrate :mod:`openemt.calibrate`, :mod:`openemt.solve` and :mod:`openemt.evaluate`;
see docs/paper-reproductions.md. Each reproduction returns a result dataclass whose
``to_dict()`` is the JSON the ``openemt reproduce`` commands print.
"""

from .._lazy import lazy_exports

#: where each public name lives; a module is imported on first use of one of its names
_SOURCES = {
    "._characterization": ("CalibrationCharacterization", "PaperCharacterization", "accuracy_row",
                           "characterize_calibration", "characterize_paper_run"),
    "._parameters": ("coil_name", "parameter_rows"),
    "._reasons": ("explain_rows",),
    "._run": ("PaperRun", "load_paper_run", "sequence_steps"),
    "._simstudies": ("DipoleCost", "ParameterRecovery", "dipole_cost", "parameter_recovery"),
    "._simulated": ("parameters_against_truth", "truth_comparison_rows"),
    "._table2": ("TABLE2_PAPER", "TABLE2_PAPER_COLUMNS", "Table2Column", "Table2Reproduction",
                 "identify_table2_column", "reproduce_table2", "table2_row", "table2_tests"),
    "._table3": ("TABLE3_COLUMNS", "TABLE3_PAPER", "TABLE3_ROWS", "Table3Reproduction",
                 "reproduce_table3", "table3_test_masks"),
    "._table4": ("FIXTURE_MOMENT_M", "TABLE4_PAPER", "FixtureRefit", "Table4Reproduction",
                 "Table4Result", "refit_fixtures", "reproduce_table4", "sweep_test"),
    "._workflow": ("TABLES", "ReproduceOptions", "Reproduction", "improved_lines", "reproduce"),
}
__all__, __getattr__, __dir__ = lazy_exports(__name__, _SOURCES)
