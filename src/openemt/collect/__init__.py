"""Collection of a reference-pose dataset (``openemt collect``): couplings of a tracker source
recorded while a reference (an OpenIGTLink server such as PLUS or 3D Slicer, a CSV with time
stamps, or a simulated robot / optical tracker) reports poses; the two clocks synchronised, both
streams averaged over the dwells where both are static, the pairing checked, and the dataset
written for ``openemt calibrate --mode reference`` (docs/reference-calibration.md#collecting).
"""

from ._collector import (
    MIN_CONFIDENCE,
    MIN_CORRELATION,
    MIN_OVERLAP_S,
    OFFSET_WINDOW_S,
    Collector,
)
from ._gate import MAX_STEP_S, ROTATION_TOL, Drops, TimeGate, rigid_rows
from ._pairing import MAX_ANGLE_DIFF_DEG, MIN_RANK_CORRELATION, SCALE_RANGE, check_pairing
from ._refcsv import MAX_MEDIAN_STEP_S, ReferenceTable, read_reference_csv
from ._reference import (
    DwellMotion,
    ReferenceClient,
    SimulatedReferenceServer,
    parse_reference_url,
    parse_transform_body,
    simulated_motion,
)
from ._workflow import (
    SIM_CLOCK_OFFSET_S,
    SIM_LATENCY_S,
    SIM_RATE_HZ,
    CollectOptions,
    CollectResult,
    collect,
    spare_poses,
)

__all__ = [
    "MAX_ANGLE_DIFF_DEG",
    "MAX_MEDIAN_STEP_S",
    "MAX_STEP_S",
    "MIN_CONFIDENCE",
    "MIN_CORRELATION",
    "MIN_OVERLAP_S",
    "MIN_RANK_CORRELATION",
    "OFFSET_WINDOW_S",
    "ROTATION_TOL",
    "SCALE_RANGE",
    "SIM_CLOCK_OFFSET_S",
    "SIM_LATENCY_S",
    "SIM_RATE_HZ",
    "CollectOptions",
    "CollectResult",
    "Collector",
    "Drops",
    "DwellMotion",
    "ReferenceClient",
    "ReferenceTable",
    "SimulatedReferenceServer",
    "TimeGate",
    "check_pairing",
    "collect",
    "parse_reference_url",
    "parse_transform_body",
    "read_reference_csv",
    "rigid_rows",
    "simulated_motion",
    "spare_poses",
]
