"""MacLachlan et al. 2025, Table II on an ILEMT folder: the paper's calibration procedure as one call.

Import the folder, run the paper's run sequence from ``base_calibration.mat`` (with its output
corrections), solve the home-source ``ld`` rows (LM from the Kim18 start of the concentric
calibration) and score them, as docs/paper-procedure.md describes (#run-sequence,
#output-correction, #pose-solution, #test-error).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .._errors import InputError
from .._result import DictResult
from ..evaluate import ACCURACY_KEYS, STAGE_UNCERTAINTY_MM
from ._run import PaperRun, as_run, load_paper_run

__all__ = [
    "TABLE2_PAPER",
    "TABLE2_PAPER_COLUMNS",
    "Table2Column",
    "Table2Reproduction",
    "identify_table2_column",
    "reproduce_table2",
    "table2_row",
    "table2_tests",
]

#: Table II of MacLachlan et al. 2025, both source designs: (trans rms, trans max) mm and
#: (rot rms, rot max) deg per calibration row, to the digits of the authors' result files.
TABLE2_PAPER_COLUMNS = {
    "concentric source": {
        "default": {"trans_rms_mm": 0.41555, "trans_max_mm": 1.02214, "rot_rms_deg": 0.27262,
                    "rot_max_deg": 0.63741},
        "corrected": {"trans_rms_mm": 0.26306, "trans_max_mm": 0.72037, "rot_rms_deg": 0.27262,
                      "rot_max_deg": 0.63741},
        "concentric": {"trans_rms_mm": 0.90484, "trans_max_mm": 2.49205, "rot_rms_deg": 0.50825,
                       "rot_max_deg": 1.41547},
    },
    "dipole approximating source": {
        "default": {"trans_rms_mm": 0.27148, "trans_max_mm": 0.74731, "rot_rms_deg": 0.21000,
                    "rot_max_deg": 0.52906},
        "corrected": {"trans_rms_mm": 0.17790, "trans_max_mm": 0.61461, "rot_rms_deg": 0.21000,
                      "rot_max_deg": 0.52906},
        "concentric": {"trans_rms_mm": 28.3254, "trans_max_mm": 73.4540, "rot_rms_deg": 20.2638,
                       "rot_max_deg": 56.8394},
    },
}

#: The concentric-source column: the column of the recording bundled with openemt.
TABLE2_PAPER = TABLE2_PAPER_COLUMNS["concentric source"]

#: Test rows of the paper's Table II (three sensor fixtures, home source fixture, ``ld``).
TABLE2_TEST_ROWS = 1896

#: Source designs told apart by the fitted source coil positions: the concentric source's coils
#: share a centre to a few mm, the dipole approximating source's are 45 mm apart.
CONCENTRIC_SPREAD_MAX_M = 0.010
DIPOLE_APPROX_SPREAD_MIN_M = 0.025


@dataclass(frozen=True)
class Table2Column:
    """Which column of the paper's Table II a folder's results compare with, and why.

    Attributes
    ----------
    name : str or None
        ``"concentric source"``, ``"dipole approximating source"``, or None (no comparable
        column).
    values : dict or None
        The column's rows (see :data:`TABLE2_PAPER_COLUMNS`).
    same_recording : bool
        The folder's test files are byte-identical to the paper's bundled recording.
    source_spread_mm : float
        Largest distance of a fitted source coil position from their centroid.
    note : str
        The evidence, in one sentence.
    """

    name: str | None
    values: dict | None
    same_recording: bool
    source_spread_mm: float
    note: str

    def to_dict(self) -> dict:
        return {"name": self.name, "same_recording": self.same_recording,
                "source_spread_mm": self.source_spread_mm, "note": self.note}


def _same_as_bundled(folder, test_files) -> bool:
    """Whether every test file equals the bundled paper recording's file of the same name."""
    from .. import datasets

    try:
        entry = datasets.info("cal_9_15_premo_cmu")
        recorded = dict(line.split(maxsplit=1)[::-1] for line in
                        entry.checksum_file.read_text().splitlines())
    except OSError:
        return False
    from ..io import file_sha256

    for name in test_files:
        digest = recorded.get(f"./{name}")
        f = folder / name
        if digest is None or not f.is_file() or file_sha256(f) != digest:
            return False
    return bool(test_files)


