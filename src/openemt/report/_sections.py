"""Sections of the calibration-and-characterization report, built from computed results.

Each function adds headings, tables, paragraphs and figures to a :class:`~openemt.report.Report`;
none of them computes an error or solves a pose. The numbers come from
:func:`openemt.paper.characterize_calibration`, :func:`openemt.report.paper_report` and
:func:`openemt.evaluate.sweep_linearity`.
"""

from __future__ import annotations

import re

from ..calibrate._check import ILEMT_VALID_RESNORM
from ..evaluate import ACCURACY_KEYS, STAGE_UNCERTAINTY_DEG, STAGE_UNCERTAINTY_MM
from ._glossary import glossary_section
from ._html import Report

_PARAMETER_CAPTION = ("Coil positions and fixture translations in mm, fixture rotations in "
                      "degrees, moments in gain units; status says which parameters the fit "
                      "estimated and which it held fixed (no standard error).")

__all__ = [
    "accuracy_section",
    "breakdown_section",
    "by_fixture_table",
    "characterization_document",
    "error_figures",
    "paper_document",
    "reason_notes",
    "simulation_section",
    "sweep_section",
    "table3_section",
    "uncertainty_paragraph",
]



def accuracy_section(rep: Report, rows, *, with_paper: bool) -> None:
    """Table of accuracy rows (``condition``, statistics, combined uncertainties, counts) and
    its note; with ``with_paper``, each row's ``paper`` values follow it."""
    cols = ["condition", *ACCURACY_KEYS, "trans_uncert_mm", "rot_uncert_deg", "n", "n_invalid"]
    table = []
    for r in rows:
        table.append({c: r.get(c, "") for c in cols})
        if with_paper and r.get("paper"):
            table.append({"condition": "  paper", **r["paper"]})
    rep.table(table, cols, digits=5,
              caption="Translation (mm) and rotation (deg) error magnitudes, RMS and max")
    reason_notes(rep, rows, "condition")
    u_mm, u_deg = STAGE_UNCERTAINTY_MM, STAGE_UNCERTAINTY_DEG
    rep.paragraph(f"trans_uncert_mm = sqrt(RMS^2 + {u_mm:.3f}^2) and rot_uncert_deg = "
                  f"sqrt(RMS^2 + {u_deg:.2f}^2) combine the calibration error u(cal) with the "
                  "stage uncertainty (MacLachlan et al. 2025, eq. 10). Invalid solutions "
                  f"(residue >= {ILEMT_VALID_RESNORM:g}) are kept in the statistics and counted "
                  "in n_invalid.",
                  note=True)


def reason_notes(rep: Report, rows, label: str) -> None:
    """One note per row with a ``reason`` (a failed or surprising row,
    :func:`openemt.paper.explain_rows`): ``<row>: <reason>``."""
    for r in rows:
        if r.get("reason"):
            rep.paragraph(f"{r[label]}: {r['reason']}.", note=True)


def uncertainty_paragraph(rep: Report, row: dict) -> None:
    """The combined standard uncertainty of one accuracy row, spelled out."""
    u_mm, u_deg = STAGE_UNCERTAINTY_MM, STAGE_UNCERTAINTY_DEG
    rep.paragraph(
        f"Combined standard uncertainty of a measurement (MacLachlan et al. 2025, eq. 10) for "
        f"{row['condition']}: u(P) = sqrt({row['trans_rms_mm']:.3f}^2 + {u_mm:.3f}^2) = "
        f"{row['trans_uncert_mm']:.3f} mm in translation and sqrt({row['rot_rms_deg']:.3f}^2 + "
        f"{u_deg:.2f}^2) = {row['rot_uncert_deg']:.3f} deg in rotation.")


def by_fixture_table(rep: Report, by_group: dict, caption: str) -> None:
    """Per-group statistics (:func:`openemt.evaluate.uncertainty_summary` per group)."""
    rep.table([{"test rows": g, **{k: s[k] for k in ACCURACY_KEYS},
                "u_P_trans_mm": s["u_P_trans_mm"], "u_P_rot_deg": s["u_P_rot_deg"], "n": s["n"]}
               for g, s in by_group.items()], digits=5, caption=caption)


