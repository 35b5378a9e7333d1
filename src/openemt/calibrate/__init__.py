"""Calibration of coupling models and rig fixtures: layout, objective, staged fits, uncertainty.

The entry point is :func:`fit` (also ``openemt.fit_calibration``): it fits a
:class:`~openemt.io.Calibration` (dipole model and the rig's fixture transforms) to a
:class:`~openemt.io.Dataset`, starting from another calibration, and returns a
:class:`CalibrationFit` whose ``calibration`` is the result. :func:`run_sequence` runs the
paper's staged sequence of such fits; :func:`improved_calibration` the improved rig model.
"""

from ..io import Calibration, Dataset
from ._check import HeldOutTest, held_out_rows, solve_held_out
from ._environment import (
    PLANAR_CANDIDATES,
    BoardEnvironmentFit,
    EnvironmentChoice,
    EnvironmentFit,
    WitnessEstimator,
    fit_board_environment,
    fit_environment,
    known_pose_errors,
    parse_environment,
)
from ._fit import CalibrationFit, ResidueStats, fit, residue_stats
from ._heldout import (
    CANDIDATES,
    IMPROVED_OPTIONS,
    TERM_MAX_CONDITION,
    TERM_MIN_GAIN,
    TERMS,
    CrossValidation,
    ImprovedCalibration,
    ImprovedTest,
    TermDecision,
    cross_validate,
    improved_calibration,
    repeat_pairs,
    select_terms,
)
from ._identifiability import Identifiability, IdentifiabilityWarning, analyse_identifiability
from ._improved import (
    STAGE_LINEAR_BASIS,
    ImprovedFit,
    ImprovedProblem,
    RigModel,
    RigOptions,
    carry_parameters,
    fit_improved,
)
from ._layout import FIELD_NAMES, ParameterLayout
from ._modes import DEFAULT_FREEZE, DEFAULT_OPTIMIZE, MODES, CalibrationMode, get_mode, select_rows
from ._objective import CalibrationProblem, build_problem, fixture_twist_map
from ._perturb import perturb_calibration
from ._planar import (
    GridData,
    PlanarFit,
    fit_planar,
    read_grid_csv,
    write_grid_csv,
)
from ._reference import (
    EIV_NOISE_FLOOR,
    MIN_REFERENCE_POSES,
    WEIGHTINGS,
    XY_CONDITION_LIMIT,
    ReferenceFit,
    errors_in_variables_whitening,
    fit_reference,
    reference_block,
    reference_errors,
    reference_noise_covariance,
    reference_poses,
    reference_residuals,
    score_reference,
    stage_reference,
)
from ._sequence import (
    PAPER_SEQUENCE,
    OutputCorrection,
    SequenceStep,
    fit_output_correction,
    run_sequence,
)
from ._split import HOLDOUT_SCHEMES, checkerboard_split, holdout_split, location_split
from ._workflow import CalibrateOptions, CalibrateResult, calibrate_dataset, load_dataset

__all__ = [
    "ImprovedFit",
    "CalibrateOptions",
    "CalibrateResult",
    "calibrate_dataset",
    "load_dataset",
    "CANDIDATES",
    "BoardEnvironmentFit",
    "EnvironmentChoice",
    "EnvironmentFit",
    "PLANAR_CANDIDATES",
    "fit_board_environment",
    "known_pose_errors",
    "Calibration",
    "CalibrationFit",
    "CalibrationMode",
    "CalibrationProblem",
    "CrossValidation",
    "DEFAULT_FREEZE",
    "DEFAULT_OPTIMIZE",
    "EIV_NOISE_FLOOR",
    "Dataset",
    "FIELD_NAMES",
    "GridData",
    "HOLDOUT_SCHEMES",
    "HeldOutTest",
    "IMPROVED_OPTIONS",
    "Identifiability",
    "IdentifiabilityWarning",
    "ImprovedCalibration",
    "ImprovedProblem",
    "ImprovedTest",
    "MIN_REFERENCE_POSES",
    "MODES",
    "OutputCorrection",
    "PAPER_SEQUENCE",
    "ParameterLayout",
    "ReferenceFit",
    "ResidueStats",
    "RigModel",
    "RigOptions",
    "STAGE_LINEAR_BASIS",
    "SequenceStep",
    "TERMS",
    "TERM_MAX_CONDITION",
    "TERM_MIN_GAIN",
    "TermDecision",
    "WitnessEstimator",
    "WEIGHTINGS",
    "XY_CONDITION_LIMIT",
    "analyse_identifiability",
    "build_problem",
    "carry_parameters",
    "checkerboard_split",
    "cross_validate",
    "errors_in_variables_whitening",
    "fit",
    "fit_environment",
    "fit_improved",
    "fit_output_correction",
    "fit_reference",
    "fixture_twist_map",
    "get_mode",
    "held_out_rows",
    "holdout_split",
    "improved_calibration",
    "location_split",
    "parse_environment",
    "perturb_calibration",
    "read_grid_csv",
    "reference_block",
    "reference_errors",
    "reference_noise_covariance",
    "reference_poses",
    "reference_residuals",
    "repeat_pairs",
    "residue_stats",
    "run_sequence",
    "score_reference",
    "select_rows",
    "select_terms",
    "solve_held_out",
    "stage_reference",
    "write_grid_csv",
]
__all__ += ["PlanarFit", "fit_planar"]  # the board fit (docs/planar.md)
