"""The symbols and terms of the calibration-and-characterization reports, defined in words.

:data:`GLOSSARY` holds one definition per symbol a report table can show (column names and
parameter symbols); :func:`glossary_section` adds, at the end of a report, the definitions of
the symbols its tables showed (:attr:`openemt.report.Report.symbols`) and of the terms its text
uses. A symbol a table shows without a definition here is a bug the report tests catch.
"""

from __future__ import annotations

from ..calibrate._check import ILEMT_VALID_RESNORM
from ..evaluate import STAGE_UNCERTAINTY_DEG, STAGE_UNCERTAINTY_MM
from ._html import Report

__all__ = ["GLOSSARY", "PLAIN_WORDS", "PLANAR_GLOSSARY", "TERMS", "glossary_section"]

_CHAIN = ("the ground-truth pose of a row on the test rig, P = F_so · so_J · F_st · st_J · F_se "
          "(MacLachlan et al. 2025, eq. 6): so_J and st_J are the known source-fixture rotation "
          "and stage motion of the row, F_so, F_st and F_se the three fixture transforms a "
          "calibration fits, and P maps sensor coordinates into source coordinates. A fixture "
          "is a pose vector [x, y, z, rx, ry, rz], shown as .x .y .z (translation, mm) and "
          ".rx .ry .rz (rotation vector: axis times angle, deg)")
_FIX = "fixture transform of the fixture chain (see there), a pose vector"
_COIL = ("coils are the columns of the 3 × n matrix, named X, Y, Z for a tri-axial set (the "
         "last, Z, is the reference coil)")
_U = (f"combined standard uncertainty of a measurement, u(P) = sqrt(u(cal)^2 + u_stage^2): "
      f"u(cal) is the RMS error of the calibration on the test rows and u_stage the stage "
      f"uncertainty, {STAGE_UNCERTAINTY_MM:.3f} mm and {STAGE_UNCERTAINTY_DEG:.2f} deg "
      "(MacLachlan et al. 2025, eq. 10)")
_SWEEP = ("Table IV of MacLachlan et al. 2025 along the axis sweeps (one axis of the stage moved "
          "at a time)")

#: Symbol -> definition, in the order the glossary lists them.
GLOSSARY = {
    "L_so": f"source coil positions: the dipole centre of each source coil in the source frame "
            f"(mm); {_COIL}",
    "M_so": f"source coil moments: direction and strength of each source coil's dipole, in gain "
            f"units (the model coupling is gain · m_j · B_i, docs/ilemt-data.md#dipole-model); "
            f"{_COIL}",
    "L_se": f"sensor coil positions: the dipole centre of each sensor coil in the sensor frame "
            f"(mm); {_COIL}",
    "M_se": f"sensor coil moments, in gain units, as M_so; {_COIL}",
    "F_so": f"source {_FIX}: source mover -> source coils",
    "F_st": f"stage {_FIX}: stage base -> source-fixture base",
    "F_se": f"sensor {_FIX}: sensor coils -> sensor mover",
    "fixture chain": _CHAIN,
    "status": "fitted: estimated by this calibration; fixed (gauge): held by the gauge that "
              "makes the model unique (the reference coil at the origin with its moment along "
              "+z; MacLachlan et al. 2025, eq. 7); fixed: held at its start value in this "
              "calibration's mode (e.g. the y component of the X coil's moment, which fixes the "
              "frame's rotation about z, and the source reference gain). Fixed parameters have "
              "no standard error",
    "std_error": "standard error of a fitted parameter, from the Jacobian of the calibration "
                 "fit at the solution scaled by the residual variance",
    "truth": "the simulated tracker's true value: the dipole equivalent of its finite coils and "
             "the fixtures the simulator used",
    "condition": "how the test rows were solved: the calibration with the iterative (LM) "
                 "solver started from the Kim18 closed form of the concentric calibration; the "
                 "same with the DLT output correction applied to the positions; or the "
                 "concentric calibration's Kim18 closed form alone",
    "calibration": "the calibration tested on the test rows (its fixtures define the ground "
                   "truth), or one calibration of the paper's sequence",
    "test rows": "a fixture combination soA_seB (source fixture A, sensor fixture B: the rig's "
                 "manual orientations, e.g. YoutZup = Y axis out, Z axis up; "
                 "docs/ilemt-data.md), with the stage pattern when there are several",
    "group": "rows of the held-out breakdown: all rows, a range bin of the distance r of the "
             "sensor from the source, a stage rotation Rz, or a sensor fixture",
    "trans_rms_mm": "RMS of the translation error magnitude over the rows (mm): distance between "
                    "the solved and the reference sensor position, in stage coordinates "
                    "(docs/paper-procedure.md#test-error)",
    "trans_max_mm": "largest translation error magnitude over the rows (mm)",
    "rot_rms_deg": "RMS of the rotation error magnitude over the rows (deg): angle of the "
                   "rotation between the solved and the reference sensor orientation",
    "rot_max_deg": "largest rotation error magnitude over the rows (deg)",
    "trans_uncert_mm": "u(P) in translation (mm), see u(P)",
    "rot_uncert_deg": "u(P) in rotation (deg), see u(P)",
    "u_P_trans_mm": "u(P) in translation of the rows of one fixture combination (mm), see u(P)",
    "u_P_rot_deg": "u(P) in rotation of the rows of one fixture combination (deg), see u(P)",
    "n": "number of test rows scored",
    "n_invalid": f"rows whose solution residue is not below {ILEMT_VALID_RESNORM:g} (ILEMT's "
                 "validity rule); they are kept in the statistics",
    "mode": "calibration mode: which parameter groups are fitted on which rows "
            "(docs/paper-procedure.md#parameter-groups)",
    "rms_residue": "RMS of the normalised coupling residual over the calibration rows "
                   "(dimensionless)",
    "rows": "calibration rows the fit used",
    "invalid": "calibration rows without a valid pose solution when the output correction was "
               "fitted",
    "uncorrected_mm": "RMS translation error of the calibration rows before the DLT output "
                      "correction (mm)",
    "corrected_mm": "RMS translation error of the calibration rows after the DLT output "
                    "correction (mm)",
    "calibration data": "Table III of MacLachlan et al. 2025: the data a calibration was fitted "
                        "on (dimensionality of the motion)",
    "test data": "Table III of MacLachlan et al. 2025: the data the calibration was tested on",
    "paper trans rms / max": "the paper's translation RMS and maximum (mm) for the same cell",
    "paper rot rms / max": "the paper's rotation RMS and maximum (deg) for the same cell",
    "row": f"{_SWEEP}: direct (error along the swept axis) or cross (error on the other axes), "
           "for openemt (ours) and the paper",
    "xyz_abs_rms": f"{_SWEEP}: RMS absolute error of the translation sweeps (direct mm, cross "
                   "deg)",
    "xyz_abs_max": f"{_SWEEP}: largest absolute error of the translation sweeps (direct mm, "
                   "cross deg)",
    "rot_abs_rms": f"{_SWEEP}: RMS absolute error of the rotation sweeps (direct deg, cross mm)",
    "rot_abs_max": f"{_SWEEP}: largest absolute error of the rotation sweeps (direct deg, cross "
                   "mm)",
    "xyz_nonlin_rms": f"{_SWEEP}: RMS nonlinearity of the translation sweeps (direct percent, "
                      "cross deg/mm)",
    "xyz_nonlin_max": f"{_SWEEP}: largest nonlinearity of the translation sweeps (direct "
                      "percent, cross deg/mm)",
    "rot_nonlin_rms": f"{_SWEEP}: RMS nonlinearity of the rotation sweeps (direct percent, "
                      "cross mm/deg)",
    "rot_nonlin_max": f"{_SWEEP}: largest nonlinearity of the rotation sweeps (direct percent, "
                      "cross mm/deg)",
    "u(P)": _U,
    "residue": "ILEMT's resnorm of a pose solution: sum of squared coupling residuals divided "
               "by the spectral norm of the measured coupling matrix",
    "LM": "Levenberg-Marquardt: the iterative pose solver on the calibrated dipole model",
    "Kim18": "the closed-form pose solution of Kim, Song and Park 2018 for concentric coils; it "
             "assumes every source coil (and every sensor coil) at one point",
    "DLT": "the output correction of MacLachlan et al. 2025: a 4 × 4 homogeneous map of the "
           "solved positions, fitted on the calibration rows (direct linear transform)",
    "md, ld, sweep": "stage patterns of the rig: md and ld grids (calibration and test data) and "
                     "single-axis sweeps",
}