def breakdown_section(rep: Report, breakdowns: dict, noise_floor: dict | None) -> None:
    """Held-out error by range, stage rotation and sensor fixture
    (:func:`openemt.evaluate.error_breakdown` dicts, one row per group and calibration), with
    the repeat-pose noise floor (:func:`openemt.evaluate.repeat_scatter`) beside it."""
    from ..evaluate import ErrorBreakdown

    names = list(breakdowns)
    tables = {n: ErrorBreakdown(**breakdowns[n]).rows() for n in names}
    rows = [{"group": r["group"], "calibration": n, "n": r["n"],
             "trans_rms_mm": r["trans_rms_mm"], "rot_rms_deg": r["rot_rms_deg"]}
            for k in range(len(tables[names[0]])) for n in names
            for r in tables[n][k:k + 1]]
    rep.table(rows, digits=4, caption="Held-out errors by range from the source (r), stage "
              "rotation Rz and sensor fixture: where the error sits")
    if noise_floor and noise_floor.get("n_pairs"):
        rep.paragraph(
            f"Noise floor: {noise_floor['n_pairs']} md and ld rows measured at the same stage "
            f"pose and fixtures, solved with the same calibration, scatter by "
            f"{noise_floor['trans_rms_mm']:.4f} mm and {noise_floor['rot_rms_deg']:.4f} deg "
            "(per measurement). Model errors cancel in these differences: errors far above "
            "the floor are systematic (model or rig), not noise.", note=True)


def error_figures(rep: Report, M, D, trans, rot, shown, title: str) -> None:
    """Error-vector figure of the rows ``shown`` and the error histograms."""
    from ._figures import error_histogram_figure, error_vector_figure

    rep.figure(error_vector_figure(D[shown, :3, 3], M[shown, :3, 3] - D[shown, :3, 3],
                                   title=f"{title}: translation error across the workspace"),
               "Translation error vectors at the test positions (MacLachlan et al. 2025, Fig. 8 "
               "style); several Rz rotations per grid point.")
    rep.figure(error_histogram_figure(trans, rot, title=f"{title}: error distribution"),
               "Histogram of the error magnitudes.")


def _short_label(label: str) -> str:
    """``soYoutZup_seZinYup_sweep.dat`` -> ``seZinYup`` (else the label without ``.dat``)."""
    m = re.search(r"_(se[^_]+)_", label)
    return m.group(1) if m else label.removesuffix(".dat")


def sweep_section(rep: Report, analysis, paper=None, note: str = "") -> None:
    """Table IV style table of a :class:`~openemt.evaluate.SweepAnalysis` (and the paper's
    values) and the figure of every sweep curve."""
    from ._figures import sweep_figure

    t = analysis.table
    cols = ["row", "xyz_abs_rms", "xyz_abs_max", "rot_abs_rms", "rot_abs_max",
            "xyz_nonlin_rms", "xyz_nonlin_max", "rot_nonlin_rms", "rot_nonlin_max"]
    rows = []
    sources = [("ours", t)] + ([("paper", paper)] if paper else [])
    for label, src in sources:
        for row in ("direct", "cross"):
            d = {"row": f"{row} ({label})"}
            for k, v in src[row].items():
                d["_".join(k.split("_")[:3])] = v
            rows.append(d)
    rep.table(rows, cols, digits=4, caption=(
        "Direct: abs mm (xyz) / deg (rot), nonlinearity percent. Cross: abs deg (xyz motion) / "
        "mm (rot motion), nonlinearity deg/mm (xyz) / mm/deg (rot)."))
    if note:
        rep.paragraph(note, note=True)
    curves = {}
    for c in analysis.curves:
        unit = "deg" if c.is_rotation else "mm"
        other = "mm" if c.is_rotation else "deg"
        nl_unit = "mm/deg" if c.is_rotation else "deg/mm"
        kind = "rotation" if c.is_rotation else "translation"
        curves[f"{_short_label(c.label)} {c.axis}"] = {
            "position": c.motion, "position_unit": unit, "panels": {
                f"direct abs error, {kind} sweeps ({unit})": c.abs_direct,
                f"cross abs error, {kind} sweeps ({other})": c.abs_cross,
                f"direct nonlinearity, {kind} sweeps (%)": c.nonlin_direct,
                f"cross nonlinearity, {kind} sweeps ({nl_unit})": c.nonlin_cross}}
    if curves:
        rep.figure(sweep_figure(curves), "Absolute error and nonlinearity along each axis "
                   "sweep (MacLachlan et al. 2025, Fig. 10 style): one line per sweep file and "
                   "swept axis.")


