"""Characterization of one calibration on a test dataset with a reference (the numbers of the
characterization report; :func:`openemt.report.characterization_document` lays them out).

The test rows are solved as the paper does (docs/paper-procedure.md#pose-solution) and scored
against the rig kinematics with the calibration's own fixtures (stage-coordinates error,
docs/paper-procedure.md#test-error) or against the dataset's reference poses; the sweep files,
if any, are analysed as Table IV (MacLachlan et al. 2025) after re-optimising the stage and
sensor fixtures.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .._errors import InputError
from .._result import Result
from ..evaluate import STAGE_UNCERTAINTY_M, STAGE_UNCERTAINTY_RAD, combined_uncertainty

__all__ = ["CalibrationCharacterization", "accuracy_row", "characterize_calibration"]

_KEYS = ("trans_rms_mm", "trans_max_mm", "rot_rms_deg", "rot_max_deg")
_U_MM = STAGE_UNCERTAINTY_M * 1e3
_U_DEG = float(np.rad2deg(STAGE_UNCERTAINTY_RAD))


def accuracy_row(name: str, test, paper=None) -> dict:
    """One accuracy row of a :class:`~openemt.calibrate.HeldOutTest`: ``condition``, RMS and
    max errors (mm, deg), combined uncertainties with the stage's (MacLachlan et al. 2025,
    eq. 10), ``n``, ``n_invalid`` and, if given, the ``paper`` values."""
    s = test.summary
    row = {"condition": name, **{k: s[k] for k in _KEYS}}
    row["trans_uncert_mm"] = float(combined_uncertainty(s["trans_rms_mm"], _U_MM))
    row["rot_uncert_deg"] = float(combined_uncertainty(s["rot_rms_deg"], _U_DEG))
    row["n"] = int(s["n"])
    row["n_invalid"] = int(test.n_invalid)
    if paper is not None:
        row["paper"] = dict(paper)
    return row


def corrected_poses(P, L):
    """Poses with the linear output correction ``L`` (4, 4) applied to their positions."""
    from ..correct import apply_linear_correction

    out = np.array(P, dtype=np.float64)
    out[:, :3, 3] = apply_linear_correction(L, out[:, :3, 3])
    return out


@dataclass(frozen=True, eq=False)
class CalibrationCharacterization(Result):
    """Accuracy of one calibration on test rows with a reference.

    Attributes
    ----------
    calibration : Calibration
        The calibration tested.
    reference : str
        ``"kinematics"`` (rig kinematics with the calibration's fixtures) or ``"poses"``.
    n_test, n_files : int
        Test rows and the files/blocks they come from.
    accuracy : dict of str -> dict
        Condition (``calibration``, ``calibration + correction``, ``concentric + Kim18``) ->
        :func:`accuracy_row`.
    main : str
        The condition characterized in detail (with the correction when there is one).
    characterization : Characterization
        Statistics of ``main`` overall and per fixture combination (and pattern).
    measured, reference_poses : ndarray, shape (N, 4, 4)
        Poses of ``main`` (corrected if so) and the reference.
    trans, rot : ndarray, shape (N,)
        Error magnitudes of ``main`` (m, rad).
    shown : ndarray of int
        Rows of one grid group, for the error-vector figure.
    sweeps : SweepAnalysis or None
        Table IV analysis of the sweep rows, if any.
    sweep_note : str
        How the sweep reference was made.
    seconds : dict
        Wall time, ``total``.

    ``to_dict()`` is the report's JSON summary: ``mode`` (``"dataset"``), ``reference``,
    ``n_test``, ``accuracy``, ``by_fixture``, ``table4`` (direct, cross, n_curves, or None)
    and ``seconds``.
    """

    calibration: object
    reference: str
    n_test: int
    n_files: int
    accuracy: dict
    main: str
    characterization: object
    measured: np.ndarray
    reference_poses: np.ndarray
    trans: np.ndarray
    rot: np.ndarray
    shown: np.ndarray
    sweeps: object
    sweep_note: str
    seconds: dict

    def _items(self) -> dict:
        table4 = None
        if self.sweeps is not None:
            t = self.sweeps.table
            table4 = {"direct": t.direct, "cross": t.cross, "n_curves": t.n_curves}
        return {"mode": "dataset", "reference": self.reference, "n_test": self.n_test,
                "accuracy": self.accuracy, "by_fixture": self.characterization.by_group,
                "table4": table4, "seconds": self.seconds}


def _check(dataset, calibration, concentric, reference):
    from ..io import Calibration, Dataset

    if not isinstance(dataset, Dataset):
        raise TypeError(f"expected an openemt.io.Dataset, got {type(dataset).__name__}")
    if not isinstance(calibration, Calibration):
        raise TypeError(f"expected a Calibration, got {type(calibration).__name__}")
    if concentric is not None and not isinstance(concentric, Calibration):
        raise TypeError(f"expected a concentric Calibration, got {type(concentric).__name__}")
    if reference not in ("kinematics", "poses"):
        raise InputError(f"expected reference 'kinematics' or 'poses', got {reference!r}")
    if reference == "poses" and dataset.poses is None:
        raise InputError("expected a dataset with reference `poses` for reference='poses', got "
                         "none")


def _kinematic_conditions(dataset, cal, concentric):
    """Conditions solved as the paper does and scored against the rig kinematics."""
    from ..calibrate import solve_held_out

    conc_model = None if concentric is None else concentric.model
    r = solve_held_out(dataset, cal, concentric_model=conc_model)
    conds = {"calibration": (r, r.poses)}
    if cal.linear_correction is not None:
        r = solve_held_out(dataset, cal, concentric_model=conc_model, apply_correction=True)
        conds["calibration + correction"] = (r, corrected_poses(r.poses, cal.linear_correction))
    if concentric is not None:
        r = solve_held_out(dataset, concentric, solver="kim18")
        conds["concentric + Kim18"] = (r, r.poses)
    return conds


def _pose_conditions(dataset, cal, concentric, D):
    """Conditions solved with the calibration's own solver and scored against ``D``."""
    from ..calibrate import HeldOutTest
    from ..evaluate import error_summary, pose_error_magnitudes
    from ..solve import hemisphere_from_positions, solve

    hemi = hemisphere_from_positions(D[:, :3, 3])
    res = solve(dataset.signed_real(), cal, hemisphere=hemi, apply_correction=False,
                concentric_calibration=concentric)
    variants = {"calibration": (res, res.poses)}
    if cal.linear_correction is not None:
        variants["calibration + correction"] = (res, corrected_poses(res.poses,
                                                                     cal.linear_correction))
    if concentric is not None:
        rk = solve(dataset.signed_real(), concentric, solver="kim18", hemisphere=hemi,
                   apply_correction=False)
        variants["concentric + Kim18"] = (rk, rk.poses)
    conds = {}
    for name, (r, M) in variants.items():
        trans, rot = pose_error_magnitudes(M, D)  # NaN for failed solves
        test = HeldOutTest(trans=trans, rot=rot, summary=error_summary(trans, rot),
                           n_invalid=int((~(np.asarray(r.residual) < 1e-5)).sum()),
                           poses=np.asarray(r.poses))
        conds[name] = (test, M)
    return conds


def _sweeps(dataset, cal, M, D, reference):
    """Table IV analysis of the sweep rows (fixtures re-optimised against the kinematics)."""
    from ..evaluate import sweep_linearity
    from ..geometry import ground_truth_poses

    rows = dataset.mask(pattern="sweep")
    if not rows.any():
        return None, ""
    sub = dataset.select(rows)
    M, Ds = M[rows], D[rows]
    stage = sub.stage_logged if sub.stage_logged is not None else sub.stage
    note, F_sweep = "", None
    if reference == "kinematics":
        from ._table4 import refit_fixtures

        rc = refit_fixtures(M, sub, cal).calibration
        Ds = ground_truth_poses(rc.source_fixture, rc.stage_fixture, rc.sensor_fixture,
                                sub.source_fixture, sub.stage, sub.sensor_fixture)
        F_sweep = rc.sensor_fixture
        note = "Stage and sensor fixtures re-optimised in pose space (0.05 m moment)."
    a = sweep_linearity(M, Ds, stage, labels=sub.file_names(), sensor_fixture=F_sweep)
    return (a, note) if a.curves else (None, "")


def characterize_calibration(dataset, calibration, *, concentric=None,
                             reference: str = "kinematics") -> CalibrationCharacterization:
    """Test one calibration on a dataset with a reference.

    Parameters
    ----------
    dataset : Dataset
        Test rows (couplings with stage and fixture codes, or with ``poses``).
    calibration : Calibration
    concentric : Calibration, optional
        Concentric calibration whose Kim18 closed form starts the solver (ILEMT practice); it is
        also tested with Kim18 alone.
    reference : {'kinematics', 'poses'}
        Ground truth from the rig kinematics with the calibration's fixtures (the paper's
        procedure, stage-coordinates error) or the dataset's ``poses``.

    Returns
    -------
    CalibrationCharacterization

    Examples
    --------
    >>> import openemt
    >>> from openemt.calibrate import held_out_rows
    >>> from openemt.paper import characterize_calibration
    >>> folder = openemt.datasets.path("cal_9_15_premo_cmu")
    >>> data = openemt.import_ilemt_folder(folder)
    >>> xyz = openemt.read_ilemt_calibration(folder / "output" / "XYZ_hr_cal.mat")
    >>> c = characterize_calibration(data.select(held_out_rows(data)), xyz)
    >>> c.main, c.n_test, round(c.accuracy[c.main]["trans_rms_mm"], 3)
    ('calibration + correction', 1896, 0.263)
    """
    from ..evaluate import characterize, fixture_labels
    from ..geometry import ground_truth_poses

    _check(dataset, calibration, concentric, reference)
    t0 = time.perf_counter()
    cal = calibration
    groups = fixture_labels(dataset)
    if len(np.unique(dataset.pattern)) > 1:
        groups = np.char.add(np.char.add(groups, " "), dataset.pattern.astype(str))
    if reference == "kinematics":
        D = ground_truth_poses(cal.source_fixture, cal.stage_fixture, cal.sensor_fixture,
                               dataset.source_fixture, dataset.stage, dataset.sensor_fixture)
        F_se = cal.sensor_fixture
        conds = _kinematic_conditions(dataset, cal, concentric)
    else:
        D = np.asarray(dataset.poses, dtype=np.float64)
        F_se = None
        conds = _pose_conditions(dataset, cal, concentric, D)
    accuracy = {name: accuracy_row(name, test) for name, (test, _) in conds.items()}
    main = "calibration + correction" if "calibration + correction" in conds else "calibration"
    test, M = conds[main]
    char = characterize(M, D, groups=groups, sensor_fixture=F_se)
    grid = dataset.pattern != "sweep"
    first = groups[np.flatnonzero(grid)[0]] if grid.any() else groups[0]
    sweeps, note = _sweeps(dataset, cal, M, D, reference)
    return CalibrationCharacterization(
        calibration=cal, reference=reference, n_test=len(dataset), n_files=len(dataset.files),
        accuracy=accuracy, main=main, characterization=char, measured=M, reference_poses=D,
        trans=test.trans, rot=test.rot, shown=np.flatnonzero(groups == first), sweeps=sweeps,
        sweep_note=note, seconds={"total": time.perf_counter() - t0})
