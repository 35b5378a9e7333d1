"""Figures (matplotlib), the self-contained HTML report and its sections. Nothing numeric
imports this package; its functions lay out results computed elsewhere."""

from .._lazy import lazy_exports

#: where each public name lives; a module is imported on first use of one of its names (so
#: ``openemt info`` loads the summary of files, not the figures and tables behind the report)
_SOURCES = {
    "._built": ("BuiltReport", "characterization_report", "paper_report"),
    "._demo": ("DemoOptions", "DemoResult", "run_demo"),
    "._describe": ("FileInfo", "describe"),
    "._figures": ("error_histogram_figure", "error_map_figure", "error_vector_figure",
                  "pyplot", "sweep_figure"),
    "._glossary": ("GLOSSARY", "glossary_section"),
    "._html": ("Report", "figure_png"),
    "._navigation": ("assessment_document", "distance_error_figure"),
    "._planar": ("planar_document", "planar_report"),
    "._sections": ("accuracy_section", "by_fixture_table", "characterization_document",
                   "error_figures", "paper_document", "reason_notes", "simulation_section",
                   "sweep_section", "table3_section", "uncertainty_paragraph"),
    "._workflow": ("ReportOptions", "ReportResult", "write_report"),
}
__all__, __getattr__, __dir__ = lazy_exports(__name__, _SOURCES)