def table3_section(rep: Report, t3, rows, columns) -> None:
    """Table III cells (a :class:`~openemt.paper.Table3Reproduction`) beside the paper's."""
    table = []
    for row in rows:
        for col in columns:
            c = t3.cells[row][col]
            p = c["paper"]
            table.append({"calibration data": row, "test data": col,
                          **{k: c[k] for k in ACCURACY_KEYS},
                          "paper trans rms / max": f"{p['trans_rms_mm']:.3f} / "
                                                   f"{p['trans_max_mm']:.3f}",
                          "paper rot rms / max": f"{p['rot_rms_deg']:.3f} / "
                                                 f"{p['rot_max_deg']:.3f}",
                          "n": c["n"], "n_invalid": c["n_invalid"]})
    rep.table(table, digits=3, caption="MacLachlan et al. 2025, Table III: calibration data "
                                       "versus test data (uncorrected; mm and degrees)")
    rep.paragraph(f"Largest deviation from the paper over all 36 numbers: "
                  f"{100 * t3.max_deviation:.2f} %.", note=True)


def characterization_document(c, parameters, title: str | None = None, *,
                              glossary: bool = True) -> Report:
    """The report of a :class:`~openemt.paper.CalibrationCharacterization`.

    ``parameters`` are the calibration's parameter rows
    (:func:`openemt.paper.parameter_rows`). With ``glossary`` the report ends with the
    definitions of its symbols (:func:`glossary_section`); a caller that adds sections
    passes False and adds the glossary last.
    """
    rep = Report(title or "openemt calibration and characterization report")
    rep.paragraph(f"Test data: {c.n_test} rows from {c.n_files} files/blocks; "
                  f"calibration mode {c.calibration.mode or '?'}; reference: "
                  + ("rig kinematics with the calibration's fixtures (stage-coordinates error)."
                     if c.reference == "kinematics" else "the dataset's reference poses.")
                  + " Every symbol is defined at the end (Symbols and terms).")
    rep.heading("Accuracy (MacLachlan et al. 2025, Table II style)")
    accuracy_section(rep, list(c.accuracy.values()), with_paper=False)
    uncertainty_paragraph(rep, c.accuracy[c.main])
    rep.heading("Per fixture combination and pattern (MacLachlan et al. 2025, Table III style)")
    by_fixture_table(rep, c.characterization.by_group,
                     f"{c.main}: errors per fixture combination with the combined uncertainty "
                     "u(P)")
    error_figures(rep, c.measured, c.reference_poses, c.trans, c.rot, c.shown, c.main)
    if c.sweeps is not None:
        rep.heading("Axis sweeps (MacLachlan et al. 2025, Table IV style)")
        sweep_section(rep, c.sweeps, note=c.sweep_note)
    rep.heading("Calibration parameters and standard errors")
    rep.table(parameters, digits=6, caption=_PARAMETER_CAPTION)
    if not c.calibration.standard_errors:
        rep.paragraph("This calibration carries no standard errors.", note=True)
    if glossary:
        glossary_section(rep)
    return rep


