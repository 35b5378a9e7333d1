"""The paper's staged run sequence (docs/paper-procedure.md#run-sequence) and the output correction
(docs/paper-procedure.md#output-correction).

Each step fits one mode starting from an earlier step's output (or the base calibration):

1. ``XYZ_nosofix``        XYZ from base
2. ``so_fixture_all``     source and stage fixtures from 1, all fixtures
3. ``XYZ_concentric``     concentric from 2 (correction fitted with the Kim18 solver)
4. ``XYZ_all_concentric`` from 3
5. ``XYZ``                XYZ from 2 -- the main calibration
6. ``XYZ_all``            from 5
7. ``trans_only``         translation-only data from 2
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, replace

import numpy as np

from ..geometry import vector_from_pose
from ._check import ILEMT_VALID_RESNORM, ilemt_solve, truth_poses
from ._fit import CalibrationFit, fit
from ._modes import get_mode, select_rows

__all__ = [
    "PAPER_SEQUENCE",
    "OutputCorrection",
    "SequenceStep",
    "fit_output_correction",
    "run_sequence",
]


@dataclass(frozen=True)
class SequenceStep:
    """One calibration of a staged sequence.

    Attributes
    ----------
    name : str
        Name of the output (``XYZ``, ``so_fixture_all``, ...).
    mode : str
        Calibration mode (see :data:`~openemt.calibrate.MODES`).
    start : str
        ``"base"`` or the name of an earlier step.
    correction : str or None
        Pose solver for the output-correction fit (``"lm"``, ``"kim18"``) or ``None`` for no
        correction (ILEMT ``correct_mode = 'none'``).
    """

    name: str
    mode: str
    start: str
    correction: str | None = "lm"


PAPER_SEQUENCE = (
    SequenceStep("XYZ_nosofix", "XYZ", "base", None),
    SequenceStep("so_fixture_all", "so_fixture_all", "XYZ_nosofix", None),
    SequenceStep("XYZ_concentric", "concentric", "so_fixture_all", "kim18"),
    SequenceStep("XYZ_all_concentric", "XYZ_all_concentric", "XYZ_concentric", "kim18"),
    SequenceStep("XYZ", "XYZ", "so_fixture_all", "lm"),
    SequenceStep("XYZ_all", "XYZ_all", "XYZ", "lm"),
    SequenceStep("trans_only", "trans_only", "so_fixture_all", "lm"),
)


@dataclass(frozen=True, eq=False)
class OutputCorrection:
    """Result of the output-correction fit on the calibration rows (docs/paper-procedure.md#output-correction).

    Attributes
    ----------
    matrix : ndarray, shape (4, 4) or None
        The correction, or ``None`` when fewer than 75 % of the solutions were valid.
    n_points, n_invalid : int
        Calibration rows solved and rows discarded as invalid (resnorm >= threshold).
    rms_uncorrected, rms_corrected : float
        Position RMS (m) of the valid solutions before/after correction (nan without one).
    method : str
        Winning candidate (``none``, ``pinv``, ``dlt``) or ``"skipped"``.
    """

    matrix: np.ndarray | None
    n_points: int
    n_invalid: int
    rms_uncorrected: float
    rms_corrected: float
    method: str


def fit_output_correction(data, cal, *, solver: str = "lm",
                          valid_threshold: float = ILEMT_VALID_RESNORM,
                          min_valid: float = 0.75) -> OutputCorrection:
    """Fit the DLT output correction on calibration rows (docs/paper-procedure.md#output-correction).

    Poses are solved from the ground truth (``solver='lm'``) or in closed form
    (``solver='kim18'``), without correction; invalid solutions (resnorm >= ``valid_threshold``)
    are discarded; with fewer than ``min_valid`` valid rows no correction is made. The
    candidates and refinement are :func:`openemt.correct.fit_dlt`.
    """
    from ..correct import fit_dlt

    P = truth_poses(data, cal)
    res = ilemt_solve(data, cal, solver, P, initial=vector_from_pose(P))
    xyz, resnorm = res.poses[:, :3, 3], np.asarray(res.residual, dtype=np.float64)
    ok = np.isfinite(resnorm) & (resnorm < valid_threshold) & np.all(np.isfinite(xyz), axis=1)
    n, n_ok = len(ok), int(ok.sum())
    if n_ok < min_valid * n:
        return OutputCorrection(None, n, n - n_ok, float("nan"), float("nan"), "skipped")
    d = fit_dlt(xyz[ok], P[ok, :3, 3])
    return OutputCorrection(np.asarray(d.matrix), n, n - n_ok, float(d.rms_uncorrected),
                            float(d.rms_corrected), str(d.method))


def run_sequence(dataset, base, steps=PAPER_SEQUENCE, *, correction: bool = True,
                 warn: bool = False) -> dict:
    """Run a staged calibration sequence.

    Parameters
    ----------
    dataset : Dataset
        All rows of an ILEMT-style folder (every mode picks its own rows).
    base : Calibration
        Starting calibration (``base_calibration.mat``).
    steps : sequence of SequenceStep
    correction : bool
        Fit the output correction where a step asks for one.
    warn : bool
        Emit identifiability warnings.

    Returns
    -------
    dict of str -> CalibrationFit
        In step order (steps without rows, or whose start was skipped, are left out with a
        warning); each fit's ``calibration`` carries the correction (when fitted) and the
        correction statistics in ``stats`` (``uncorrected``/``corrected`` in m, ``num_invalid``).
    """
    out: dict[str, CalibrationFit] = {}
    for step in steps:
        if step.start != "base" and step.start not in out:
            warnings.warn(f"sequence step {step.name!r} skipped: its start {step.start!r} "
                          "was not run", stacklevel=2)
            continue
        if not select_rows(dataset, get_mode(step.mode)).any():
            warnings.warn(f"sequence step {step.name!r} skipped: the dataset has no rows for "
                          f"mode {step.mode!r}", stacklevel=2)
            continue
        start = base if step.start == "base" else out[step.start].calibration
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            if not warn:
                warnings.simplefilter("ignore")
            f = fit(dataset, start, step.mode)
        cal = f.calibration
        stats = dict(cal.stats)
        if correction and step.correction is not None:
            rows = _rows_of(dataset, f)
            oc = fit_output_correction(rows, cal, solver=step.correction)
            stats.update(num_invalid=oc.n_invalid, uncorrected=oc.rms_uncorrected,
                         corrected=oc.rms_corrected, correction_method=oc.method)
            cal = cal.replace(linear_correction=oc.matrix)
        stats["seconds"] = time.perf_counter() - t0
        cal = cal.replace(stats=stats, provenance={**cal.provenance, "sequence_step": step.name})
        out[step.name] = _with_calibration(f, cal)
    return out


def _rows_of(dataset, f: CalibrationFit):
    return dataset.select(select_rows(dataset, f.mode))


def _with_calibration(f: CalibrationFit, cal) -> CalibrationFit:
    return replace(f, calibration=cal)
