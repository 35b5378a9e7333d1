"""Alignment of two trackers (or a tracker and a robot): hand-eye / robot-world calibration
``A_i X = Y B_i``, pairing of recordings, and the motion, time offset and dwells of two streams
(docs/alignment.md, docs/reference-calibration.md#collecting)."""

from ._dwells import (
    COUPLING_RATE_STATIC,
    ROTATION_SPEED_STATIC,
    SPEED_STATIC,
    DwellSet,
    collect_dwells,
    coupling_motion,
    coverage,
    estimate_time_offset,
    find_dwells,
    log_profile,
    mean_pose,
    pose_motion,
    thresholds,
)
from ._handeye import (
    MIN_PAIRS,
    OUTLIER_P,
    HandEyeResult,
    axyb_closed_form,
    fit_axyb,
    reference_in_measured_frame,
)
from ._pairs import MATCH_MODES, pair_rows

__all__ = [
    "COUPLING_RATE_STATIC",
    "ROTATION_SPEED_STATIC",
    "SPEED_STATIC",
    "DwellSet",
    "collect_dwells",
    "coupling_motion",
    "coverage",
    "estimate_time_offset",
    "find_dwells",
    "log_profile",
    "mean_pose",
    "pose_motion",
    "thresholds",
    "MATCH_MODES",
    "MIN_PAIRS",
    "OUTLIER_P",
    "HandEyeResult",
    "axyb_closed_form",
    "fit_axyb",
    "pair_rows",
    "reference_in_measured_frame",
]
