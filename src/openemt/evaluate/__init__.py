"""Error statistics, uncertainty, dimensionality tables, sweeps and linearity."""

from ._breakdown import (
    RANGE_EDGES_MM,
    ErrorBreakdown,
    RepeatScatter,
    error_breakdown,
    repeat_scatter,
)
from ._characterize import (
    Characterization,
    UncertaintySummary,
    characterize,
    fixture_labels,
    uncertainty_summary,
)
from ._errors import (
    ACCURACY_KEYS,
    STAGE_UNCERTAINTY_DEG,
    STAGE_UNCERTAINTY_M,
    STAGE_UNCERTAINTY_MM,
    STAGE_UNCERTAINTY_RAD,
    ErrorSummary,
    combined_uncertainty,
    error_summary,
    pose_error_magnitudes,
    pose_error_vectors,
    pose_errors,
)
from ._sweeps import (
    SweepAnalysis,
    SweepCurve,
    SweepTable,
    find_sweeps,
    sweep_linearity,
    sweep_table,
)

__all__ = [
    "ACCURACY_KEYS",
    "RANGE_EDGES_MM",
    "STAGE_UNCERTAINTY_DEG",
    "STAGE_UNCERTAINTY_M",
    "STAGE_UNCERTAINTY_MM",
    "STAGE_UNCERTAINTY_RAD",
    "Characterization",
    "ErrorBreakdown",
    "ErrorSummary",
    "RepeatScatter",
    "SweepAnalysis",
    "SweepCurve",
    "SweepTable",
    "UncertaintySummary",
    "characterize",
    "combined_uncertainty",
    "error_breakdown",
    "error_summary",
    "find_sweeps",
    "fixture_labels",
    "pose_error_magnitudes",
    "pose_error_vectors",
    "pose_errors",
    "repeat_scatter",
    "sweep_linearity",
    "sweep_table",
    "uncertainty_summary",
]
