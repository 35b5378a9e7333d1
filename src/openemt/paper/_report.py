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

from ._characterization import characterize_calibration, characterize_paper_run

__all__ = ["BuiltReport", "characterization_report", "coil_name", "paper_report", "parameter_rows"]


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


def coil_name(c: int, n: int) -> str:
    """The one name of coil ``c`` of ``n`` in every report table: X, Y, Z for a tri-axial set
    (the columns of docs/ilemt-data.md#dipole-model), else the column index."""
    return "XYZ"[c] if n == 3 else str(c)


def _parameter_status(cal, layout) -> np.ndarray:
    """Per entry of the full parameter vector: ``fitted``, ``fixed (gauge)`` or ``fixed``
    (not fitted in the calibration's mode); ``""`` where the calibration does not say."""
    status = np.full(layout.size, "", dtype=object)
    free = None
    if cal.free:
        try:
            free = layout.free_indices(cal.free, cal.frozen)
        except ValueError:      # groups of another layout (e.g. a reference calibration)
            free = None
    se = cal.standard_errors or {}
    if free is None and se:     # a fit leaves 0 for what it held and > 0 for what it fitted
        full = np.concatenate([np.asarray(se[k], dtype=np.float64).T.ravel()
                               for k in ("L_so", "M_so", "L_se", "M_se") if k in se]
                              + [np.asarray(se[k], dtype=np.float64).ravel()
                                 for k in ("source_fixture", "stage_fixture", "sensor_fixture")
                                 if k in se])
        if full.size == layout.size:
            free = np.flatnonzero(full != 0.0)
    if free is not None:
        status[:] = "fixed"
        status[free] = "fitted"
    status[layout.gauge] = "fixed (gauge)"
    return status


def parameter_rows(cal, truth=None) -> list:
    """Rows (``parameter``, ``unit``, ``value``, ``std_error``, ``status`` and, with ``truth``,
    ``truth``) of a calibration's model and fixtures, as every report shows them.

    One naming (``L_so[x, coil X]``, ``F_st.rx``; :func:`coil_name`) and one unit per
    quantity: coil positions and fixture translations in mm, fixture rotation vectors in
    degrees, moments in gain units. ``status`` is ``fitted``, ``fixed`` (held in the
    calibration's mode) or ``fixed (gauge)`` (docs/ilemt-data.md#dipole-model); fixed
    parameters have no standard error (NaN). Standard errors come from
    ``cal.standard_errors`` (NaN if absent).
    """
    from ..calibrate._layout import ParameterLayout

    se = cal.standard_errors or {}
    layout = ParameterLayout.for_model(cal.model)
    status = _parameter_status(cal, layout)
    rows = []

    def add(name, unit, value, err, st, true):
        row = {"parameter": name, "unit": unit, "value": value,
               "std_error": err if st not in ("fixed", "fixed (gauge)") else float("nan"),
               "status": st}
        if truth is not None:
            row["truth"] = true
        rows.append(row)

    for name, unit, scale in (("L_so", "mm", 1e3), ("M_so", "gain", 1.0),
                              ("L_se", "mm", 1e3), ("M_se", "gain", 1.0)):
        val = np.asarray(getattr(cal.model, name))
        err = se.get(name)
        err = None if err is None else np.asarray(err)
        tv = None if truth is None else np.asarray(getattr(truth.model, name))
        n, s0 = val.shape[1], layout.slices[name].start
        for c in range(n):
            for a in range(3):
                add(f"{name}[{'xyz'[a]}, coil {coil_name(c, n)}]", unit, float(val[a, c]) * scale,
                    float(err[a, c]) * scale if err is not None else float("nan"),
                    status[s0 + 3 * c + a], None if tv is None else float(tv[a, c]) * scale)
    for name, attr in (("F_so", "source_fixture"), ("F_st", "stage_fixture"),
                       ("F_se", "sensor_fixture")):
        val = np.asarray(getattr(cal, attr))
        err = se.get(attr)
        err = None if err is None else np.asarray(err)
        tv = None if truth is None else np.asarray(getattr(truth, attr))
        s0 = layout.slices[name].start
        for i, comp in enumerate(("x", "y", "z", "rx", "ry", "rz")):
            unit, scale = ("mm", 1e3) if i < 3 else ("deg", float(np.rad2deg(1.0)))
            add(f"{name}.{comp}", unit, float(val[i]) * scale,
                float(err[i]) * scale if err is not None else float("nan"), status[s0 + i],
                None if tv is None else float(tv[i]) * scale)
    return rows


def paper_report(source, *, title: str | None = None) -> BuiltReport:
    """The full report for an ILEMT folder (or a :class:`PaperRun` with the whole sequence).

    The numbers are :func:`~openemt.paper.characterize_paper_run`; the document is
    :func:`openemt.report.paper_document`.

    Parameters
    ----------
    source : path-like or PaperRun
    title : str, optional

    Returns
    -------
    BuiltReport
        ``summary`` is the characterization's ``to_dict()``: ``table2`` (rows
        default/corrected/concentric with combined uncertainties and the paper's values),
        ``table3``, ``table4`` (None without sweep files), ``calibration_stats``, ``seconds``.
    """
    from ..report import paper_document

    t_all = time.perf_counter()
    c = characterize_paper_run(source)
    t0 = time.perf_counter()
    rep = paper_document(c, parameter_rows(c.run.calibration("XYZ")), title)
    c.seconds["report"] = time.perf_counter() - t0
    c.seconds["total"] = time.perf_counter() - t_all
    return BuiltReport(report=rep, summary=c.to_dict())


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
