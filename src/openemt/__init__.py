"""openemt: open software stack for electromagnetic position-and-orientation trackers.

The pipeline's subpackages (``openemt.solve``, ``openemt.calibrate``, ...) and its main objects
and functions are reachable from the top level; they are imported on first use, so
``import openemt`` stays fast.

Examples
--------
>>> import openemt
>>> folder = openemt.datasets.path("cal_9_15_premo_cmu")
>>> cal = openemt.read_ilemt_calibration(folder / "output" / "XYZ_hr_cal.mat")
>>> cal.model.n_source, cal.model.n_sensor
(3, 3)
"""

from __future__ import annotations

import importlib
from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("openemt")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0.0.0+unknown"

#: Subpackages, in pipeline order.
SUBPACKAGES = ("geometry", "field", "board", "simulate", "io", "signal", "solve", "calibrate",
               "correct", "align", "evaluate", "navigate", "paper", "report", "live", "collect",
               "view", "bench", "datasets", "design")

#: Top-level name -> (subpackage, name there).
_ATTRIBUTES = {
    # data and calibration files
    "Dataset": ("io", "Dataset"),
    "read_dataset": ("io", "read_dataset"),
    "write_dataset": ("io", "write_dataset"),
    "Calibration": ("io", "Calibration"),
    "read_calibration": ("io", "read_calibration"),
    "write_calibration": ("io", "write_calibration"),
    "read_ilemt_calibration": ("io", "read_ilemt_calibration"),
    "import_ilemt_folder": ("io", "import_ilemt_folder"),
    # models and geometry
    "DipoleModel": ("field", "DipoleModel"),
    "pose_from_vector": ("geometry", "pose_from_vector"),
    "vector_from_pose": ("geometry", "vector_from_pose"),
    # pose solution
    "solve_lm": ("solve", "solve_lm"),
    "solve_svd": ("solve", "solve_svd"),
    "solve_kuipers": ("solve", "solve_kuipers"),
    "solve_kim18": ("solve", "solve_kim18"),
    "SolveResult": ("solve", "SolveResult"),
    "Status": ("solve", "Status"),
    # calibration, correction, evaluation
    "fit_calibration": ("calibrate", "fit"),
    "CalibrationFit": ("calibrate", "CalibrationFit"),
    "fit_correction": ("correct", "fit_correction"),
    "pose_errors": ("evaluate", "pose_errors"),
    "error_summary": ("evaluate", "error_summary"),
    "ErrorSummary": ("evaluate", "ErrorSummary"),
    # navigation: tool calibration, registration, assessment
    "pivot_calibration": ("navigate", "pivot_calibration"),
    "spin_calibration": ("navigate", "spin_calibration"),
    "register_points": ("navigate", "register_points"),
    "register_points_batch": ("navigate", "register_points_batch"),
    "assess_grid": ("navigate", "assess_grid"),
    "read_markups": ("navigate", "read_markups"),
}

#: the version, then the subpackages in pipeline order, then the names
__all__ = ["__version__", *SUBPACKAGES, *_ATTRIBUTES]


def __getattr__(name: str):
    if name in SUBPACKAGES:
        module = importlib.import_module(f"{__name__}.{name}")
        globals()[name] = module
        return module
    if name in _ATTRIBUTES:
        package, attr = _ATTRIBUTES[name]
        value = getattr(importlib.import_module(f"{__name__}.{package}"), attr)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'openemt' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))
