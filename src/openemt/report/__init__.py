"""Figures (matplotlib) and the self-contained HTML report. Nothing numeric imports this package."""

from ._figures import error_histogram_figure, error_vector_figure, sweep_figure
from ._html import Report, figure_png

__all__ = ["Report", "error_histogram_figure", "error_vector_figure", "figure_png", "sweep_figure"]