#: Terms the report text uses: always defined.
TERMS = ("u(P)", "residue", "LM", "Kim18", "DLT", "md, ld, sweep")

#: The board (planar) report's symbols (docs/planar.md#reports).
PLANAR_GLOSSARY = {
    "points": "the grid points scored: all of them, or with a hold-out scheme the points the "
              "calibration was fitted on (in-sample) and the others (held out)",
    "n": "number of grid points scored",
    "n_failed": "grid points without a converged 5-DOF solution (left out of the error "
                "statistics, drawn as crosses in the error map)",
    "position_rms_mm": "RMS of the position error magnitude over the converged points (mm): "
                       "distance between the solved and the known sensor position",
    "position_max_mm": "largest position error magnitude over the converged points (mm)",
    "axis_rms_deg": "RMS angle between the solved and the known sensor coil axis (deg); a "
                    "5-DOF sensor has no roll",
    "status": "solver status of a grid point (docs/solve.md): converged, max_iterations, "
              "invalid_input, ambiguous, out_of_volume or not_converged",
    "samples": "grid points with that solver status",
    "coil": "a source coil of the board, by its name in the board file",
    **{f"residual, {k} (%)": f"RMS of measured minus model coupling of the coil at the known "
                             f"poses of the {k} points, in percent of the coil's peak coupling "
                             "on these points" for k in ("all points", "in-sample", "held out")},
    "gain": "the coil's fitted gain (coupling per unit of the finite-coil model field)",
    **{f"offset {a} (mm)": f"the coil's fitted position offset along {a} from the board file's "
                           "geometry (mm)" for a in "xyz"},
    **{f"tilt {a} (deg)": f"{a} component of the coil's fitted tilt, a rotation vector (axis "
                          "times angle, deg); 'fixed' when the fit kept it (no --tilt)"
       for a in "xyz"},
}

#: Column names that are plain words, not symbols.
PLAIN_WORDS = frozenset({"parameter", "unit", "value"})


def glossary_section(rep: Report, terms=TERMS, glossary=None) -> None:
    """Define every symbol the report's tables showed, and ``terms``, at the end of ``rep``
    (with a fixture, the fixture chain they belong to); ``glossary`` defaults to
    :data:`GLOSSARY`."""
    glossary = GLOSSARY if glossary is None else glossary
    shown = set(rep.symbols) | set(terms)
    if shown & {"F_so", "F_st", "F_se"}:
        shown.add("fixture chain")
    used = [k for k in glossary if k in shown]
    rep.heading("Symbols and terms")
    rep.definitions([(k, glossary[k]) for k in used],
                    caption="Every symbol the tables above show, in words. Units: positions "
                            "and translations in mm, rotations in degrees, moments in gain "
                            "units.")
