"""Calibration of coupling models and rig fixtures: layout, objective, staged fits, uncertainty."""

from ._fit import CalibrationFit, calibrate, fit, residue_stats
from ._identifiability import Identifiability, IdentifiabilityWarning, analyse_identifiability
from ._layout import FIELD_NAMES, ParameterLayout
from ._modes import DEFAULT_FREEZE, DEFAULT_OPTIMIZE, MODES, CalibrationMode, get_mode, select_rows
from ._objective import CalibrationProblem, build_problem, fixture_twist_map
from ._sequence import (PAPER_SEQUENCE, OutputCorrection, SequenceStep, fit_output_correction,
                        run_sequence)

__all__ = [
    "DEFAULT_FREEZE",
    "DEFAULT_OPTIMIZE",
    "FIELD_NAMES",
    "MODES",
    "PAPER_SEQUENCE",
    "CalibrationFit",
    "CalibrationMode",
    "CalibrationProblem",
    "Identifiability",
    "OutputCorrection",
    "IdentifiabilityWarning",
    "ParameterLayout",
    "SequenceStep",
    "analyse_identifiability",
    "build_problem",
    "calibrate",
    "fit",
    "fit_output_correction",
    "fixture_twist_map",
    "get_mode",
    "residue_stats",
    "run_sequence",
    "select_rows",
]
