"""``openemt report``: one self-contained HTML report of a calibration and characterization run.

* ``openemt report ILEMT_DIR -o report.html``: import the folder, run the paper's calibration
  sequence once, reproduce MacLachlan et al. 2025, Tables II-IV with figures and the main calibration's
  parameters;
* ``openemt report --calibration CAL.json --dataset TEST.h5 -o report.html`` (or
  ``openemt report TEST.h5 --calibration CAL.json ...``): characterise a calibration on a test
  dataset against the rig kinematics (``--reference kinematics``, the default) or the dataset's
  reference poses (``--reference poses``);
* ``openemt report GRID --calibration BOARD_CAL.json [--holdout checkerboard] -o report.html``
  with a finite-coil (board) calibration: grid data with known positions and axes (a grid CSV
  or a simulated single-coil dataset) solved with the 5-DOF solver, scored as the planar
  calibration scores it (docs/planar.md#reports).
"""

from __future__ import annotations

from pathlib import Path

from .._compile_notice import PLANAR_KERNELS, announce_compile
from .._errors import InputError
from . import command_help
from ._common import add_common, emit, stage

__all__ = ["register", "run"]


def register(sub) -> None:
    p = sub.add_parser(
        "report", help=command_help("report"),
        description="Write one self-contained HTML report (tables and figures embedded). With an "
                    "ILEMT folder: the paper's calibration sequence and the reproductions of "
                    "Tables II, III and IV of MacLachlan et al. 2025. With a dataset and --calibration: accuracy, "
                    "per-fixture errors, error-vector and sweep plots and the parameters with "
                    "standard errors of that calibration. With grid data and a finite-coil "
                    "board calibration: 5-DOF accuracy on the grid's known poses, per-coil "
                    "residuals, an error map and the fitted coil parameters.")
    p.add_argument("source", nargs="?", metavar="ILEMT_DIR_OR_DATASET",
                   help="an ILEMT data folder, or a dataset file (.h5/.csv; needs --calibration)")
    p.add_argument("--dataset", help="test dataset file (alternative to the positional "
                                     "argument)")
    p.add_argument("--calibration", help="calibration to characterise (.json or ILEMT .mat)")
    p.add_argument("--concentric",
                   help="concentric calibration whose Kim18 closed form starts the pose solver "
                        "(also reported with Kim18 alone)")
    p.add_argument("--reference", choices=("kinematics", "poses"), default="kinematics",
                   help="ground truth of a dataset: rig kinematics with the calibration's "
                        "fixtures (default) or the dataset's reference poses")
    p.add_argument("--holdout", choices=("checkerboard",), default=None,
                   help="board calibrations: also score the grid's checkerboard halves as "
                        "`calibrate --mode planar --holdout checkerboard` splits them "
                        "(insample: fit points, holdout: the others)")
    p.add_argument("--title", help="report title")
    p.add_argument("-o", "--output", required=True, metavar="REPORT.html",
                   help="output HTML file")
    add_common(p)
    p.set_defaults(func=run)


def _read_dataset(path: Path):
    from ..io import import_csv, read_dataset

    if path.suffix.lower() == ".csv":
        return import_csv(path)
    return read_dataset(path)


