"""Error statistics, uncertainty, dimensionality tables, sweeps and linearity."""

from ._errors import (
    STAGE_UNCERTAINTY_M,
    STAGE_UNCERTAINTY_RAD,
    combined_uncertainty,
    error_summary,
    pose_error_magnitudes,
)

__all__ = [
    "STAGE_UNCERTAINTY_M",
    "STAGE_UNCERTAINTY_RAD",
    "combined_uncertainty",
    "error_summary",
    "pose_error_magnitudes",
]
