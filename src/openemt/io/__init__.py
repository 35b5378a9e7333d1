"""Reading and writing every box of the pipeline: datasets, calibrations, importers."""

from .._lazy import lazy_exports

#: where each public name lives; a module is imported on first use of one of its names (so a
#: command reading a dataset does not load the board, field and calibration libraries)
_SOURCES = {
    ".._atomic": ("atomic_path",),
    "._board_file": ("load_board", "read_board", "write_board"),
    "._calfile": ("read_calibration", "write_calibration"),
    "._calibration": ("Calibration",),
    "._csv": ("export_csv", "import_csv"),
    "._dataset": ("BAND_COUPLINGS", "Dataset", "is_recording", "recording_meta",
                   "signed_real"),
    "._h5write": ("atomic_h5",),
    "._hdf5": ("CouplingReader", "open_dataset_couplings", "read_dataset", "write_dataset"),
    "._ilemt": ("compensate_stage", "file_sha256", "import_ilemt_folder", "parse_sign_options",
                "read_ilemt_dat"),
    "._ilemt_mat": ("read_ilemt_calibration",),
    "._import_workflow": ("IMPORT_FORMATS", "ImportOptions", "ImportResult", "import_files",
                          "parse_sign_arg"),
    "._ndi": ("NdiRecording", "NdiTool", "import_ndi", "read_ndi_tsv", "write_ndi_tsv"),
    "._pose_dataset": ("pose_dataset", "read_pose_dataset"),
    "._poses_csv": ("PoseTable", "StaticAverage", "average_static", "import_poses_csv",
                    "read_poses_csv", "write_poses_csv"),
}
__all__, __getattr__, __dir__ = lazy_exports(__name__, _SOURCES)
