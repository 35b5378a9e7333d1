"""Testing calibrations as the paper does (docs/paper-procedure.md#pose-solution, docs/paper-procedure.md#test-error; ILEMT's ``check_poses``).

Test rows are the ``ld`` files of the home source fixture with all three sensor fixtures (1896
rows on the ILEMT folders, null and key rows included). Each row is solved without any use of
the ground truth except the hemisphere (ILEMT takes it from the ground-truth position): the
iterative solver starts from the Kim18 closed form of the concentric calibration. The error is
ILEMT's "stage coordinates" error ``F_se . D^-1 . M . F_se^-1`` against the ground truth ``D``
built with the tested calibration's own fixtures.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._constants import ILEMT_POSITION_BOX_M
from .._errors import InputError
from .._result import Result
from ..evaluate import error_summary, pose_error_magnitudes
from ..geometry import SENSOR_FIXTURES, SOURCE_FIXTURES, ground_truth_poses

__all__ = ["ILEMT_VALID_RESNORM", "HeldOutTest", "held_out_rows", "solve_held_out"]

#: ILEMT's validity test of a pose solution, part of the paper's procedure
#: (docs/paper-procedure.md#iterative-solution): valid if the resnorm (sum of squared coupling
#: residuals / spectral norm of the measured coupling matrix, in ILEMT's coupling units) is
#: below this. It drives the retries of the iterative solution and the invalid counts of the
#: paper's tables; openemt's own, unit-free rule for pose statuses is docs/solve.md#validity-rule.
ILEMT_VALID_RESNORM = 1e-5

@dataclass(frozen=True, eq=False)
class HeldOutTest(Result):
    """Test rows solved with a calibration and scored against the rig's ground truth.

    Attributes
    ----------
    trans, rot : ndarray, shape (N,)
        Translation (m) and rotation (rad) error magnitudes; NaN for failed solutions.
    summary : dict
        :func:`openemt.evaluate.error_summary` of the errors (mm, deg).
    n_invalid : int
        Rows whose solution residual is not below ``ILEMT_VALID_RESNORM`` (kept in the statistics).
    poses : ndarray, shape (N, 4, 4)
        Solved poses, before any output correction.

    ``to_dict()`` gives ``summary`` and ``n_invalid``.
    """

    _not_in_dict = ("trans", "rot", "poses")

    trans: np.ndarray
    rot: np.ndarray
    summary: dict
    n_invalid: int
    poses: np.ndarray


def held_out_rows(dataset):
    """Boolean mask of the paper's test rows, held out of every calibration: home source
    fixture, every sensor fixture, ``ld`` pattern."""
    return dataset.mask(pattern="ld", source_fixture=SOURCE_FIXTURES[0],
                        sensor_fixture=SENSOR_FIXTURES)


def truth_poses(data, cal) -> np.ndarray:
    """Ground-truth poses ``(N, 4, 4)`` of ``data``'s rows under ``cal``'s fixtures."""
    return ground_truth_poses(cal.source_fixture, cal.stage_fixture, cal.sensor_fixture,
                              data.source_fixture, data.stage, data.sensor_fixture)


def ilemt_solve(data, cal, solver: str, truth, *, initial="kim18", concentric_model=None):
    """ILEMT's pose solution of ``data``'s rows with ``cal``'s model, in the hemisphere of
    the ground truth ``truth (N, 4, 4)``: the Kim18 closed form (``solver='kim18'``), or the
    LM (``'lm'``) from ``initial`` within ILEMT's position box and with its retry test
    (docs/paper-procedure.md#iterative-solution). The complex couplings go to the solver so
    that the validity residual is normalised by the complex spectral norm, as ILEMT's
    resnorm is."""
    from ..solve import hemisphere_from_positions, solve_kim18, solve_lm

    hemi = hemisphere_from_positions(truth[:, :3, 3])
    if solver == "kim18":
        return solve_kim18(data.couplings, cal.model, hemisphere=hemi)
    if solver == "lm":
        return solve_lm(data.couplings, cal.model, initial=initial, hemisphere=hemi,
                        bounds=ILEMT_POSITION_BOX_M, concentric_model=concentric_model,
                        retry_resnorm=ILEMT_VALID_RESNORM)
    raise InputError(f"expected solver 'lm' or 'kim18', got {solver!r}")


def solve_held_out(data, cal, *, solver: str = "lm", concentric_model=None,
                   apply_correction: bool = False) -> HeldOutTest:
    """Solve and score test rows with a calibration (docs/paper-procedure.md#pose-solution, docs/paper-procedure.md#test-error).

    Parameters
    ----------
    data : Dataset
        Test rows.
    cal : Calibration
        Calibration under test (its fixtures define the ground truth).
    solver : {'lm', 'kim18'}
        Iterative solution started from Kim18 (``concentric_model``), or Kim18 alone.
    concentric_model : DipoleModel, optional
        Concentric model of the Kim18 start (ILEMT: the concentric calibration).
    apply_correction : bool
        Apply ``cal.linear_correction`` to the solved positions (docs/paper-procedure.md#applying-correction).

    Returns
    -------
    HeldOutTest

    Examples
    --------
    The paper's Table II "default" row from the authors' own XYZ and concentric calibrations:

    >>> import openemt
    >>> from openemt.calibrate import held_out_rows, solve_held_out
    >>> folder = openemt.datasets.path("cal_9_15_premo_cmu")
    >>> data = openemt.import_ilemt_folder(folder)
    >>> test = data.select(held_out_rows(data))
    >>> xyz = openemt.read_ilemt_calibration(folder / "output" / "XYZ_hr_cal.mat")
    >>> conc = openemt.read_ilemt_calibration(folder / "output" / "XYZ_concentric_hr_cal.mat")
    >>> res = solve_held_out(test, xyz, concentric_model=conc.model)
    >>> res.summary["n"], round(res.summary["trans_rms_mm"], 3), res.n_invalid
    (1896, 0.416, 0)
    """
    from ..correct import apply_linear_correction

    D = truth_poses(data, cal)
    res = ilemt_solve(data, cal, solver, D, concentric_model=concentric_model)
    M = np.array(res.poses)
    if apply_correction:
        if cal.linear_correction is None:
            raise InputError("expected a calibration with a linear_correction, got none")
        M[:, :3, 3] = apply_linear_correction(cal.linear_correction, M[:, :3, 3])
    trans, rot = pose_error_magnitudes(M, D, sensor_fixture=cal.sensor_fixture)
    valid = np.asarray(res.residual) < ILEMT_VALID_RESNORM
    return HeldOutTest(trans=trans, rot=rot, summary=error_summary(trans, rot),
                       n_invalid=int((~valid).sum()), poses=np.asarray(res.poses))

