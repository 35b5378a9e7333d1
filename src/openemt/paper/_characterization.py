"""The numbers of the characterization reports: one calibration on a test dataset with a
reference (:func:`characterize_calibration`), or a whole ILEMT folder with the paper's tables
(:func:`characterize_paper_run`). :func:`openemt.report.characterization_document` and
:func:`openemt.report.paper_document` lay them out.

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
from ..calibrate._check import ILEMT_VALID_RESNORM
from ..evaluate import (
    ACCURACY_KEYS,
    STAGE_UNCERTAINTY_DEG,
    STAGE_UNCERTAINTY_MM,
    combined_uncertainty,
)
from ._reasons import explain_rows
from ._run import corrected_poses

__all__ = [
    "CalibrationCharacterization",
    "PaperCharacterization",
    "accuracy_row",
    "characterize_calibration",
    "characterize_paper_run",
]


def accuracy_row(name: str, test, paper=None) -> dict:
    """One accuracy row of a :class:`~openemt.calibrate.HeldOutTest`: ``condition``, RMS and
    max errors (mm, deg), combined uncertainties with the stage's (MacLachlan et al. 2025,
    eq. 10), ``n``, ``n_invalid`` and, if given, the ``paper`` values."""
    s = test.summary
    row = {"condition": name, **{k: s[k] for k in ACCURACY_KEYS}}
    row["trans_uncert_mm"] = float(combined_uncertainty(s["trans_rms_mm"], STAGE_UNCERTAINTY_MM))
    row["rot_uncert_deg"] = float(combined_uncertainty(s["rot_rms_deg"], STAGE_UNCERTAINTY_DEG))
    row["n"] = int(s["n"])
    row["n_invalid"] = int(test.n_invalid)
    if paper is not None:
        row["paper"] = dict(paper)
    return row


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
        :func:`accuracy_row`, with a ``reason``: one line for a failed or surprising row
        (:func:`openemt.paper.explain_rows`), else None.
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


def check_inputs(dataset, calibration, concentric, reference) -> None:
    """Refuse inputs :func:`characterize_calibration` cannot use (one ``InputError`` line)."""
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
                concentric_calibration=concentric, retry_resnorm=ILEMT_VALID_RESNORM)
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
                           n_invalid=int((~(np.asarray(r.residual) < ILEMT_VALID_RESNORM)).sum()),
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

    check_inputs(dataset, calibration, concentric, reference)
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
    explain_rows(accuracy, model=cal.model, poses=D,
                 concentric=None if concentric is None else concentric.model,
                 concentric_key="concentric + Kim18",
                 corrections=[("calibration", "calibration + correction")])
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


@dataclass(frozen=True, eq=False)
class PaperCharacterization(Result):
    """The paper's tables and the characterization of its main calibration on an ILEMT folder.

    Attributes
    ----------
    run : PaperRun
        The imported folder and its calibration sequence.
    test : Dataset
        Table II test rows.
    table2 : dict of str -> dict
        Rows ``default``, ``corrected``, ``concentric`` (:func:`accuracy_row`, with the
        paper's values and a ``reason`` as in :class:`CalibrationCharacterization`).
    table2_column : Table2Column
        The paper's column the folder compares with.
    table3 : Table3Reproduction or None
        None when the folder lacks Table III's calibration or test data.
    table4 : Table4Result or None
        None without sweep files.
    default : HeldOutTest
        The ``default`` (XYZ_hr_cal, uncorrected) test.
    reference_poses : ndarray, shape (N, 4, 4)
        Ground truth of the test rows.
    characterization : Characterization
        ``default`` per fixture combination.
    shown : ndarray of int
        Rows of the error-vector figure (sensor fixture YoutZup).
    calibration_stats : list of dict
        Residue and output-correction fit of every calibration of the sequence.
    seconds : dict
        Wall time per stage.
    breakdown : dict
        Table II rows (``default``, ``corrected``) by range, stage Rz and sensor fixture
        (:func:`openemt.evaluate.error_breakdown`).
    noise_floor : dict or None
        Repeat-pose scatter of the md and ld rows at the same stage pose, both solved with
        ``XYZ_hr_cal`` (:func:`openemt.evaluate.repeat_scatter`); None without md rows.

    ``to_dict()`` is the ``openemt report ILEMT_DIR --json`` summary: ``mode`` (``"ilemt"``),
    ``folder``, ``n_rows``, ``n_test``, ``table2``, ``table2_paper_column``, ``table3`` and
    ``table4`` (without their ``seconds``; ``table4`` without its curves), ``by_fixture``,
    ``calibration_stats`` (by calibration), ``breakdown``, ``noise_floor`` and ``seconds``.
    """

    run: object
    test: object
    table2: dict
    table2_column: object
    table3: object
    table4: object
    default: object
    reference_poses: np.ndarray
    characterization: object
    shown: np.ndarray
    calibration_stats: list
    seconds: dict
    breakdown: dict | None = None
    noise_floor: dict | None = None

    def _items(self) -> dict:
        t3, t4 = self.table3, self.table4
        return {
            "mode": "ilemt", "folder": str(self.run.folder), "n_rows": len(self.run.dataset),
            "n_test": len(self.test), "table2": self.table2,
            "table2_paper_column": self.table2_column.to_dict(),
            "table3": None if t3 is None else {k: v for k, v in t3.to_dict().items()
                                               if k != "seconds"},
            "table4": None if t4 is None else {k: v for k, v in t4.summary.to_dict().items()
                                               if k not in ("curves", "seconds")},
            "by_fixture": self.characterization.by_group,
            "calibration_stats": {r["calibration"]: r for r in self.calibration_stats},
            "breakdown": self.breakdown, "noise_floor": self.noise_floor,
            "seconds": self.seconds,
        }


def _sequence_stats(run) -> list:
    rows = []
    for name, f in run.fits.items():
        s = f.calibration.stats
        rows.append({"calibration": f"{name}_hr_cal", "mode": f.calibration.mode,
                     "rms_residue": s.get("rms_residue"), "rows": s.get("num_points"),
                     "invalid": s.get("num_invalid", ""),
                     "uncorrected_mm": 1e3 * s["uncorrected"] if s.get("uncorrected")
                     is not None else float("nan"),
                     "corrected_mm": 1e3 * s["corrected"] if s.get("corrected")
                     is not None else float("nan")})
    return rows


def characterize_paper_run(source) -> PaperCharacterization:
    """Tables II-IV of MacLachlan et al. 2025 and the characterization of ``XYZ_hr_cal`` on an
    ILEMT folder (or a :class:`PaperRun` with the whole sequence).

    Table III is left out (None) when the folder lacks its data, Table IV when it has no sweep
    files.
    """
    from ..evaluate import characterize, fixture_labels
    from ..geometry import ground_truth_poses
    from ._run import PaperRun, as_run, load_paper_run
    from ._table2 import identify_table2_column, table2_tests
    from ._table3 import TABLE3_ROWS, reproduce_table3, table3_test_masks
    from ._table4 import sweep_test

    run = source if isinstance(source, PaperRun) else load_paper_run(source)
    as_run(run, ["XYZ", "XYZ_concentric"])  # the least a report needs
    ds = run.dataset
    seconds = dict(run.seconds)
    xyz = run.calibration("XYZ")
    t0 = time.perf_counter()
    test, results, _ = table2_tests(run)
    labels = {"default": "default (XYZ_hr_cal)", "corrected": "corrected (XYZ_hr_cal + DLT)",
              "concentric": "concentric + Kim18"}
    column = identify_table2_column(run, test)
    paper = column.values or {}
    t2 = {k: accuracy_row(labels[k], r, paper.get(k)) for k, r in results.items()}
    seconds["table2"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    masks = table3_test_masks(ds)
    t3 = reproduce_table3(run) if (run.has(*TABLE3_ROWS.values())
                                   and all(m.any() for m in masks.values())) else None
    seconds["table3"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    has_sweeps = bool(ds.mask(pattern="sweep", source_fixture="YoutZup").any())
    t4 = sweep_test(run) if has_sweeps else None
    seconds["table4"] = time.perf_counter() - t0
    default = results["default"]
    D = ground_truth_poses(xyz.source_fixture, xyz.stage_fixture, xyz.sensor_fixture,
                           test.source_fixture, test.stage, test.sensor_fixture)
    explain_rows(t2, model=xyz.model, poses=D,
                 concentric=run.calibration("XYZ_concentric").model, concentric_key="concentric",
                 corrections=[("default", "corrected")])
    char = characterize(default.poses, D, groups=fixture_labels(test),
                        sensor_fixture=xyz.sensor_fixture)
    t0 = time.perf_counter()
    breakdown, floor = _breakdown(run, test, results, D)
    seconds["breakdown"] = time.perf_counter() - t0
    return PaperCharacterization(
        run=run, test=test, table2=t2, table2_column=column, table3=t3, table4=t4,
        default=default, reference_poses=D, characterization=char,
        shown=np.flatnonzero(test.sensor_fixture == "YoutZup"),
        calibration_stats=_sequence_stats(run), seconds=seconds, breakdown=breakdown,
        noise_floor=floor)


def _breakdown(run, test, results, D):
    """Breakdown of the Table II rows and the md/ld repeat-pose noise floor (XYZ_hr_cal)."""
    from ..calibrate import repeat_pairs, solve_held_out
    from ..evaluate import error_breakdown, repeat_scatter

    rz = np.asarray(test.stage)[:, 5]
    out = {k: error_breakdown(results[k].trans, results[k].rot, D[:, :3, 3], stage_rz=rz,
                              sensor_fixture=test.sensor_fixture).to_dict()
           for k in ("default", "corrected") if k in results}
    ds = run.dataset
    md = ds.select(ds.mask(pattern="md", source_fixture="YoutZup"))
    i, j = repeat_pairs(md, test)
    if i.size == 0:
        return out, None
    xyz, conc = run.calibration("XYZ"), run.calibration("XYZ_concentric")
    m = solve_held_out(md.select(i), xyz, concentric_model=conc.model)
    return out, repeat_scatter(m.poses, results["default"].poses[j]).to_dict()