def paper_document(c, parameters, title: str | None = None) -> Report:
    """The report of a :class:`~openemt.paper.PaperCharacterization` (an ILEMT folder with the
    paper's tables); ``parameters`` are the main calibration's parameter rows
    (:func:`openemt.paper.parameter_rows`)."""
    from ..paper import TABLE3_COLUMNS, TABLE3_ROWS

    run, test = c.run, c.test
    ds = run.dataset
    rep = Report(title or f"openemt calibration and characterization report: {run.folder.name}")
    rep.paragraph(
        f"ILEMT folder {run.folder.name}: {len(ds)} rows in {len(ds.files)} files. The paper's "
        "calibration sequence (docs/paper-procedure.md#run-sequence) was run from "
        "base_calibration.mat; the main calibration is XYZ_hr_cal (dipole model, three sensor "
        f"fixtures, md data). Test data: {len(test)} rows (soYoutZup, three sensor fixtures, "
        "ld). Poses are solved with the iterative solver started from the Kim18 closed form of "
        "the concentric calibration and compared with the rig kinematics (stage-coordinates "
        "error). Every symbol is defined at the end (Symbols and terms).")
    rep.heading("Calibration sequence")
    rep.table(c.calibration_stats, digits=6, caption="Calibration residues (rms of the "
              "normalised coupling residual) and output-correction fits on the calibration rows")

    rep.heading("Accuracy (MacLachlan et al. 2025, Table II)")
    accuracy_section(rep, list(c.table2.values()), with_paper=True)
    rep.paragraph(f"Paper column: {c.table2_column.note}.", note=True)
    uncertainty_paragraph(rep, c.table2.get("corrected") or c.table2["default"])
    by_fixture_table(rep, c.characterization.by_group, "XYZ_hr_cal (uncorrected) per fixture "
                     "combination, with the combined uncertainty u(P)")
    if c.breakdown:
        breakdown_section(rep, c.breakdown, c.noise_floor)
    d = c.default
    error_figures(rep, d.poses, c.reference_poses, d.trans, d.rot, c.shown, "XYZ_hr_cal")

    rep.heading("Calibration versus test dimensionality (MacLachlan et al. 2025, Table III)")
    if c.table3 is not None:
        table3_section(rep, c.table3, TABLE3_ROWS, TABLE3_COLUMNS)
    else:
        rep.paragraph("This folder lacks the calibration or test data of Table III "
                      "(mdtrans/ldtrans files, source-fixture md/ld files).", note=True)

    t4 = c.table4
    if t4 is not None:
        rep.heading("Axis sweeps: cross-coupling and nonlinearity (MacLachlan et al. 2025, "
                    "Table IV)")
        sweep_section(rep, t4.analysis, t4.summary.paper, note=(
            f"XYZ_hr_cal {t4.summary.condition} on {', '.join(t4.summary.files)}; stage "
            "and sensor fixtures re-optimised in pose space (0.05 m moment). The paper's values "
            "come from another collection (cal_9_16, dipole-approximating source)."))
    else:
        rep.paragraph("No sweep files in this folder: Table IV is not reproduced.", note=True)

    rep.heading("Main calibration XYZ_hr_cal: parameters and standard errors")
    rep.table(parameters, digits=6, caption=_PARAMETER_CAPTION)
    rep.paragraph("Standard errors from the Jacobian of the calibration fit at the solution "
                  "(scaled by the residual variance). Fixed parameters (the gauge: Z-coil "
                  "positions and transverse moments; and what the mode holds: the Y component "
                  "of the X moments, the source Z gain, ...) have none.", note=True)
    glossary_section(rep)
    return rep


def simulation_section(rep: Report, *, description: str, setup: str, rows: dict,
                       parameters: list | None = None) -> None:
    """The simulated tracker: its description, the set-up, test errors of every calibration
    (``rows``: name -> accuracy row, with the ``reason`` of a failed or surprising one) and,
    if given, fitted parameters against the truth
    (:func:`openemt.paper.parameters_against_truth`)."""
    rep.heading("The simulation: truth, starting point, calibration")
    rep.paragraph(description)
    rep.paragraph(setup)
    table = [{"calibration": k, **v} for k, v in rows.items()]
    rep.table(table, ["calibration", *ACCURACY_KEYS, "trans_uncert_mm", "n_invalid"], digits=4,
              caption="Test errors of every calibration (rig kinematics with its own fixtures)")
    reason_notes(rep, table, "calibration")
    if parameters:
        rep.table(parameters, digits=6,
                  caption="Fitted parameters against the truth (the dipole equivalent of the "
                          "simulated finite coils and the simulator's fixtures). "
                          + _PARAMETER_CAPTION)
