"""Figures (matplotlib), the self-contained HTML report and its sections. Nothing numeric
imports this package; its functions lay out results computed elsewhere."""

from ._figures import error_histogram_figure, error_map_figure, error_vector_figure, sweep_figure
from ._html import Report, figure_png
from ._navigation import assessment_document, distance_error_figure
from ._planar import planar_document, planar_report
from ._sections import (
    accuracy_section,
    by_fixture_table,
    characterization_document,
    error_figures,
    paper_document,
    simulation_section,
    sweep_section,
    table3_section,
    uncertainty_paragraph,
)

__all__ = [
    "Report",
    "accuracy_section",
    "assessment_document",
    "by_fixture_table",
    "characterization_document",
    "distance_error_figure",
    "error_figures",
    "error_histogram_figure",
    "error_map_figure",
    "error_vector_figure",
    "figure_png",
    "paper_document",
    "planar_document",
    "planar_report",
    "simulation_section",
    "sweep_figure",
    "sweep_section",
    "table3_section",
    "uncertainty_paragraph",
]
