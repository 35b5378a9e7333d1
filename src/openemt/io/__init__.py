"""Reading and writing every box of the pipeline: datasets, calibrations, importers."""

from ._atomic import atomic_path
from ._calibration import Calibration
from ._dataset import Dataset, signed_real
from ._ilemt import (compensate_stage, file_sha256, import_ilemt_folder, parse_sign_options,
                     read_ilemt_dat)

__all__ = ["Calibration", "Dataset", "atomic_path", "signed_real"]

__all__ += ["compensate_stage", "file_sha256", "import_ilemt_folder", "parse_sign_options",
            "read_ilemt_dat"]
