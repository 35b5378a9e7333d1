"""Error statistics, uncertainty, dimensionality tables, sweeps and linearity."""

from .._lazy import lazy_exports

#: where each public name lives; a module is imported on first use of one of its names
_SOURCES = {
    "._breakdown": ("RANGE_EDGES_MM", "ErrorBreakdown", "RepeatScatter", "error_breakdown",
                    "repeat_scatter"),
    "._characterize": ("Characterization", "UncertaintySummary", "characterize", "fixture_labels",
                       "uncertainty_summary"),
    "._errors": ("ACCURACY_KEYS", "STAGE_UNCERTAINTY_DEG", "STAGE_UNCERTAINTY_M",
                 "STAGE_UNCERTAINTY_MM", "STAGE_UNCERTAINTY_RAD", "ErrorSummary", "axis_errors",
                 "coil_residual_percent", "combined_uncertainty", "error_summary",
                 "point_axis_summary", "pose_error_magnitudes", "pose_error_vectors",
                 "pose_errors"),
    "._sweeps": ("SweepAnalysis", "SweepCurve", "SweepTable", "find_sweeps", "sweep_linearity",
                 "sweep_table"),
}
__all__, __getattr__, __dir__ = lazy_exports(__name__, _SOURCES)
