"""Rows of a calibration's parameters for report tables: one coil naming (X, Y, Z), one unit per
quantity (mm, deg, gain), the standard errors, and whether each parameter was fitted or held
(fixed, or fixed by the gauge)."""

from __future__ import annotations

import numpy as np

__all__ = ["coil_name", "parameter_rows"]


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

    if not layout.is_dipole:      # any other model: its own labels and units
        x = cal.model.params
        errs = cal.model.split_params(np.full(x.size, np.nan))
        if se:
            flat = [np.ravel(se.get(k, np.full(np.shape(v), np.nan))) for k, v in errs.items()]
            errs = np.concatenate(flat)
        else:
            errs = np.full(x.size, np.nan)
        tv = None if truth is None else truth.model.params
        for i in range(x.size):
            unit, scale = cal.model.parameter_unit(i)
            add(cal.model.parameter_label(i), unit, float(x[i]) * scale, float(errs[i]) * scale,
                status[i], None if tv is None else float(tv[i]) * scale)
    for name, unit, scale in (() if not layout.is_dipole else
                              (("L_so", "mm", 1e3), ("M_so", "gain", 1.0),
                               ("L_se", "mm", 1e3), ("M_se", "gain", 1.0))):
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
