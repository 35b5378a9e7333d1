"""Calibration of coupling models and rig fixtures: layout, objective, staged fits, uncertainty.

The entry point is :func:`fit` (also ``openemt.fit_calibration``): it fits a
:class:`~openemt.io.Calibration` (dipole model and the rig's fixture transforms) to a
:class:`~openemt.io.Dataset`, starting from another calibration, and returns a
:class:`CalibrationFit` whose ``calibration`` is the result. :func:`run_sequence` runs the
paper's staged sequence of such fits; :func:`improved_calibration` the improved rig model.
"""

from .._lazy import lazy_exports

#: where each public name lives; a module is imported on first use of one of its names
_SOURCES = {
    "..io": ("Calibration", "Dataset"),
    "._check": ("HeldOutTest", "held_out_rows", "solve_held_out"),
    "._environment": ("PLANAR_CANDIDATES", "BoardEnvironmentFit", "EnvironmentChoice",
                      "EnvironmentFit", "WitnessEstimator", "fit_board_environment",
                      "fit_environment", "known_pose_errors", "parse_environment"),
    "._fit": ("CalibrationFit", "ResidueStats", "fit", "residue_stats"),
    "._heldout": ("CANDIDATES", "IMPROVED_OPTIONS", "TERM_MAX_CONDITION", "TERM_MIN_GAIN", "TERMS",
                  "CrossValidation", "ImprovedCalibration", "ImprovedTest", "TermDecision",
                  "cross_validate", "improved_calibration", "repeat_pairs", "select_terms"),
    "._identifiability": ("Identifiability", "IdentifiabilityWarning", "analyse_identifiability"),
    "._improved": ("STAGE_LINEAR_BASIS", "ImprovedFit", "ImprovedProblem", "RigModel",
                   "RigOptions", "carry_parameters", "fit_improved"),
    "._layout": ("FIELD_NAMES", "ParameterLayout"),
    "._modes": ("DEFAULT_FREEZE", "DEFAULT_OPTIMIZE", "MODES", "CalibrationMode", "get_mode",
                "select_rows"),
    "._objective": ("CalibrationProblem", "build_problem", "fixture_twist_map"),
    "._perturb": ("perturb_calibration",),
    "._planar": ("GridData", "PlanarFit", "fit_planar", "read_grid_csv", "write_grid_csv"),
    "._reference": ("EIV_NOISE_FLOOR", "MIN_REFERENCE_POSES", "WEIGHTINGS", "XY_CONDITION_LIMIT",
                    "ReferenceFit", "errors_in_variables_whitening", "fit_reference",
                    "reference_block", "reference_errors", "reference_noise_covariance",
                    "reference_poses", "reference_residuals", "score_reference", "stage_reference"),
    "._sequence": ("PAPER_SEQUENCE", "OutputCorrection", "SequenceStep", "fit_output_correction",
                   "run_sequence"),
    "._split": ("HOLDOUT_SCHEMES", "checkerboard_split", "holdout_split", "location_split"),
    "._workflow": ("CalibrateOptions", "CalibrateResult", "calibrate_dataset", "load_dataset"),
}
__all__, __getattr__, __dir__ = lazy_exports(__name__, _SOURCES)