def run(args) -> int:
    from ..io import import_ilemt_folder, read_calibration
    from ..paper import load_paper_run
    from ..paper._characterization import check_inputs
    from ..paper._run import check_paper_folder
    from ..report import characterization_report, paper_report

    if args.source and args.dataset:
        raise InputError(f"expected one input (positional or --dataset), got {args.source!r} "
                         f"and {args.dataset!r}")
    src = args.source or args.dataset
    if src is None:
        raise InputError("expected an ILEMT folder or a dataset (--dataset), got none")
    src = Path(src)
    out_path = Path(args.output)
    if src.is_dir():
        if args.dataset or args.calibration or args.concentric or args.holdout:
            raise InputError("expected no --dataset/--calibration/--concentric/--holdout with an "
                             f"ILEMT folder, got them with {str(src)!r}")
        check_paper_folder(src)              # bad input refused before any stage line
        dataset = import_ilemt_folder(src)
        announce_compile(args, "solver kernels")
        stage(args, f"running the paper's calibration sequence on {src} ...")
        run = load_paper_run(src, dataset=dataset)
        stage(args, "solving and scoring Tables II, III and IV, drawing the figures ...")
        built = paper_report(run, title=args.title)
    else:
        if not src.is_file():
            raise FileNotFoundError(f"expected an ILEMT folder or a dataset file, got "
                                    f"{str(src)!r}")
        if not args.calibration:
            raise InputError(f"expected --calibration CAL.json to characterise on "
                             f"{src.name}, got none")
        cal = read_calibration(args.calibration)
        if cal.model.dof == 5 and hasattr(cal.model, "board"):
            # a board's 5-DOF sensor: the grid report of positions and axes (docs/planar.md#reports)
            return _board_report(args, src, cal, out_path)
        if args.holdout is not None:
            raise InputError(f"expected --holdout only with a finite-coil (5-DOF board) calibration, "
                             f"got it with the {cal.kind!r} calibration {args.calibration!r}")
        ds = _read_dataset(src)
        conc = read_calibration(args.concentric) if args.concentric else None
        check_inputs(ds, cal, conc, args.reference)   # refused before any stage line
        announce_compile(args, "solver kernels")
        stage(args, f"solving and scoring the {len(ds)} rows of {src.name} with "
                    f"{args.calibration}, drawing the figures ...")
        built = characterization_report(ds, cal, concentric=conc, reference=args.reference,
                                        title=args.title)
    stage(args, f"writing {out_path} ...")
    summary = built.write(out_path)
    human = [f"report: {out_path} ({summary['n_figures']} figures)"]
    if summary["mode"] == "ilemt":
        for name, r in summary["table2"].items():
            human.append(f"  Table II {name:11s} {r['trans_rms_mm']:.4f} mm RMS "
                         f"(u(P) {r['trans_uncert_mm']:.4f} mm), {r['rot_rms_deg']:.4f} deg RMS")
            human += _why(r)
        if summary["table3"] is not None:
            human.append(f"  Table III max |ours/paper - 1| = "
                         f"{100 * summary['table3']['max_deviation']:.2f} %")
    else:
        for name, r in summary["accuracy"].items():
            human.append(f"  {name:26s} {r['trans_rms_mm']:.4f} mm RMS (u(P) "
                         f"{r['trans_uncert_mm']:.4f} mm), {r['rot_rms_deg']:.4f} deg RMS")
            human += _why(r)
    human.append(f"  total {summary['seconds']['total']:.2f} s")
    emit(args, summary, human)
    return 0


def _why(row: dict) -> list:
    """The reason line of a failed or surprising accuracy row (none for the others)."""
    reason = row.get("reason")
    return [f"      why: {reason}"] if reason else []


def _board_report(args, src: Path, cal, out_path: Path) -> int:
    """The report of a finite-coil calibration on grid data (docs/planar.md#reports)."""
    from ..calibrate._planar import check_grid_units, read_grid
    from ..report import planar_report

    if args.concentric:
        raise InputError(f"expected no --concentric with a finite-coil calibration (the 5-DOF "
                         f"solver starts from its seed grid), got {args.concentric!r}")
    data = read_grid(src)
    n = cal.model.n_coils
    if data.couplings.shape[1] != n:
        raise InputError(f"expected grid data with {n} coil columns for the board calibration "
                         f"{str(args.calibration)!r}, got {data.couplings.shape[1]} in "
                         f"{src.name}")
    check_grid_units(data)                 # refused before any stage line
    announce_compile(args, "finite-coil kernels", kernels=PLANAR_KERNELS)
    stage(args, f"solving the {len(data.points)} grid points with the board calibration "
                "(5-DOF), drawing the error map ...")
    built = planar_report(data, cal, holdout=args.holdout, dataset=str(src), title=args.title)
    summary = built.write(out_path)
    human = [f"report: {out_path} ({summary['n_figures']} figures)"]
    blocks = [("all points", summary["accuracy"])]
    if "holdout" in summary:
        blocks += [("in-sample", summary["insample"]), ("held out", summary["holdout"])]
    for name, b in blocks:
        human.append(f"  {name:11s} {b['position_rms_mm']:.4f} mm RMS, "
                     f"{b['position_max_mm']:.4f} mm max, {b['axis_rms_deg']:.4f} deg axis RMS "
                     f"over {b['n']} points ({b['n_failed']} failed)")
    human.append(f"  total {summary['seconds']['total']:.2f} s")
    emit(args, summary, human)
    return 0
