"""Seed 000 Table II on an ILEMT folder: the paper's calibration procedure as one call.

Import the folder, run the §9 sequence from ``base_calibration.mat`` (with the §11 output
corrections), solve the home-source ``ld`` rows as §10 (LM from the Kim18 start of the
concentric calibration) and score them as §12.
"""

from __future__ import annotations

import time

import numpy as np

from .._errors import InputError
from ..evaluate import STAGE_UNCERTAINTY_M
from ._run import PaperRun, as_run, load_paper_run

__all__ = ["TABLE2_PAPER", "reproduce_table2", "table2_tests"]

#: Seed 000 Table II, concentric source (cal_9_15): (trans rms, trans max) mm, (rot rms, max) deg
TABLE2_PAPER = {
    "default": {"trans_rms_mm": 0.41555, "trans_max_mm": 1.02214, "rot_rms_deg": 0.27262,
                "rot_max_deg": 0.63741},
    "corrected": {"trans_rms_mm": 0.26306, "trans_max_mm": 0.72037, "rot_rms_deg": 0.27262,
                  "rot_max_deg": 0.63741},
    "concentric": {"trans_rms_mm": 0.90484, "trans_max_mm": 2.49205, "rot_rms_deg": 0.50825,
                   "rot_max_deg": 1.41547},
}

_ROW_KEYS = ("trans_rms_mm", "trans_max_mm", "rot_rms_deg", "rot_max_deg")


def table2_tests(run: PaperRun):
    """Solve and score the Table II rows of a paper run.

    Returns
    -------
    test : Dataset
        The test rows (home source fixture, three sensor fixtures, ld).
    results : dict
        ``default`` (XYZ, LM), ``corrected`` (with its DLT, when the fit made one) and
        ``concentric`` (Kim18 alone): each the dict of :func:`openemt.calibrate.test_poses`.
    seconds : dict
    """
    from ..calibrate import test_poses, test_rows

    run = as_run(run, ["XYZ", "XYZ_concentric"])
    test = run.dataset.select(test_rows(run.dataset))
    if len(test) == 0:
        raise InputError(f"expected soYoutZup ld test files in {str(run.folder)!r}, got none")
    xyz, conc = run.calibration("XYZ"), run.calibration("XYZ_concentric")
    seconds = {}
    t0 = time.perf_counter()
    results = {"default": test_poses(test, xyz, concentric_model=conc.model)}
    seconds["test_solve_default"] = time.perf_counter() - t0
    if xyz.linear_correction is not None:
        results["corrected"] = test_poses(test, xyz, concentric_model=conc.model,
                                          apply_correction=True)
    t0 = time.perf_counter()
    results["concentric"] = test_poses(test, conc, solver="kim18")
    seconds["test_solve_concentric"] = time.perf_counter() - t0
    return test, results, seconds


def _row(t: dict) -> dict:
    s = t["summary"]
    row = {k: s[k] for k in _ROW_KEYS}
    row["trans_uncert_mm"] = float(np.hypot(s["trans_rms_mm"], STAGE_UNCERTAINTY_M * 1e3))
    row["n_invalid"] = t["n_invalid"]
    return row


def reproduce_table2(source, *, improved: bool = False, cross_validation: bool = False) -> dict:
    """Seed 000 Table II from an ILEMT folder: import, the §9 sequence, §11 correction, §12 tests.

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
    dict
        JSON-ready summary: rows ``default``, ``corrected`` (None when the sequence made no
        correction), ``concentric`` (and the improved rows), ``n_test``,
        ``calibration_residues``, ``calibration_stats``, ``skipped_steps``, ``paper`` (the
        published values), and ``seconds`` per stage.
    """
    t_all = time.perf_counter()
    run = source if isinstance(source, PaperRun) else load_paper_run(source)
    test, results, solve_seconds = table2_tests(run)
    seconds = {**run.seconds, **solve_seconds}
    out = {name: _row(results[name]) if name in results else None
           for name in ("default", "corrected", "concentric")}
    if improved:
        from ..calibrate import CANDIDATES, improved_calibration

        xyz, conc = run.calibration("XYZ"), run.calibration("XYZ_concentric")
        t0 = time.perf_counter()
        imp = improved_calibration(run.dataset, xyz, conc.model,
                                   candidates=CANDIDATES if cross_validation else None)
        seconds["improved_calibration"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        out.update(imp.test(test))
        seconds["test_solve_improved"] = time.perf_counter() - t0
        out["improved_model"] = imp.summary()
    out["n_test"] = len(test)
    out["calibration_residues"] = {k: f.calibration.stats["rms_residue"]
                                   for k, f in run.fits.items()}
    out["calibration_stats"] = {
        k: {kk: f.calibration.stats.get(kk) for kk in
            ("num_points", "num_invalid", "uncorrected", "corrected")}
        for k, f in run.fits.items()}
    out["skipped_steps"] = list(run.skipped)
    out["paper"] = TABLE2_PAPER
    seconds["total"] = time.perf_counter() - t_all
    out["seconds"] = seconds
    return out
