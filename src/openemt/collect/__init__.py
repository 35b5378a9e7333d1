"""Collection of a reference-pose dataset (``openemt collect``): couplings of a tracker source
recorded while a reference (an OpenIGTLink server such as PLUS or 3D Slicer, a CSV with time
stamps, or a simulated robot / optical tracker) reports poses; the two clocks synchronised, both
streams averaged over the dwells where both are static, the pairing checked, and the dataset
written for ``openemt calibrate --mode reference`` (docs/reference-calibration.md#collecting).
"""

from .._lazy import lazy_exports

#: where each public name lives; a module is imported on first use of one of its names
_SOURCES = {
    "._collector": ("MIN_CONFIDENCE", "MIN_CORRELATION", "MIN_OVERLAP_S", "OFFSET_WINDOW_S",
                    "Collector"),
    "._gate": ("MAX_STEP_S", "ROTATION_TOL", "Drops", "TimeGate", "rigid_rows"),
    "._pairing": ("MAX_ANGLE_DIFF_DEG", "MIN_RANK_CORRELATION", "SCALE_RANGE", "check_pairing"),
    "._refcsv": ("MAX_MEDIAN_STEP_S", "ReferenceTable", "read_reference_csv"),
    "._reference": ("DwellMotion", "ReferenceClient", "SimulatedReferenceServer",
                    "parse_reference_url", "parse_transform_body", "simulated_motion"),
    "._workflow": ("SIM_CLOCK_OFFSET_S", "SIM_LATENCY_S", "SIM_RATE_HZ", "CollectOptions",
                   "CollectResult", "collect", "spare_poses"),
}
__all__, __getattr__, __dir__ = lazy_exports(__name__, _SOURCES)
