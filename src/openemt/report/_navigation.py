"""The HTML report of a grid accuracy assessment (``openemt assess -o report.html``)."""

from __future__ import annotations

import numpy as np

from ._figures import error_vector_figure, pyplot
from ._html import Report

__all__ = ["assessment_document", "distance_error_figure"]


def distance_error_figure(nominal_distance, distance_error, classes=(), tolerance: float = 0.0):
    """Measured minus nominal distance (mm) against the nominal distance (mm) of every point
    pair; the pairs of the distance ``classes`` (m, within ``tolerance``) highlighted."""
    plt = pyplot()
    dn = 1e3 * np.asarray(nominal_distance, dtype=float)
    e = 1e3 * np.asarray(distance_error, dtype=float)
    fig, ax = plt.subplots(figsize=(7.5, 4.2))
    ax.scatter(dn, e, s=6, c="0.6", label="all pairs")
    for c in classes:
        sel = np.abs(dn - 1e3 * c) <= 1e3 * tolerance
        if sel.any():
            ax.scatter(dn[sel], e[sel], s=10, label=f"{1e3 * c:g} mm class")
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set_xlabel("nominal distance (mm)")
    ax.set_ylabel("distance error (mm)")
    ax.set_title("Errors of the distances between grid points")
    ax.legend(fontsize=8)
    return fig


def assessment_document(result, *, measured: str = "", nominal: str = "",
                        title: str | None = None) -> Report:
    """Report of a :class:`openemt.navigate.GridAssessment`: the summary tables, the rigid-fit
    residual vectors and the distance errors."""
    from ..navigate import DISTANCE_CLASSES_MM

    d = result.to_dict()
    rep = Report(title or "openemt grid accuracy assessment")
    rep.paragraph(f"Measured {measured or 'points'} ({d['n']} points from {d['n_rows']} rows, "
                  f"{d['match']} match) against nominal {nominal or 'positions'}. Protocol of "
                  "Hummel et al. 2005: rigid fit to the nominal grid, errors of the distances "
                  "between grid points, jitter of repeated samples (docs/navigation.md#assess).")
    rep.heading("Rigid fit")
    rep.table([{"statistic": "residual (mm)", "RMS": d["rigid_rms_mm"],
                "mean": d["rigid_mean_mm"], "max": d["rigid_max_mm"]}],
              caption="Distance of each rigidly fitted measured point from its nominal point")
    rep.figure(error_vector_figure(result.nominal, result.residuals,
                                   title="Rigid-fit residuals at the grid points"),
               "Residual vectors of the rigid fit at the nominal grid points (exaggerated).")
    rep.heading("Distance errors")
    rows = [{"pairs": "all", "n": d["n_distances"], "mean |e| (mm)": d["distance_error_mean_mm"],
             "RMS (mm)": d["distance_error_rms_mm"], "bias (mm)": d["distance_error_bias_mm"],
             "max |e| (mm)": d["distance_error_max_mm"]}]
    for c, s in d["distance_classes"].items():
        rows.append({"pairs": f"{c} mm", "n": s["n"], "mean |e| (mm)": s["mean_mm"],
                     "RMS (mm)": s["rms_mm"], "bias (mm)": s["bias_mm"],
                     "max |e| (mm)": s["max_mm"]})
    rep.table(rows, caption=f"Measured minus nominal distance of point pairs; classes within "
                            f"{d['distance_class_tolerance_mm']:g} mm of the nominal distance")
    rep.figure(distance_error_figure(result.nominal_distance, result.distance_error,
                                     [1e-3 * c for c in DISTANCE_CLASSES_MM],
                                     result.class_tolerance),
               "Distance error of every pair of grid points against its nominal distance.")
    if d["jitter"] or "rotation_error_rms_deg" in d:
        rep.heading("Jitter and rotation")
        rows = []
        if d["jitter"]:
            j = d["jitter"]
            rows.append({"quantity": "jitter, position (mm)", "RMS": j["jitter_trans_rms_mm"],
                         "max": j["jitter_trans_max_mm"]})
            if "jitter_rot_rms_deg" in j:
                rows.append({"quantity": "jitter, rotation (deg)",
                             "RMS": j["jitter_rot_rms_deg"], "max": j["jitter_rot_max_deg"]})
        if "rotation_error_rms_deg" in d:
            rows.append({"quantity": "rotation from the mean orientation (deg)",
                         "RMS": d["rotation_error_rms_deg"], "max": d["rotation_error_max_deg"]})
        rep.table(rows)
    return rep
