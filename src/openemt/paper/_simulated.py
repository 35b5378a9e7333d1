"""Calibration of the simulated tracker judged against its known truth (the tables of
``openemt demo``).

On simulated data the truth is known: the dipole equivalent of the simulated coils and the
fixtures the simulator used. These functions put a fitted calibration beside that truth and
beside the perturbed start it was fitted from.
"""

from __future__ import annotations

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
        ``n_invalid``, ``trans_uncert_mm`` (combined with the stage uncertainty) and
        ``reason``: one line for a failed or surprising row (the unfitted start; invalid
        solutions; see :func:`openemt.paper.explain_rows`), else None.
    """
    from ..calibrate import solve_held_out
    from ._reasons import invalid_reason, start_reason
    from ._table2 import table2_row

    keys = (*ACCURACY_KEYS, "n_invalid", "trans_uncert_mm")
    rows = {}
    for label, cal in (("truth (dipole equivalent of the finite coils)", truth),
                       ("start (perturbed)", start)):
        row = table2_row(solve_held_out(test_data, cal, concentric_model=concentric.model))
        rows[label] = {k: row[k] for k in keys}
        rows[label]["reason"] = (start_reason(start, truth) if cal is start
                                 else invalid_reason(row["n_invalid"], len(test_data)))
    accuracy = characterization.accuracy
    for cond, label in _CONDITIONS:
        if cond in accuracy:
            r = accuracy[cond]
            rows[label] = {**{k: r[k] for k in keys}, "reason": r.get("reason")}
    return rows


def parameters_against_truth(calibration, truth) -> list:
    """:func:`openemt.paper.parameter_rows` of a fitted calibration with a ``truth`` column:
    coil positions and fixture translations in mm, rotations in degrees, moments in gain
    units, fixed parameters marked ``fixed``."""
    from ._parameters import parameter_rows

    return parameter_rows(calibration, truth=truth)
