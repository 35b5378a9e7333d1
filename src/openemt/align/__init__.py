"""Alignment of two trackers (or a tracker and a robot): hand-eye / robot-world calibration
``A_i X = Y B_i``, pairing of recordings, and the motion, time offset and dwells of two streams
(docs/alignment.md, docs/reference-calibration.md#collecting)."""

from .._lazy import lazy_exports

#: where each public name lives; a module is imported on first use of one of its names
_SOURCES = {
    "._dwells": ("BASELINE_S", "COUPLING_RATE_STATIC", "GRID_S", "LEVER_M", "MARGIN_S",
                 "MIN_DWELL_S", "ROTATION_SPEED_STATIC", "SPEED_STATIC", "DwellSet",
                 "OffsetEstimate", "average_dwell", "collect_dwells", "coupling_motion", "coverage",
                 "estimate_time_offset", "find_dwells", "log_profile", "mean_pose", "pose_motion",
                 "thresholds", "time_offset_scan"),
    "._handeye": ("MIN_PAIRS", "OUTLIER_P", "HandEyeResult", "axyb_closed_form", "fit_axyb",
                  "reference_in_measured_frame"),
    "._pairs": ("MATCH_MODES", "pair_rows"),
}
__all__, __getattr__, __dir__ = lazy_exports(__name__, _SOURCES)
