"""The report of a finite-coil (board) calibration on grid data (docs/planar.md#reports).

The numbers are those of the planar calibration's accuracy blocks
(:func:`openemt.calibrate._planar.planar_errors`: every grid point solved from its couplings
alone with the 5-DOF solver, cold, and compared with its known position and axis); this module
lays them out with the calibration's fitted parameters and a per-point error map.
"""

from __future__ import annotations

import time

import numpy as np

from ._glossary import PLANAR_GLOSSARY, glossary_section
from ._html import Report

__all__ = ["planar_document", "planar_report"]

#: The accuracy keys shared with ``openemt calibrate --mode planar --json``.
_KEYS = ("n", "n_failed", "position_rms_mm", "position_max_mm", "axis_rms_deg")


def _pm(value: float, se: float, digits: int) -> str:
    """``value ± se`` (the standard error left out when unknown; "fixed" when it is 0, a
    parameter the fit kept, e.g. tilts without ``--tilt``)."""
    if not np.isfinite(se):
        return f"{value:.{digits}f}"
    return f"{value:.{digits}f} (fixed)" if se == 0 else f"{value:.{digits}f} ± {se:.2g}"


def _parameter_rows(cal) -> list:
    """Rows of (coil, gain, offsets in mm, tilts in deg), each value ± its standard error."""
    m, se = cal.model, cal.standard_errors or {}
    nan = np.full((m.n_coils, 3), np.nan)
    g_se = np.asarray(se.get("gains", np.full(m.n_coils, np.nan)), dtype=float)
    o_se = np.asarray(se.get("offsets", nan), dtype=float) * 1e3
    t_se = np.degrees(np.asarray(se.get("tilts", nan), dtype=float))
    rows = []
    for i, c in enumerate(m.board.coils):
        row = {"coil": c.name, "gain": _pm(float(m.gains[i]), float(g_se[i]), 5)}
        for a, ax in enumerate("xyz"):
            row[f"offset {ax} (mm)"] = _pm(float(m.offsets[i, a] * 1e3), float(o_se[i, a]), 4)
        for a, ax in enumerate("xyz"):
            row[f"tilt {ax} (deg)"] = _pm(float(np.degrees(m.tilts[i, a])), float(t_se[i, a]),
                                          4)
        rows.append(row)
    return rows


def planar_document(summary: dict, errors, points, cal, title: str | None = None) -> Report:
    """The HTML report: accuracy blocks of ``summary`` (``accuracy`` and, with a hold-out
    scheme, ``insample`` / ``holdout``), status counts, per-coil residuals, the error map of
    ``errors`` (:class:`~openemt.calibrate._planar.PlanarErrors`) at ``points`` and the
    calibration's parameters with standard errors."""
    from ._figures import error_map_figure

    m = cal.model
    rep = Report(title or f"openemt board calibration report: {m.board.name}")
    rep.paragraph(f"Board {m.board.name!r} ({m.n_coils} source coils, single-coil sensor "
                  f"{m.sensor_length * 1e3:g} mm long); test data: {summary['n_points']} grid "
                  f"points with known positions and sensor axes ({summary['dataset']}). Every "
                  "point is solved from its couplings alone with the 5-DOF solver from a cold "
                  "start and compared with its known pose, as the accuracy blocks of the planar "
                  "calibration do (docs/planar.md#accuracy).")
    rep.heading("Accuracy")
    blocks = [("all points", summary["accuracy"])]
    short = ["all points"]
    if "holdout" in summary:
        blocks += [(f"in-sample ({summary['holdout']['scheme']} fit points)",
                    summary["insample"]),
                   (f"held out ({summary['holdout']['scheme']})", summary["holdout"])]
        short += ["in-sample", "held out"]
    rep.table([{"points": name, **{k: b[k] for k in _KEYS}} for name, b in blocks],
              ["points", *_KEYS], digits=4,
              caption="Position error (mm) and sensor-axis error (deg) of the converged points")
    counts = summary["status_counts"]
    rep.table([{"status": k, "samples": v} for k, v in counts.items() if v],
              caption="Solver status of the grid points")
    rep.heading("Coil residuals")
    rep.table([{"coil": c.name, **{f"residual, {k} (%)": b["coil_residual_percent"][i]
                                   for k, (_, b) in zip(short, blocks)}}
               for i, c in enumerate(m.board.coils)], digits=4,
              caption="RMS of measured minus model coupling at the known poses, percent of the "
                      "coil's peak coupling on these points")
    rep.heading("Error map")
    rep.figure(error_map_figure(points, errors.error_vectors, failed=~errors.converged,
                                title=f"{m.board.name}: position error per grid point"),
               "Grid points seen from above the board, coloured by the position error of their "
               "5-DOF solution; arrows are the in-plane part of the error; crosses mark points "
               "without a converged solution.")
    rep.heading("Calibration parameters and standard errors")
    rep.table(_parameter_rows(cal), digits=5,
              caption="Per-coil gain, position offset (mm) and tilt (rotation vector, deg), each "
                      "± its standard error (Gauss-Newton covariance of the fit)")
    st = cal.stats or {}
    if st:
        rep.paragraph(f"Fit: status {st.get('status', '?')}, {st.get('iterations', '?')} "
                      f"iterations on {st.get('n_points', '?')} points, condition "
                      f"{st.get('condition', float('nan')):.3g}.", note=True)
    if not cal.standard_errors:
        rep.paragraph("This calibration carries no standard errors.", note=True)
    glossary_section(rep, terms=(), glossary=PLANAR_GLOSSARY)
    return rep


