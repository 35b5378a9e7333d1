"""Error statistics, uncertainty, dimensionality tables, sweeps and linearity."""

from ._errors import (
    STAGE_UNCERTAINTY_M,
    STAGE_UNCERTAINTY_RAD,
    combined_uncertainty,
    error_summary,
    pose_error_magnitudes,
)
from ._characterize import (Characterization, characterize, fixture_labels, pose_error_vectors,
                            uncertainty_summary)
from ._sweeps import SweepAnalysis, SweepCurve, find_sweeps, sweep_linearity, sweep_table

__all__ = [
    "STAGE_UNCERTAINTY_M",
    "STAGE_UNCERTAINTY_RAD",
    "combined_uncertainty",
    "error_summary",
    "pose_error_magnitudes",
]
__all__ += ["Characterization", "SweepAnalysis", "SweepCurve", "characterize", "find_sweeps",
            "fixture_labels", "pose_error_vectors", "sweep_linearity", "sweep_table",
            "uncertainty_summary"]
