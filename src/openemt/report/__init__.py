"""Figures (matplotlib), the self-contained HTML report and its sections. Nothing numeric
imports this package; its functions lay out results computed elsewhere."""

from ._built import BuiltReport, characterization_report, paper_report
from ._demo import DemoOptions, DemoResult, run_demo
from ._describe import FileInfo, describe
from ._figures import error_histogram_figure, error_map_figure, error_vector_figure, sweep_figure
from ._glossary import GLOSSARY, glossary_section
from ._html import Report, figure_png
from ._navigation import assessment_document, distance_error_figure
from ._planar import planar_document, planar_report
from ._sections import (
    accuracy_section,
    by_fixture_table,
    characterization_document,
    error_figures,
    paper_document,
    reason_notes,
    simulation_section,
    sweep_section,
    table3_section,
    uncertainty_paragraph,
)
from ._workflow import ReportOptions, ReportResult, write_report

__all__ = [
    "GLOSSARY",
    "BuiltReport",
    "DemoOptions",
    "DemoResult",
    "FileInfo",
    "Report",
    "ReportOptions",
    "ReportResult",
    "accuracy_section",
    "assessment_document",
    "by_fixture_table",
    "characterization_report",
    "characterization_document",
    "describe",
    "distance_error_figure",
    "error_figures",
    "error_histogram_figure",
    "error_map_figure",
    "error_vector_figure",
    "figure_png",
    "glossary_section",
    "paper_document",
    "paper_report",
    "planar_document",
    "planar_report",
    "reason_notes",
    "run_demo",
    "simulation_section",
    "sweep_figure",
    "sweep_section",
    "table3_section",
    "uncertainty_paragraph",
    "write_report",
]