def identify_table2_column(run: PaperRun, test) -> Table2Column:
    """The Table II column that matches a folder, identified by its data.

    The source design is read off the folder's own default (XYZ) calibration: concentric when
    the fitted source coils share a centre within :data:`CONCENTRIC_SPREAD_MAX_M`, dipole
    approximating when they are at least :data:`DIPOLE_APPROX_SPREAD_MIN_M` apart. A column is
    only named when the test set has the paper's layout (:data:`TABLE2_TEST_ROWS` rows of the
    three sensor fixtures); the folder's name plays no part. Byte-identical test files mark the
    paper's own recording.
    """
    L = np.asarray(run.calibration("XYZ").model.L_so, dtype=np.float64)
    spread = float(np.max(np.linalg.norm(L - L.mean(axis=1, keepdims=True), axis=0)))
    spread_mm = round(spread * 1e3, 3)
    files = sorted({test.files[i] for i in np.unique(test.file_index)})
    if len(test) != TABLE2_TEST_ROWS:
        return Table2Column(None, None, False, spread_mm,
                            f"no paper column: {len(test)} test rows, the paper's Table II has "
                            f"{TABLE2_TEST_ROWS}")
    if spread <= CONCENTRIC_SPREAD_MAX_M:
        name = "concentric source"
    elif spread >= DIPOLE_APPROX_SPREAD_MIN_M:
        name = "dipole approximating source"
    else:
        return Table2Column(None, None, False, spread_mm,
                            f"no paper column: fitted source coils {spread_mm:.1f} mm apart fit "
                            f"neither the concentric nor the dipole approximating source")
    same = _same_as_bundled(run.folder, files)
    basis = (f"fitted source coils within {spread_mm:.1f} mm of their centre"
             + ("; test files identical to the paper's recording" if same else
                "; not the paper's recording (files differ), so compare with care"))
    return Table2Column(name, TABLE2_PAPER_COLUMNS[name], same, spread_mm, f"{name}: {basis}")



def table2_tests(run: PaperRun):
    """Solve and score the Table II rows of a paper run.

    Returns
    -------
    test : Dataset
        The test rows (home source fixture, three sensor fixtures, ld).
    results : dict
        ``default`` (XYZ, LM), ``corrected`` (with its DLT, when the fit made one) and
        ``concentric`` (Kim18 alone): each a :class:`openemt.calibrate.HeldOutTest`.
    seconds : dict
    """
    from ..calibrate import held_out_rows, solve_held_out

    run = as_run(run, ["XYZ", "XYZ_concentric"])
    test = run.dataset.select(held_out_rows(run.dataset))
    if len(test) == 0:
        raise InputError(f"expected soYoutZup ld test files in {str(run.folder)!r}, got none")
    xyz, conc = run.calibration("XYZ"), run.calibration("XYZ_concentric")
    seconds = {}
    t0 = time.perf_counter()
    results = {"default": solve_held_out(test, xyz, concentric_model=conc.model)}
    seconds["test_solve_default"] = time.perf_counter() - t0
    if xyz.linear_correction is not None:
        results["corrected"] = solve_held_out(test, xyz, concentric_model=conc.model,
                                          apply_correction=True)
    t0 = time.perf_counter()
    results["concentric"] = solve_held_out(test, conc, solver="kim18")
    seconds["test_solve_concentric"] = time.perf_counter() - t0
    return test, results, seconds


def table2_row(t) -> dict:
    """A Table II row of a :class:`~openemt.calibrate.HeldOutTest`: RMS and max errors (mm,
    deg), ``trans_uncert_mm`` combined with the stage uncertainty and ``n_invalid``."""
    s = t.summary
    row = {k: s[k] for k in ACCURACY_KEYS}
    row["trans_uncert_mm"] = float(np.hypot(s["trans_rms_mm"], STAGE_UNCERTAINTY_MM))
    row["n_invalid"] = t.n_invalid
    return row


@dataclass(frozen=True, eq=False)
class Table2Reproduction(DictResult):
    """MacLachlan et al. 2025, Table II reproduced.

    Attributes
    ----------
    default, corrected, concentric : dict or None
        Rows (``trans_rms_mm``, ``trans_max_mm``, ``rot_rms_deg``, ``rot_max_deg``,
        ``trans_uncert_mm`` combined with the stage uncertainty, ``n_invalid``);
        ``corrected`` is None when the sequence made no output correction.
    improved, improved_corrected : dict or None
        The improved calibration's rows (only with ``improved=True``).
    improved_model : dict or None
        :meth:`openemt.calibrate.ImprovedCalibration.to_dict` (only with ``improved=True``);
        its ``terms`` say which terms of :data:`openemt.calibrate.TERMS` were kept and why.
    breakdown : dict or None
        Held-out errors by range, stage Rz and sensor fixture
        (:func:`openemt.evaluate.error_breakdown`): ``default`` and, per improved step (the
        base model, then each term tried, with ``kept``), ``improved_steps`` (only with
        ``improved=True``).
    noise_floor : dict or None
        Repeat-pose scatter of md and ld rows at the same stage pose, solved with the improved
        model (:func:`openemt.evaluate.repeat_scatter`; only with ``improved=True``).
    n_test : int
    calibration_residues : dict
        Calibration step -> rms residue.
    calibration_stats : dict
        Calibration step -> rows, invalid rows and output-correction RMS.
    skipped_steps : list of str
    paper : dict or None
        The published values of the matching column (:func:`identify_table2_column`).
    paper_column : dict
        :meth:`Table2Column.to_dict`.
    seconds : dict
        Wall time per stage.

    ``to_dict()`` leaves out the three improved entries when the improved model was not run.
    """

    default: dict | None
    corrected: dict | None
    concentric: dict | None
    n_test: int
    calibration_residues: dict
    calibration_stats: dict
    skipped_steps: list
    paper: dict | None
    paper_column: dict
    seconds: dict
    improved: dict | None = None
    improved_corrected: dict | None = None
    improved_model: dict | None = None
    breakdown: dict | None = None
    noise_floor: dict | None = None

    def _items(self) -> dict:
        items = super()._items()        # the rows first, then the improved entries if run
        rows = {k: items.pop(k) for k in ("default", "corrected", "concentric")}
        improved = {k: items.pop(k) for k in ("improved", "improved_corrected",
                                              "improved_model", "breakdown", "noise_floor")}
        return {**rows, **(improved if self.improved_model is not None else {}), **items}


