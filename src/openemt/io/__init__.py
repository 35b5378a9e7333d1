"""Reading and writing every box of the pipeline: datasets, calibrations, importers."""

from ._atomic import atomic_path
from ._calibration import Calibration
from ._dataset import Dataset, signed_real

__all__ = ["Calibration", "Dataset", "atomic_path", "signed_real"]
