"""The calibration-and-characterization report: one self-contained HTML file.

Two entry points build an :class:`openemt.report.Report` and a JSON-ready summary:

* :func:`paper_report` on an ILEMT folder: one import, one run of the paper's calibration
  sequence, then MacLachlan et al. 2025, Tables II, III and IV, error-vector and sweep figures (Figs. 8, 10),
  the main calibration's parameters with standard errors and the combined uncertainty (eq. 10);
* :func:`characterization_report` for any calibration on a test dataset with a reference (the
  rig kinematics from the calibration's fixtures, or the dataset's own ``poses``).
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass

import numpy as np

from .._errors import InputError
from ..calibrate._check import ILEMT_VALID_RESNORM
from ..evaluate import STAGE_UNCERTAINTY_M, STAGE_UNCERTAINTY_RAD, combined_uncertainty
from ._run import PaperRun, as_run, load_paper_run

__all__ = ["BuiltReport", "characterization_report", "paper_report", "parameter_rows"]

_KEYS = ("trans_rms_mm", "trans_max_mm", "rot_rms_deg", "rot_max_deg")
_U_MM = STAGE_UNCERTAINTY_M * 1e3
_U_DEG = float(np.rad2deg(STAGE_UNCERTAINTY_RAD))


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


def _corrected(P, L):
    """Poses with the output correction ``L`` applied to the positions."""
    from ..correct import apply_linear_correction

    out = np.array(P, dtype=np.float64)
    out[:, :3, 3] = apply_linear_correction(L, out[:, :3, 3])
    return out


def _accuracy_row(name, t, paper=None) -> dict:
    s = t["summary"]
    row = {"condition": name, **{k: s[k] for k in _KEYS}}
    row["trans_uncert_mm"] = float(combined_uncertainty(s["trans_rms_mm"], _U_MM))
    row["rot_uncert_deg"] = float(combined_uncertainty(s["rot_rms_deg"], _U_DEG))
    row["n"] = int(s["n"])
    row["n_invalid"] = int(t["n_invalid"])
    if paper is not None:
        row["paper"] = dict(paper)
    return row


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


def _accuracy_section(rep, rows, *, with_paper: bool):
    cols = ["condition", *_KEYS, "trans_uncert_mm", "rot_uncert_deg", "n", "n_invalid"]
    table = []
    for r in rows:
        table.append({c: r.get(c, "") for c in cols})
        if with_paper and r.get("paper"):
            table.append({"condition": "  paper", **r["paper"]})
    rep.table(table, cols, digits=5,
              caption="Translation (mm) and rotation (deg) error magnitudes, RMS and max")
    rep.paragraph(f"trans_uncert_mm = sqrt(RMS^2 + {_U_MM:.3f}^2) and rot_uncert_deg = "
                  f"sqrt(RMS^2 + {_U_DEG:.2f}^2) combine the calibration error u(cal) with the "
                  "stage uncertainty (MacLachlan et al. 2025, eq. 10). Invalid solutions (residue >= "
                  f"{ILEMT_VALID_RESNORM:g}) are "
                  "kept in the statistics and counted in n_invalid.", note=True)


def _uncertainty_paragraph(rep, row):
    rep.paragraph(
        f"Combined standard uncertainty of a measurement (MacLachlan et al. 2025, eq. 10) for "
        f"{row['condition']}: u(P) = sqrt({row['trans_rms_mm']:.3f}^2 + {_U_MM:.3f}^2) = "
        f"{row['trans_uncert_mm']:.3f} mm in translation and sqrt({row['rot_rms_deg']:.3f}^2 + "
        f"{_U_DEG:.2f}^2) = {row['rot_uncert_deg']:.3f} deg in rotation.")


def _figures(rep, M, D, trans, rot, shown, title):
    from ..report import error_histogram_figure, error_vector_figure

    rep.figure(error_vector_figure(D[shown, :3, 3], M[shown, :3, 3] - D[shown, :3, 3],
                                   title=f"{title}: translation error across the workspace"),
               "Translation error vectors at the test positions (MacLachlan et al. 2025, Fig. 8 style); "
               "several Rz rotations per grid point.")
    rep.figure(error_histogram_figure(trans, rot, title=f"{title}: error distribution"),
               "Histogram of the error magnitudes.")


def _short_label(label: str) -> str:
    """``soYoutZup_seZinYup_sweep.dat`` -> ``seZinYup`` (else the label without ``.dat``)."""
    m = re.search(r"_(se[^_]+)_", label)
    return m.group(1) if m else label.removesuffix(".dat")


def _sweep_section(rep, analysis, paper=None, note=""):
    from ..report import sweep_figure

    t = analysis.table
    cols = ["row", "xyz_abs_rms", "xyz_abs_max", "rot_abs_rms", "rot_abs_max",
            "xyz_nonlin_rms", "xyz_nonlin_max", "rot_nonlin_rms", "rot_nonlin_max"]
    rows = []
    sources = [("ours", t)] + ([("paper", paper)] if paper else [])
    for label, src in sources:
        for row in ("direct", "cross"):
            d = {"row": f"{row} ({label})"}
            for k, v in src[row].items():
                short = "_".join(k.split("_")[:3])
                d[short] = v
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
        name = f"{_short_label(c.label)} {c.axis}"
        curves[name] = {"position": c.motion, "position_unit": unit, "panels": {
            f"direct abs error, {kind} sweeps ({unit})": c.abs_direct,
            f"cross abs error, {kind} sweeps ({other})": c.abs_cross,
            f"direct nonlinearity, {kind} sweeps (%)": c.nonlin_direct,
            f"cross nonlinearity, {kind} sweeps ({nl_unit})": c.nonlin_cross}}
    if curves:
        rep.figure(sweep_figure(curves), "Absolute error and nonlinearity along each axis sweep "
                   "(MacLachlan et al. 2025, Fig. 10 style): one line per sweep file and swept axis.")


def _table3_section(rep, t3):
    from ._table3 import TABLE3_COLUMNS, TABLE3_ROWS

    rows = []
    for row in TABLE3_ROWS:
        for col in TABLE3_COLUMNS:
            c = t3[row][col]
            p = c["paper"]
            rows.append({"calibration data": row, "test data": col,
                         **{k: c[k] for k in _KEYS},
                         "paper trans rms / max": f"{p['trans_rms_mm']:.3f} / "
                                                  f"{p['trans_max_mm']:.3f}",
                         "paper rot rms / max": f"{p['rot_rms_deg']:.3f} / "
                                                f"{p['rot_max_deg']:.3f}",
                         "n": c["n"], "n_invalid": c["n_invalid"]})
    rep.table(rows, digits=3, caption="MacLachlan et al. 2025, Table III: calibration data versus test data "
                                      "(uncorrected; mm and degrees)")
    rep.paragraph(f"Largest deviation from the paper over all 36 numbers: "
                  f"{100 * t3['max_deviation']:.2f} %.", note=True)


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
    from ..report import Report
    from ._table2 import identify_table2_column, table2_tests
    from ._table3 import TABLE3_ROWS, reproduce_table3, table3_test_masks
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
    t2 = {k: _accuracy_row(labels[k], r, paper.get(k)) for k, r in results.items()}
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
    char = characterize(default["poses"], D, groups=fixture_labels(test),
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
    _accuracy_section(rep, list(t2.values()), with_paper=True)
    rep.paragraph(f"Paper column: {column.note}.", note=True)
    _uncertainty_paragraph(rep, t2.get("corrected") or t2["default"])
    by_fixture = [{"test rows": g, **{k: s[k] for k in _KEYS}, "u_P_trans_mm": s["u_P_trans_mm"],
                   "u_P_rot_deg": s["u_P_rot_deg"], "n": s["n"]}
                  for g, s in char.by_group.items()]
    rep.table(by_fixture, digits=5, caption="XYZ_hr_cal (uncorrected) per fixture combination, "
              "with the combined uncertainty u(P)")
    shown = np.flatnonzero(test.sensor_fixture == "YoutZup")
    _figures(rep, default["poses"], D, default["trans"], default["rot"], shown, "XYZ_hr_cal")

    rep.heading("Calibration versus test dimensionality (MacLachlan et al. 2025, Table III)")
    if t3 is not None:
        _table3_section(rep, t3)
    else:
        rep.paragraph("This folder lacks the calibration or test data of Table III "
                      "(mdtrans/ldtrans files, source-fixture md/ld files).", note=True)

    if t4 is not None:
        rep.heading("Axis sweeps: cross-coupling and nonlinearity (MacLachlan et al. 2025, Table IV)")
        _sweep_section(rep, t4.analysis, t4.summary["paper"], note=(
            f"XYZ_hr_cal {t4.summary['condition']} on {', '.join(t4.summary['files'])}; stage "
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
    t3s = None if t3 is None else {k: v for k, v in t3.items() if k != "seconds"}
    summary = {
        "mode": "ilemt", "folder": str(run.folder), "n_rows": len(ds), "n_test": len(test),
        "table2": t2, "table2_paper_column": column.to_dict(), "table3": t3s,
        "table4": None if t4 is None else {k: v for k, v in t4.summary.items()
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

    Parameters
    ----------
    dataset : Dataset
        Test rows (couplings with stage and fixture codes, or with ``poses``).
    calibration : Calibration
    concentric : Calibration, optional
        Concentric calibration whose Kim18 closed form starts the solver (ILEMT practice); it is
        also tested with Kim18 alone.
    reference : {'kinematics', 'poses'}
        Ground truth from the rig kinematics with the calibration's fixtures (the paper's
        procedure, stage-coordinates error) or the dataset's ``poses``.
    title : str, optional

    Returns
    -------
    BuiltReport
    """
    from ..calibrate import test_poses
    from ..evaluate import characterize, fixture_labels
    from ..geometry import ground_truth_poses
    from ..io import Calibration, Dataset
    from ..report import Report

    if not isinstance(dataset, Dataset):
        raise TypeError(f"expected an openemt.io.Dataset, got {type(dataset).__name__}")
    if not isinstance(calibration, Calibration):
        raise TypeError(f"expected a Calibration, got {type(calibration).__name__}")
    if concentric is not None and not isinstance(concentric, Calibration):
        raise TypeError(f"expected a concentric Calibration, got {type(concentric).__name__}")
    if reference not in ("kinematics", "poses"):
        raise InputError(f"expected reference 'kinematics' or 'poses', got {reference!r}")
    if reference == "poses" and dataset.poses is None:
        raise InputError("expected a dataset with reference `poses` for reference='poses', got "
                         "none")
    t_all = time.perf_counter()
    cal = calibration
    conc_model = None if concentric is None else concentric.model
    groups = fixture_labels(dataset)
    if len(np.unique(dataset.pattern)) > 1:
        groups = np.char.add(np.char.add(groups, " "), dataset.pattern.astype(str))
    if reference == "kinematics":
        D = ground_truth_poses(cal.source_fixture, cal.stage_fixture, cal.sensor_fixture,
                               dataset.source_fixture, dataset.stage, dataset.sensor_fixture)
        F_se = cal.sensor_fixture
        conds = {"calibration": test_poses(dataset, cal, concentric_model=conc_model)}
        conds["calibration"]["measured"] = conds["calibration"]["poses"]
        if cal.linear_correction is not None:
            r = test_poses(dataset, cal, concentric_model=conc_model, apply_correction=True)
            r["measured"] = _corrected(r["poses"], cal.linear_correction)
            conds["calibration + correction"] = r
        if concentric is not None:
            r = test_poses(dataset, concentric, solver="kim18")
            r["measured"] = r["poses"]
            conds["concentric + Kim18"] = r
    else:
        from ..evaluate import error_summary, pose_error_magnitudes
        from ..solve import hemisphere_from_positions, solve

        D = np.asarray(dataset.poses, dtype=np.float64)
        F_se = None
        hemi = hemisphere_from_positions(D[:, :3, 3])
        res = solve(dataset.signed_real(), cal, hemisphere=hemi, apply_correction=False,
                    concentric_calibration=concentric, retry_resnorm=ILEMT_VALID_RESNORM)
        variants = {"calibration": (res, res.poses)}
        if cal.linear_correction is not None:
            variants["calibration + correction"] = (res, _corrected(res.poses,
                                                                    cal.linear_correction))
        if concentric is not None:
            rk = solve(dataset.signed_real(), concentric, solver="kim18", hemisphere=hemi,
                       apply_correction=False)
            variants["concentric + Kim18"] = (rk, rk.poses)
        conds = {}
        for name, (r, M) in variants.items():
            trans, rot = pose_error_magnitudes(M, D)  # NaN for failed solves
            conds[name] = {"trans": trans, "rot": rot, "summary": error_summary(trans, rot),
                           "n_invalid": int((~(np.asarray(r.residual) < ILEMT_VALID_RESNORM)).sum()),
                           "poses": r.poses,
                           "measured": M}
    rows = [_accuracy_row(name, r) for name, r in conds.items()]
    main_name = "calibration + correction" if "calibration + correction" in conds else \
        "calibration"
    main = conds[main_name]
    char = characterize(main["measured"], D, groups=groups, sensor_fixture=F_se)

    rep = Report(title or "openemt calibration and characterization report")
    rep.paragraph(f"Test data: {len(dataset)} rows from {len(dataset.files)} files/blocks; "
                  f"calibration mode {cal.mode or '?'}; reference: "
                  + ("rig kinematics with the calibration's fixtures (stage-coordinates error)."
                     if reference == "kinematics" else "the dataset's reference poses."))
    rep.heading("Accuracy (MacLachlan et al. 2025, Table II style)")
    _accuracy_section(rep, rows, with_paper=False)
    _uncertainty_paragraph(rep, next(r for r in rows if r["condition"] == main_name))
    rep.heading("Per fixture combination and pattern (MacLachlan et al. 2025, Table III style)")
    rep.table([{"test rows": g, **{k: s[k] for k in _KEYS}, "u_P_trans_mm": s["u_P_trans_mm"],
                "u_P_rot_deg": s["u_P_rot_deg"], "n": s["n"]}
               for g, s in char.by_group.items()], digits=5,
              caption=f"{main_name}: errors per fixture combination with the combined "
                      "uncertainty u(P)")
    grid = dataset.pattern != "sweep"
    first = groups[np.flatnonzero(grid)[0]] if grid.any() else groups[0]
    shown = np.flatnonzero(groups == first)
    _figures(rep, main["measured"], D, main["trans"], main["rot"], shown, main_name)
    sweep_summary = None
    sweep_rows = dataset.mask(pattern="sweep")
    if sweep_rows.any():
        from ..evaluate import sweep_linearity

        sub = dataset.select(sweep_rows)
        M = main["measured"][sweep_rows]
        Ds = D[sweep_rows]
        stage = sub.stage_logged if sub.stage_logged is not None else sub.stage
        note = ""
        if reference == "kinematics":
            from ._table4 import refit_fixtures

            refit = refit_fixtures(M, sub, cal)
            rc = refit.calibration
            Ds = ground_truth_poses(rc.source_fixture, rc.stage_fixture, rc.sensor_fixture,
                                    sub.source_fixture, sub.stage, sub.sensor_fixture)
            F_sweep = rc.sensor_fixture
            note = "Stage and sensor fixtures re-optimised in pose space (0.05 m moment)."
        else:
            F_sweep = None
        a = sweep_linearity(M, Ds, stage, labels=sub.file_names(), sensor_fixture=F_sweep)
        if a.curves:
            rep.heading("Axis sweeps (MacLachlan et al. 2025, Table IV style)")
            _sweep_section(rep, a, note=note)
            sweep_summary = {"direct": a.table["direct"], "cross": a.table["cross"],
                             "n_curves": a.table["n_curves"]}
    rep.heading("Calibration parameters and standard errors")
    rep.table(parameter_rows(cal), digits=6)
    if not cal.standard_errors:
        rep.paragraph("This calibration carries no standard errors.", note=True)
    summary = {"mode": "dataset", "reference": reference, "n_test": len(dataset),
               "accuracy": {r["condition"]: r for r in rows}, "by_fixture": char.by_group,
               "table4": sweep_summary,
               "seconds": {"total": time.perf_counter() - t_all}}
    return BuiltReport(report=rep, summary=summary)