def reproduce_table2(source, *, improved: bool = False, cross_validation: bool = False
                     ) -> Table2Reproduction:
    """MacLachlan et al. 2025, Table II from an ILEMT folder: import, run sequence, output correction,
    scoring (docs/paper-procedure.md#table-2).

    Parameters
    ----------
    source : path-like or PaperRun
        An ILEMT data folder with ``base_calibration.mat`` and the md/ld files, or a run of it.
    improved : bool
        Also run the improved calibration (:func:`openemt.calibrate.improved_calibration`) and
        report rows ``improved`` and ``improved_corrected`` and its parameters
        (``improved_model``). It is fitted on md data only.
    cross_validation : bool
        With ``improved``, also report the md cross-validation of every variant of
        :data:`openemt.calibrate.CANDIDATES` (``improved_model.selection_cv_md``).

    Returns
    -------
    Table2Reproduction
    """
    t_all = time.perf_counter()
    run = source if isinstance(source, PaperRun) else load_paper_run(source)
    test, results, solve_seconds = table2_tests(run)
    seconds = {**run.seconds, **solve_seconds}
    rows = {name: table2_row(results[name]) if name in results else None
            for name in ("default", "corrected", "concentric")}
    extra = {}
    if improved:
        from ..calibrate import CANDIDATES, TERMS, improved_calibration

        xyz, conc = run.calibration("XYZ"), run.calibration("XYZ_concentric")
        t0 = time.perf_counter()
        imp = improved_calibration(run.dataset, xyz, conc.model,
                                   candidates=CANDIDATES if cross_validation else None,
                                   terms=TERMS)
        seconds["improved_calibration"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        it = imp.test(test)
        seconds["test_solve_improved"] = time.perf_counter() - t0
        rows.update(improved=it.improved, improved_corrected=it.improved_corrected,
                    improved_model=imp.to_dict())
        t0 = time.perf_counter()
        extra = {"breakdown": {"default": default_breakdown(run, test, results["default"]),
                               "improved_steps": imp.step_breakdowns(test)},
                 "noise_floor": imp.noise_floor(test).to_dict()}
        seconds["breakdown"] = time.perf_counter() - t0
    column = identify_table2_column(run, test)
    seconds["total"] = time.perf_counter() - t_all
    return Table2Reproduction(
        **rows, n_test=len(test),
        calibration_residues={k: f.calibration.stats["rms_residue"] for k, f in run.fits.items()},
        calibration_stats={k: {kk: f.calibration.stats.get(kk) for kk in
                               ("num_points", "num_invalid", "uncorrected", "corrected")}
                           for k, f in run.fits.items()},
        skipped_steps=list(run.skipped), paper=column.values, paper_column=column.to_dict(),
        seconds=seconds, **extra)


def default_breakdown(run, test, result) -> dict:
    """:func:`openemt.evaluate.error_breakdown` (as a dict) of a Table II row's
    :class:`~openemt.calibrate.HeldOutTest` of the XYZ calibration, against the rig's ground
    truth of that calibration."""
    from ..evaluate import error_breakdown
    from ..geometry import ground_truth_poses

    xyz = run.calibration("XYZ")
    D = ground_truth_poses(xyz.source_fixture, xyz.stage_fixture, xyz.sensor_fixture,
                           test.source_fixture, test.stage, test.sensor_fixture)
    return error_breakdown(result.trans, result.rot, D[:, :3, 3],
                           stage_rz=np.asarray(test.stage)[:, 5],
                           sensor_fixture=test.sensor_fixture).to_dict()
