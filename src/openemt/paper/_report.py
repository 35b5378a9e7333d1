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
