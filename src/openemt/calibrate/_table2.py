"""Testing calibrations as the paper does (ilemt-format.md §10, §12) and ``reproduce table2``.

Test rows are the ``ld`` files of the home source fixture with all three sensor fixtures (1896
rows on the ILEMT folders, null and key rows included). Each row is solved without any use of
the ground truth except the hemisphere (ILEMT takes it from the ground-truth position): the
iterative solver starts from the Kim18 closed form of the concentric calibration. The error is
ILEMT's "stage coordinates" error ``F_se . D^-1 . M . F_se^-1`` against the ground truth ``D``
built with the tested calibration's own fixtures.
"""

from __future__ import annotations

import time
import warnings
from pathlib import Path

import numpy as np

from ..evaluate import STAGE_UNCERTAINTY_M, error_summary, pose_error_magnitudes
from ..geometry import SENSOR_FIXTURES, SOURCE_FIXTURES, ground_truth_poses

__all__ = ["TABLE2_PAPER", "reproduce_table2", "test_poses", "test_rows"]

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


def test_rows(dataset):
    """Boolean mask of the paper's test rows: home source fixture, every sensor fixture, ld."""
    return dataset.mask(pattern="ld", source_fixture=SOURCE_FIXTURES[0],
                        sensor_fixture=SENSOR_FIXTURES)


test_rows.__test__ = False  # not a pytest test


def test_poses(data, cal, *, solver: str = "lm", concentric_model=None,
               apply_correction: bool = False) -> dict:
    """Solve and score test rows with a calibration (ilemt-format.md §10, §12).

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
        Apply ``cal.linear_correction`` to the solved positions (ilemt-format.md §10.3).

    Returns
    -------
    dict
        ``trans``/``rot`` errors (m, rad; (N,)), ``summary`` (mm/deg statistics), ``n_invalid``,
        ``poses`` (N, 4, 4) as solved (before correction).
    """
    from ..correct import apply_linear_correction
    from ..solve import hemisphere_from_positions, solve_kim18, solve_lm

    F = (cal.source_fixture, cal.stage_fixture, cal.sensor_fixture)
    D = ground_truth_poses(*F, data.source_fixture, data.stage, data.sensor_fixture)
    hemi = hemisphere_from_positions(D[:, :3, 3])
    if solver == "kim18":
        res = solve_kim18(data.couplings, cal.model, hemisphere=hemi)
    elif solver == "lm":
        res = solve_lm(data.couplings, cal.model, initial="kim18", hemisphere=hemi, bounds=0.4,
                       concentric_model=concentric_model)
    else:
        raise ValueError(f"expected solver 'lm' or 'kim18', got {solver!r}")
    M = np.array(res.poses)
    if apply_correction:
        if cal.linear_correction is None:
            raise ValueError("expected a calibration with a linear_correction, got none")
        M[:, :3, 3] = apply_linear_correction(cal.linear_correction, M[:, :3, 3])
    trans, rot = pose_error_magnitudes(M, D, sensor_fixture=cal.sensor_fixture)
    valid = np.asarray(res.residual) < 1e-5
    return {"trans": trans, "rot": rot, "summary": error_summary(trans, rot),
            "n_invalid": int((~valid).sum()), "poses": np.asarray(res.poses)}


test_poses.__test__ = False  # not a pytest test


def _row(t: dict) -> dict:
    s = t["summary"]
    row = {k: s[k] for k in _ROW_KEYS}
    row["trans_uncert_mm"] = float(np.hypot(s["trans_rms_mm"], STAGE_UNCERTAINTY_M * 1e3))
    row["n_invalid"] = t["n_invalid"]
    return row


def reproduce_table2(folder, *, improved: bool = False, cross_validation: bool = False) -> dict:
    """Seed 000 Table II from an ILEMT folder: import, the §9 sequence, §11 correction, §12 tests.

    Parameters
    ----------
    folder : path-like
        An ILEMT data folder with ``base_calibration.mat`` and the md/ld files.
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
        JSON-ready summary: rows ``default``, ``corrected``, ``concentric`` (and the improved
        rows), ``n_test``, ``calibration_residues``, ``paper`` (the published values), and
        ``seconds`` per stage.
    """
    from ..io import import_ilemt_folder, read_calibration
    from ._sequence import run_sequence

    t_all = time.perf_counter()
    folder = Path(folder)
    base_path = folder / "base_calibration.mat"
    if not base_path.is_file():
        raise FileNotFoundError(f"expected {base_path.name} in the ILEMT folder, got none in "
                                f"{str(folder)!r}")
    seconds = {}
    t0 = time.perf_counter()
    ds = import_ilemt_folder(folder)
    base = read_calibration(base_path)
    seconds["import"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fits = run_sequence(ds, base)
    skipped = [str(w.message) for w in caught if "skipped" in str(w.message)]
    for need in ("XYZ", "XYZ_concentric"):
        if need not in fits:
            raise ValueError(f"expected the {need} calibration of the sequence, got it skipped "
                             f"({'; '.join(skipped)})")
    seconds["calibration_sequence"] = time.perf_counter() - t0
    seconds["calibration_steps"] = {k: f.calibration.stats["seconds"] for k, f in fits.items()}
    test = ds.select(test_rows(ds))
    if len(test) == 0:
        raise ValueError(f"expected soYoutZup ld test files in {str(folder)!r}, got none")
    xyz = fits["XYZ"].calibration
    conc = fits["XYZ_concentric"].calibration
    t0 = time.perf_counter()
    default = test_poses(test, xyz, concentric_model=conc.model)
    seconds["test_solve_default"] = time.perf_counter() - t0
    rows = {"default": _row(default)}
    if xyz.linear_correction is not None:
        rows["corrected"] = _row(test_poses(test, xyz, concentric_model=conc.model,
                                            apply_correction=True))
    else:
        rows["corrected"] = None
    t0 = time.perf_counter()
    rows["concentric"] = _row(test_poses(test, conc, solver="kim18"))
    seconds["test_solve_concentric"] = time.perf_counter() - t0
    out = {"rows": rows}
    if improved:
        from ._heldout import CANDIDATES, improved_calibration

        t0 = time.perf_counter()
        imp = improved_calibration(ds, xyz, conc.model,
                                   candidates=CANDIDATES if cross_validation else None)
        seconds["improved_calibration"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        rows.update(imp.test(test))
        seconds["test_solve_improved"] = time.perf_counter() - t0
        out["improved_model"] = imp.summary()
    out.update(rows)
    del out["rows"]
    out["n_test"] = len(test)
    out["calibration_residues"] = {k: f.calibration.stats["rms_residue"] for k, f in fits.items()}
    out["calibration_stats"] = {
        k: {kk: f.calibration.stats.get(kk) for kk in
            ("num_points", "num_invalid", "uncorrected", "corrected")}
        for k, f in fits.items()}
    out["paper"] = TABLE2_PAPER
    seconds["total"] = time.perf_counter() - t_all
    out["seconds"] = seconds
    return out