def planar_report(data, cal, *, holdout: str | None = None, dataset: str = "",
                  title: str | None = None):
    """Report of a finite-coil calibration ``cal`` on grid data ``data``
    (:class:`~openemt.calibrate.GridData`).

    ``holdout="checkerboard"`` also scores the grid's two checkerboard halves as
    ``openemt calibrate --mode planar --holdout checkerboard`` does (``insample``: the fit
    points, ``holdout``: the others); on the grid a calibration was fitted to, these blocks
    equal the calibration's.

    Returns
    -------
    openemt.report.BuiltReport
        ``summary``: ``mode = "planar"``, ``board``, ``dataset``, ``n_points``, ``accuracy``
        (all points), ``insample`` / ``holdout`` (with ``holdout``), ``status_counts``,
        ``gains``, ``gains_se``, ``offsets_mm``, ``offsets_se_mm``, ``tilts_deg``,
        ``tilts_se_deg``, ``seconds``.
    """
    from .._errors import InputError
    from ..calibrate._planar import check_grid_units, planar_errors
    from ..calibrate._split import checkerboard_split
    from ._built import BuiltReport

    t0 = time.perf_counter()
    if holdout not in (None, "checkerboard"):
        raise InputError(f"expected --holdout checkerboard for a board calibration, got "
                         f"{holdout!r}")
    m = cal.model
    check_grid_units(data)
    errors = planar_errors(cal.coupling_model, data)     # with its environment terms, if any
    summary = {"mode": "planar", "board": m.board.name, "dataset": dataset,
               "n_points": len(data.points), "accuracy": errors.summary()}
    if holdout:
        black = checkerboard_split(data.points)
        summary["insample"] = errors.subset(black).summary()
        summary["holdout"] = dict(errors.subset(~black).summary(), scheme=holdout)
    summary["status_counts"] = errors.result.status_counts()
    se = cal.standard_errors or {}
    nan3 = np.full((m.n_coils, 3), np.nan)
    summary.update(
        gains=m.gains.tolist(),
        gains_se=np.asarray(se.get("gains", np.full(m.n_coils, np.nan)), float).tolist(),
        offsets_mm=(m.offsets * 1e3).tolist(),
        offsets_se_mm=(np.asarray(se.get("offsets", nan3), float) * 1e3).tolist(),
        tilts_deg=np.degrees(m.tilts).tolist(),
        tilts_se_deg=np.degrees(np.asarray(se.get("tilts", nan3), float)).tolist())
    rep = planar_document(summary, errors, data.points, cal, title)
    summary["seconds"] = {"total": time.perf_counter() - t0}
    return BuiltReport(report=rep, summary=summary)
