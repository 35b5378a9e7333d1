"""Alignment of two trackers (or a tracker and a robot): hand-eye / robot-world calibration
``A_i X = Y B_i`` and pairing of recordings (docs/alignment.md)."""

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
    "MATCH_MODES",
    "MIN_PAIRS",
    "OUTLIER_P",
    "HandEyeResult",
    "axyb_closed_form",
    "fit_axyb",
    "pair_rows",
    "reference_in_measured_frame",
]
