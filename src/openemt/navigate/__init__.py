"""The navigation engineer's toolkit on tracked poses: pivot and spin calibration of a tool,
paired-point registration with FRE and predicted TRE (and its 3D Slicer transform), the
standard grid accuracy assessment, points from the dwells of a log, 3D Slicer markups files,
one reader of every pose file, and simulated tool motions. Pure array functions with frozen
results, and one workflow per step (an options record in, a :class:`NavigationRun` out); see
docs/navigation.md.
"""

from .._lazy import lazy_exports

#: where each public name lives; a module is imported on first use of one of its names
_SOURCES = {
    "._assess": ("DISTANCE_CLASSES_MM", "MAX_ASSESS_POINTS", "MAX_STORED_PAIRS", "GridAssessment",
                 "assess_grid", "regular_grid"),
    "._inputs": ("MAX_POSE_FILE_BYTES", "MAX_POSE_ROWS", "ROTATION_TOLERANCE", "ToolPoses",
                 "check_rotations", "read_points_csv", "read_tool_poses"),
    "._markups": ("MarkupPoints", "is_markups_path", "read_markups", "write_markups"),
    "._pivot": ("MAX_PIVOT_RMS_MM", "MAX_SPIN_RMS_DEG", "MIN_POSES", "MIN_SPIN_DEG",
                "PIVOT_METHODS", "TOOL_FORMAT", "PivotResult", "SpinResult", "pivot_calibration",
                "read_tip_transform", "spin_calibration"),
    "._register": ("BatchRegistration", "Registration", "predicted_tre", "register_points",
                   "register_points_batch", "rigid_fit"),
    "._simulate": ("MOTIONS", "MotionOptions", "simulate_grid_points", "simulate_pivot_poses",
                   "simulate_spin_poses", "simulate_tool_session"),
    "._steps": ("MAX_LOG_SECONDS", "REGISTRATION_FORMAT", "AlignOptions", "AssessOptions",
                "NavigationRun", "PivotOptions", "PointsOptions", "RegisterOptions", "SpinOptions",
                "align_poses", "assess", "pivot", "points", "read_registration", "register", "spin",
                "write_slicer_transform"),
}
__all__, __getattr__, __dir__ = lazy_exports(__name__, _SOURCES)
