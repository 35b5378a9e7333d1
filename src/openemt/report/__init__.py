"""Figures (matplotlib), the self-contained HTML report and its sections. Nothing numeric
imports this package; its functions lay out results computed elsewhere."""

import importlib

#: where each public name lives; a module is imported on first use of one of its names (so
#: ``openemt info`` loads the summary of files, not the figures and tables behind the report)
_SOURCES = {
    "_built": ("BuiltReport", "characterization_report", "paper_report"),
    "_demo": ("DemoOptions", "DemoResult", "run_demo"),
    "_describe": ("FileInfo", "describe"),
    "_figures": ("error_histogram_figure", "error_map_figure", "error_vector_figure",
                 "sweep_figure"),
    "_glossary": ("GLOSSARY", "glossary_section"),
    "_html": ("Report", "figure_png"),
    "_navigation": ("assessment_document", "distance_error_figure"),
    "_planar": ("planar_document", "planar_report"),
    "_sections": ("accuracy_section", "by_fixture_table", "characterization_document",
                  "error_figures", "paper_document", "reason_notes", "simulation_section",
                  "sweep_section", "table3_section", "uncertainty_paragraph"),
    "_workflow": ("ReportOptions", "ReportResult", "write_report"),
}
_MODULE = {name: module for module, names in _SOURCES.items() for name in names}

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


def __getattr__(name):
    module = _MODULE.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
