"""The calibration-and-characterization report: one self-contained HTML file.

Two entry points build a :class:`~openemt.report.Report` and a JSON-ready summary:

* :func:`paper_report` on an ILEMT folder: one import, one run of the paper's calibration
  sequence, then MacLachlan et al. 2025, Tables II, III and IV, error-vector and sweep figures
  (Figs. 8, 10), the main calibration's parameters with standard errors and the combined
  uncertainty (eq. 10);
* :func:`characterization_report` for any calibration on a test dataset with a reference (the
  rig kinematics from the calibration's fixtures, or the dataset's own ``poses``).

The numbers come from :mod:`openemt.paper`; this module only lays them out.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from ..paper import characterize_calibration, characterize_paper_run, parameter_rows
from ._sections import characterization_document, paper_document

__all__ = ["BuiltReport", "characterization_report", "paper_report"]


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
    t_all = time.perf_counter()
    c = characterize_calibration(dataset, calibration, concentric=concentric,
                                 reference=reference)
    rep = characterization_document(c, parameter_rows(c.calibration), title)
    summary = c.to_dict()
    summary["seconds"] = {"total": time.perf_counter() - t_all}
    return BuiltReport(report=rep, summary=summary)
