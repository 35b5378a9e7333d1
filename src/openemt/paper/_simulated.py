"""Calibration of the simulated tracker judged against its known truth (the tables of
``openemt demo``).

On simulated data the truth is known: the dipole equivalent of the simulated coils and the
fixtures the simulator used. These functions put a fitted calibration beside that truth and
beside the perturbed start it was fitted from.
"""

from __future__ import annotations

import numpy as np

from ..evaluate import ACCURACY_KEYS

__all__ = ["parameters_against_truth", "truth_comparison_rows"]

#: Characterization condition -> row name in the comparison.
_CONDITIONS = (("calibration", "calibrated"),
               ("calibration + correction", "calibrated + DLT correction"),
               ("concentric + Kim18", "concentric + Kim18"))


def truth_comparison_rows(test_data, truth, start, concentric, characterization) -> dict:
    """Test errors of the truth, the start and every tested condition of a calibration.

    Parameters
    ----------
    test_data : Dataset
        Simulated test rows.
    truth, start : Calibration
        The simulator's truth (dipole equivalent) and the perturbed start of the fit.
    concentric : Calibration
        Concentric calibration whose Kim18 closed form starts the solver.
    characterization : CalibrationCharacterization
        The fitted calibration's test (:func:`openemt.paper.characterize_calibration`).

    Returns
    -------
    dict of str -> dict
        Row name -> ``trans_rms_mm``, ``trans_max_mm``, ``rot_rms_deg``, ``rot_max_deg``,
        ``n_invalid`` and ``trans_uncert_mm`` (combined with the stage uncertainty).
    """
    from ..calibrate import solve_held_out
    from ._table2 import table2_row

    rows = {}
    for label, cal in (("truth (dipole equivalent of the finite coils)", truth),
                       ("start (perturbed)", start)):
        row = table2_row(solve_held_out(test_data, cal, concentric_model=concentric.model))
        rows[label] = {k: row[k] for k in (*ACCURACY_KEYS, "n_invalid", "trans_uncert_mm")}
    accuracy = characterization.accuracy
    for cond, label in _CONDITIONS:
        if cond in accuracy:
            r = accuracy[cond]
            rows[label] = {k: r[k] for k in (*ACCURACY_KEYS, "n_invalid", "trans_uncert_mm")}
    return rows


def parameters_against_truth(calibration, truth) -> list:
    """Rows (parameter, fitted value, standard error, truth) of the coil positions (m) and
    moments (gain units) of a fitted calibration and the truth."""
    rows = []
    se = calibration.standard_errors or {}
    for name in ("L_so", "M_so", "L_se", "M_se"):
        val = np.asarray(getattr(calibration.model, name))
        err, tv = se.get(name), np.asarray(getattr(truth.model, name))
        for c in range(val.shape[1]):
            for a in range(3):
                rows.append({
                    "parameter": f"{name}[{'xyz'[a]}, coil {c}]", "fitted": float(val[a, c]),
                    "std_error": float(np.asarray(err)[a, c]) if err is not None
                    else float("nan"),
                    "truth (dipole equiv.)": float(tv[a, c])})
    return rows
