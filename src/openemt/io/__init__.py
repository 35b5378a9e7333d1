"""Reading and writing every box of the pipeline: datasets, calibrations, importers."""

from .._atomic import atomic_path
from ._board_file import load_board, read_board, write_board
from ._calfile import read_calibration, write_calibration
from ._calibration import Calibration
from ._csv import export_csv, import_csv
from ._dataset import BAND_COUPLINGS, Dataset, is_recording, recording_meta, signed_real
from ._h5write import atomic_h5
from ._hdf5 import CouplingReader, open_dataset_couplings, read_dataset, write_dataset
from ._ilemt import (
                     compensate_stage,
                     file_sha256,
                     import_ilemt_folder,
                     parse_sign_options,
                     read_ilemt_dat,
)
from ._ilemt_mat import read_ilemt_calibration
from ._import_workflow import (
                     IMPORT_FORMATS,
                     ImportOptions,
                     ImportResult,
                     import_files,
                     parse_sign_arg,
)
from ._ndi import NdiRecording, NdiTool, import_ndi, read_ndi_tsv, write_ndi_tsv
from ._pose_dataset import pose_dataset, read_pose_dataset
from ._poses_csv import (
                     PoseTable,
                     StaticAverage,
                     average_static,
                     import_poses_csv,
                     read_poses_csv,
                     write_poses_csv,
)

__all__ = ["BAND_COUPLINGS", "Calibration", "Dataset", "atomic_h5", "atomic_path", "is_recording",
           "recording_meta", "signed_real"]
__all__ += ["load_board", "read_board", "write_board"]

__all__ += ["compensate_stage", "file_sha256", "import_ilemt_folder", "parse_sign_options",
            "read_ilemt_dat"]
__all__ += ["CouplingReader", "export_csv", "import_csv", "open_dataset_couplings",
            "read_calibration", "read_dataset", "read_ilemt_calibration", "write_calibration",
            "write_dataset"]
__all__ += ["NdiRecording", "NdiTool", "PoseTable", "StaticAverage", "average_static",
            "import_ndi", "import_poses_csv", "pose_dataset", "read_ndi_tsv", "read_pose_dataset",
            "read_poses_csv", "write_ndi_tsv", "write_poses_csv"]
__all__ += ["IMPORT_FORMATS", "ImportOptions", "ImportResult", "import_files", "parse_sign_arg"]
