"""The calibration-and-characterization report: one self-contained HTML file.

Two entry points build an :class:`openemt.report.Report` and a JSON-ready summary:

* :func:`paper_report` on an ILEMT folder: one import, one run of the paper's calibration
  sequence, then MacLachlan et al. 2025, Tables II, III and IV, error-vector and sweep figures (Figs. 8, 10),
  the main calibration's parameters with standard errors and the combined uncertainty (eq. 10);
* :func:`characterization_report` for any calibration on a test dataset with a reference (the
  rig kinematics from the calibration's fixtures, or the dataset's own ``poses``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ._characterization import accuracy_row, characterize_calibration
from ._run import PaperRun, as_run, load_paper_run

__all__ = ["BuiltReport", "characterization_report", "paper_report", "parameter_rows"]


@dataclass(frozen=True, eq=False)
class BuiltReport:
    """A report ready to write and its JSON-ready summary.

    Attributes
    ----------
    report : openemt.report.Report
    summary : dict
    """

    report: object
    summary: dict

    def write(self, path) -> dict:
        """Write the HTML (atomically) and return the summary with ``report`` = the path."""
        self.report.write(path)
        return {**self.summary, "report": str(path), "n_figures": self.report.n_figures}


def parameter_rows(cal) -> list:
    """Rows of (parameter, value, standard error) for a calibration's model and fixtures.

    Coil positions and fixture translations are reported in mm, rotation vectors in degrees,
    moments in gain units. Standard errors come from ``cal.standard_errors`` (blank if absent).
    """
    se = cal.standard_errors or {}
    rows = []
    model = cal.model
    for name, unit, scale in (("L_so", "mm", 1e3), ("M_so", "gain", 1.0),
                              ("L_se", "mm", 1e3), ("M_se", "gain", 1.0)):
        val = np.asarray(getattr(model, name))
        err = se.get(name)
        err = None if err is None else np.asarray(err)
        for c in range(val.shape[1]):
            for a in range(3):
                e = float(err[a, c]) * scale if err is not None else float("nan")
                rows.append({"parameter": f"{name}[{'xyz'[a]}, coil {'XYZ'[c] if c < 3 else c}]",
                             "unit": unit, "value": float(val[a, c]) * scale, "std_error": e})
    for name, attr in (("F_so", "source_fixture"), ("F_st", "stage_fixture"),
                       ("F_se", "sensor_fixture")):
        val = np.asarray(getattr(cal, attr))
        err = se.get(name)
        err = None if err is None else np.asarray(err)
        for i, comp in enumerate(("x", "y", "z", "rx", "ry", "rz")):
            unit, scale = ("mm", 1e3) if i < 3 else ("deg", float(np.rad2deg(1.0)))
            e = float(err[i]) * scale if err is not None else float("nan")
            rows.append({"parameter": f"{name}.{comp}", "unit": unit,
                         "value": float(val[i]) * scale, "std_error": e})
    return rows


def paper_report(source, *, title: str | None = None) -> BuiltReport:
    """The full report for an ILEMT folder (or a :class:`PaperRun` with the whole sequence).

    Parameters
    ----------
    source : path-like or PaperRun
    title : str, optional

    Returns
    -------
    BuiltReport
        ``summary`` holds ``table2`` (rows default/corrected/concentric with combined
        uncertainties and the paper's values), ``table3``, ``table4`` (None without sweep
        files), ``calibration_stats`` and ``seconds``.
    """
    from ..evaluate import characterize, fixture_labels
    from ..geometry import ground_truth_poses
    from ..report import (
        Report,
        accuracy_section,
        by_fixture_table,
        error_figures,
        sweep_section,
        table3_section,
        uncertainty_paragraph,
    )
    from ._table2 import identify_table2_column, table2_tests
    from ._table3 import TABLE3_COLUMNS, TABLE3_ROWS, reproduce_table3, table3_test_masks
    from ._table4 import sweep_test

    t_all = time.perf_counter()
    run = source if isinstance(source, PaperRun) else load_paper_run(source)
    as_run(run, ["XYZ", "XYZ_concentric"])  # the least a report needs
    ds = run.dataset
    seconds = dict(run.seconds)
    xyz = run.calibration("XYZ")
    t0 = time.perf_counter()
    test, results, _ = table2_tests(run)
    default = results["default"]
    labels = {"default": "default (XYZ_hr_cal)", "corrected": "corrected (XYZ_hr_cal + DLT)",
              "concentric": "concentric + Kim18"}
    column = identify_table2_column(run, test)
    paper = column.values or {}
    t2 = {k: accuracy_row(labels[k], r, paper.get(k)) for k, r in results.items()}
    seconds["table2"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    masks = table3_test_masks(ds)
    t3 = reproduce_table3(run) if (run.has(*TABLE3_ROWS.values())
                                   and all(m.any() for m in masks.values())) else None
    seconds["table3"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    has_sweeps = bool(ds.mask(pattern="sweep", source_fixture="YoutZup").any())
    t4 = sweep_test(run) if has_sweeps else None
    seconds["table4"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    D = ground_truth_poses(xyz.source_fixture, xyz.stage_fixture, xyz.sensor_fixture,
                           test.source_fixture, test.stage, test.sensor_fixture)
    char = characterize(default.poses, D, groups=fixture_labels(test),
                        sensor_fixture=xyz.sensor_fixture)
    rep = Report(title or f"openemt calibration and characterization report: {run.folder.name}")
    rep.paragraph(
        f"ILEMT folder {run.folder.name}: {len(ds)} rows in {len(ds.files)} files. The paper's "
        "calibration sequence (docs/paper-procedure.md#run-sequence) was run from base_calibration.mat; the main "
        "calibration is XYZ_hr_cal (dipole model, three sensor fixtures, md data). Test "
        f"data: {len(test)} rows (soYoutZup, three sensor fixtures, ld). Poses are solved with "
        "the iterative solver started from the Kim18 closed form of the concentric calibration "
        "and compared with the rig kinematics (stage-coordinates error).")
    rep.heading("Calibration sequence")
    stats_rows = []
    for name, f in run.fits.items():
        s = f.calibration.stats
        stats_rows.append({"calibration": f"{name}_hr_cal", "mode": f.calibration.mode,
                           "rms_residue": s.get("rms_residue"), "rows": s.get("num_points"),
                           "invalid": s.get("num_invalid", ""),
                           "uncorrected_mm": 1e3 * s["uncorrected"] if s.get("uncorrected")
                           is not None else float("nan"),
                           "corrected_mm": 1e3 * s["corrected"] if s.get("corrected")
                           is not None else float("nan")})
    rep.table(stats_rows, digits=6, caption="Calibration residues (rms of the normalised "
              "coupling residual) and output-correction fits on the calibration rows")

    rep.heading("Accuracy (MacLachlan et al. 2025, Table II)")
    accuracy_section(rep, list(t2.values()), with_paper=True)
    rep.paragraph(f"Paper column: {column.note}.", note=True)
    uncertainty_paragraph(rep, t2.get("corrected") or t2["default"])
    by_fixture_table(rep, char.by_group, "XYZ_hr_cal (uncorrected) per fixture combination, "
                     "with the combined uncertainty u(P)")
    shown = np.flatnonzero(test.sensor_fixture == "YoutZup")
    error_figures(rep, default.poses, D, default.trans, default.rot, shown, "XYZ_hr_cal")

    rep.heading("Calibration versus test dimensionality (MacLachlan et al. 2025, Table III)")
    if t3 is not None:
        table3_section(rep, t3, TABLE3_ROWS, TABLE3_COLUMNS)
    else:
        rep.paragraph("This folder lacks the calibration or test data of Table III "
                      "(mdtrans/ldtrans files, source-fixture md/ld files).", note=True)

    if t4 is not None:
        rep.heading("Axis sweeps: cross-coupling and nonlinearity (MacLachlan et al. 2025, Table IV)")
        sweep_section(rep, t4.analysis, t4.summary.paper, note=(
            f"XYZ_hr_cal {t4.summary.condition} on {', '.join(t4.summary.files)}; stage "
            "and sensor fixtures re-optimised in pose space (0.05 m moment). The paper's values "
            "come from another collection (cal_9_16, dipole-approximating source)."))
    else:
        rep.paragraph("No sweep files in this folder: Table IV is not reproduced.", note=True)

    rep.heading("Main calibration XYZ_hr_cal: parameters and standard errors")
    rep.table(parameter_rows(xyz), digits=6)
    rep.paragraph("Standard errors from the Jacobian of the calibration fit at the solution "
                  "(scaled by the residual variance). Gauge-fixed parameters (Z-coil positions, "
                  "source Z gain, Y component of the X moments) have none.", note=True)
    seconds["report"] = time.perf_counter() - t0
    seconds["total"] = time.perf_counter() - t_all
    t3s = None if t3 is None else {k: v for k, v in t3.to_dict().items() if k != "seconds"}
    summary = {
        "mode": "ilemt", "folder": str(run.folder), "n_rows": len(ds), "n_test": len(test),
        "table2": t2, "table2_paper_column": column.to_dict(), "table3": t3s,
        "table4": None if t4 is None else {k: v for k, v in t4.summary.to_dict().items()
                                           if k not in ("curves", "seconds")},
        "by_fixture": char.by_group,
        "calibration_stats": {r["calibration"]: r for r in stats_rows},
        "seconds": seconds,
    }
    return BuiltReport(report=rep, summary=summary)


def characterization_report(dataset, calibration, *, concentric=None,
                            reference: str = "kinematics", title: str | None = None
                            ) -> BuiltReport:
    """Report of one calibration tested on a dataset with a reference.

    The numbers are :func:`~openemt.paper.characterize_calibration` (same parameters); the
    document is :func:`openemt.report.characterization_document`.

    Returns
    -------
    BuiltReport
        ``summary`` is the characterization's ``to_dict()``.
    """
    from ..report import characterization_document

    t_all = time.perf_counter()
    c = characterize_calibration(dataset, calibration, concentric=concentric,
                                 reference=reference)
    rep = characterization_document(c, parameter_rows(c.calibration), title)
    summary = c.to_dict()
    summary["seconds"] = {"total": time.perf_counter() - t_all}
    return BuiltReport(report=rep, summary=summary)
