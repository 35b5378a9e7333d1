"""``openemt import FORMAT ...``: convert acquisition files (an ILEMT folder, NDI exports, pose
CSV files, a track log's couplings) into one openemt dataset file."""

from __future__ import annotations

from ._common import add_command, emit, run_workflow


def register(sub) -> None:
    from ..io import IMPORT_FORMATS, ImportOptions

    fsub = add_command(sub, "import").add_subparsers(dest="format", metavar="FORMAT")
    fsub.required = True
    for name, (help_, description, fields) in IMPORT_FORMATS.items():
        add_command(fsub, name, run, ImportOptions, fields, help=help_, description=description)
    t = add_command(fsub, "track-log", run_track_log, help="the couplings of a track --log .h5 "
                    "file: a recording", description="Import the couplings one sensor of a "
                    "'track --log' HDF5 file recorded into a dataset marked as a recording, "
                    "which 'openemt solve' solves as a time series.")
    t.add_argument("log_file", metavar="LOG", help="track log (.h5)")
    t.add_argument("-o", "--output", required=True, help="output dataset file (.h5)")
    t.add_argument("--sensor", default=None, help="sensor name (needed for a log of several)")


def run(args) -> int:
    from ..io import ImportOptions, import_files

    return run_workflow(args, import_files, ImportOptions, format=args.format)


def run_track_log(args) -> int:
    """``import track-log``: a track log's couplings as a dataset marked as a recording."""
    from ..io import write_dataset
    from ..live import read_track_log, track_log_dataset

    ds = track_log_dataset(read_track_log(args.log_file), args.sensor,
                           args.log_file.rpartition("/")[2])
    write_dataset(ds, args.output)
    s = {"path": args.output, "format": "track-log", "n_samples": ds.n_samples,
         "n_source": ds.n_source, "n_sensor": ds.n_sensor, "sensor": ds.meta["sensor"]["name"],
         "complete": ds.meta["complete"],
         "sample_rate_hz": ds.meta["recording"]["sample_rate_hz"]}
    emit(args, s, [f"imported {ds.n_samples} samples of sensor {s['sensor']} (a recording) "
                   f"-> {args.output}"])
    return 0
