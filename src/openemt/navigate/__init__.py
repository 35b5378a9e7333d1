"""The navigation engineer's toolkit on tracked poses: pivot and spin calibration of a tool,
paired-point registration with FRE and predicted TRE, the standard grid accuracy assessment,
and 3D Slicer markups files. Pure array functions with frozen results; see docs/navigation.md.
"""

from ._assess import DISTANCE_CLASSES_MM, GridAssessment, assess_grid, regular_grid
from ._inputs import ToolPoses, read_points_csv, read_tool_poses
from ._markups import MarkupPoints, is_markups_path, read_markups
from ._pivot import (
    MAX_PIVOT_RMS_MM,
    MAX_SPIN_RMS_DEG,
    MIN_POSES,
    MIN_SPIN_DEG,
    PIVOT_METHODS,
    TOOL_FORMAT,
    PivotResult,
    SpinResult,
    pivot_calibration,
    read_tip_transform,
    spin_calibration,
)
from ._register import (
    BatchRegistration,
    Registration,
    predicted_tre,
    register_points,
    register_points_batch,
    rigid_fit,
)
from ._simulate import simulate_grid_points, simulate_pivot_poses, simulate_spin_poses

__all__ = [
    "DISTANCE_CLASSES_MM",
    "MAX_PIVOT_RMS_MM",
    "MAX_SPIN_RMS_DEG",
    "MIN_POSES",
    "MIN_SPIN_DEG",
    "PIVOT_METHODS",
    "TOOL_FORMAT",
    "BatchRegistration",
    "GridAssessment",
    "MarkupPoints",
    "PivotResult",
    "Registration",
    "SpinResult",
    "ToolPoses",
    "assess_grid",
    "is_markups_path",
    "pivot_calibration",
    "predicted_tre",
    "read_markups",
    "read_points_csv",
    "read_tip_transform",
    "read_tool_poses",
    "register_points",
    "register_points_batch",
    "regular_grid",
    "rigid_fit",
    "simulate_grid_points",
    "simulate_pivot_poses",
    "simulate_spin_poses",
    "spin_calibration",
]
