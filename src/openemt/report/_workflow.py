"""The ``openemt report`` workflow: options in, one self-contained HTML report written, its
summary out."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from .._errors import InputError
from .._options import SILENT, option
from .._result import Result

__all__ = ["ReportOptions", "ReportResult", "write_report"]


@dataclasses.dataclass(frozen=True)
class ReportOptions:
    """What ``openemt report`` reports on (field metadata: the command-line help)."""

    output: str = option(None, "output HTML file", flag=("-o", "--output"), required=True,
                         metavar="REPORT.html")
    source: str | None = option(None, "an ILEMT data folder, or a dataset file (.h5/.csv; needs "
                                "--calibration)", positional=True, optional=True,
                                metavar="ILEMT_DIR_OR_DATASET")
    dataset: str | None = option(None, "test dataset file (alternative to the positional "
                                 "argument)")
    calibration: str | None = option(None, "calibration to characterise (.json or ILEMT .mat)")
    concentric: str | None = option(None, "concentric calibration whose Kim18 closed form starts "
                                    "the pose solver (also reported with Kim18 alone)")
    reference: str = option("kinematics", "ground truth of a dataset: rig kinematics with the "
                            "calibration's fixtures (default) or the dataset's reference poses",
                            choices=("kinematics", "poses"))
    holdout: str | None = option(None, "board calibrations: also score the grid's checkerboard "
                                 "halves as calibrate --mode planar --holdout checkerboard splits "
                                 "them (insample: fit points, holdout: the others)",
                                 choices=("checkerboard",))
    title: str | None = option(None, "report title")


@dataclasses.dataclass(frozen=True)
class ReportResult(Result):
    """The written report's summary (``to_dict()``: its layout depends on ``summary["mode"]``:
    ``ilemt``, a calibration's characterization, or a board's grid)."""

    summary: dict

    def to_dict(self) -> dict:
        return dict(self.summary)

    def lines(self) -> list[str]:
        """The human-readable summary: the accuracy rows and why any failed."""
        s = self.summary
        human = [f"report: {s['report']} ({s['n_figures']} figures)"]
        if s["mode"] == "ilemt":
            for name, r in s["table2"].items():
                human.append(f"  Table II {name:11s} {r['trans_rms_mm']:.4f} mm RMS "
                             f"(u(P) {r['trans_uncert_mm']:.4f} mm), "
                             f"{r['rot_rms_deg']:.4f} deg RMS")
                human += [f"      why: {r['reason']}"] if r.get("reason") else []
            if s["table3"] is not None:
                human.append(f"  Table III max |ours/paper - 1| = "
                             f"{100 * s['table3']['max_deviation']:.2f} %")
        elif "position_rms_mm" in s["accuracy"]:
            blocks = [("all points", s["accuracy"])]
            if "holdout" in s:
                blocks += [("in-sample", s["insample"]), ("held out", s["holdout"])]
            for name, b in blocks:
                human.append(f"  {name:11s} {b['position_rms_mm']:.4f} mm RMS, "
                             f"{b['position_max_mm']:.4f} mm max, {b['axis_rms_deg']:.4f} deg "
                             f"axis RMS over {b['n']} points ({b['n_failed']} failed)")
        else:
            for name, r in s["accuracy"].items():
                human.append(f"  {name:26s} {r['trans_rms_mm']:.4f} mm RMS (u(P) "
                             f"{r['trans_uncert_mm']:.4f} mm), {r['rot_rms_deg']:.4f} deg RMS")
                human += [f"      why: {r['reason']}"] if r.get("reason") else []
        return human + [f"  total {s['seconds']['total']:.2f} s"]


def write_report(o: ReportOptions, say=None) -> ReportResult:
    """Build and write the report ``o`` asks for (bad input refused before any stage line)."""
    from .._compile_notice import announce_compile
    from ..io import import_ilemt_folder, read_calibration
    from ..paper import load_paper_run
    from ..paper._characterization import check_inputs
    from ..paper._run import check_paper_folder
    from ._built import characterization_report, paper_report

    say = say or SILENT
    if o.source and o.dataset:
        raise InputError(f"expected one input (positional or --dataset), got {o.source!r} "
                         f"and {o.dataset!r}")
    if (o.source or o.dataset) is None:
        raise InputError("expected an ILEMT folder or a dataset (--dataset), got none")
    src = Path(o.source or o.dataset)
    if src.is_dir():
        if o.dataset or o.calibration or o.concentric or o.holdout:
            raise InputError("expected no --dataset/--calibration/--concentric/--holdout with an "
                             f"ILEMT folder, got them with {str(src)!r}")
        check_paper_folder(src)
        dataset = import_ilemt_folder(src)
        announce_compile(say, "solver kernels")
        say(f"running the paper's calibration sequence on {src} ...")
        run = load_paper_run(src, dataset=dataset)
        say("solving and scoring Tables II, III and IV, drawing the figures ...")
        built = paper_report(run, title=o.title)
    else:
        if not src.is_file():
            raise FileNotFoundError(f"expected an ILEMT folder or a dataset file, got "
                                    f"{str(src)!r}")
        if not o.calibration:
            raise InputError(f"expected --calibration CAL.json to characterise on "
                             f"{src.name}, got none")
        cal = read_calibration(o.calibration)
        if cal.model.dof == 5 and hasattr(cal.model, "board"):
            built = _board_report(o, src, cal, say)
        else:
            if o.holdout is not None:
                raise InputError(f"expected --holdout only with a finite-coil (5-DOF board) "
                                 f"calibration, got it with the {cal.kind!r} calibration "
                                 f"{o.calibration!r}")
            ds = _read_dataset(src)
            conc = read_calibration(o.concentric) if o.concentric else None
            check_inputs(ds, cal, conc, o.reference)
            announce_compile(say, "solver kernels")
            say(f"solving and scoring the {len(ds)} rows of {src.name} with {o.calibration}, "
                "drawing the figures ...")
            built = characterization_report(ds, cal, concentric=conc, reference=o.reference,
                                            title=o.title)
    say(f"writing {o.output} ...")
    return ReportResult(built.write(Path(o.output)))


def _read_dataset(path: Path):
    from ..io import import_csv, read_dataset

    return import_csv(path) if path.suffix.lower() == ".csv" else read_dataset(path)


def _board_report(o: ReportOptions, src: Path, cal, say):
    """The report of a finite-coil calibration on grid data (docs/planar.md#reports)."""
    from .._compile_notice import PLANAR_KERNELS, announce_compile
    from ..calibrate._planar import check_grid_units, read_grid
    from ._planar import planar_report

    if o.concentric:
        raise InputError(f"expected no --concentric with a finite-coil calibration (the 5-DOF "
                         f"solver starts from its seed grid), got {o.concentric!r}")
    data = read_grid(src)
    n = cal.model.n_coils
    if data.couplings.shape[1] != n:
        raise InputError(f"expected grid data with {n} coil columns for the board calibration "
                         f"{str(o.calibration)!r}, got {data.couplings.shape[1]} in "
                         f"{src.name}")
    check_grid_units(data)
    announce_compile(say, "finite-coil kernels", kernels=PLANAR_KERNELS)
    say(f"solving the {len(data.points)} grid points with the board calibration (5-DOF), "
        "drawing the error map ...")
    return planar_report(data, cal, holdout=o.holdout, dataset=str(src), title=o.title)
