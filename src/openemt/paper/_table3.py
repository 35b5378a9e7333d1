"""MacLachlan et al. 2025, Table III: calibration error versus the dimensionality of the calibration and test
data (concentric source, uncorrected; docs/paper-procedure.md#run-sequence, docs/paper-procedure.md#table-3).

Rows are calibrations of the paper's run sequence, columns are test sets:

========================  ====================  ==========================================
row                       calibration           data it was fitted on
========================  ====================  ==========================================
``translation_only``      ``trans_only_hr_cal`` soYoutZup_seYoutZup ``mdtrans`` (30 rows)
``sensor_fixture``        ``XYZ_hr_cal``        soYoutZup, three sensor fixtures, md (426)
``both_fixtures``         ``XYZ_all_hr_cal``    every fixture combination, md (852)
========================  ====================  ==========================================

============================== ============================================================
column                         test rows
============================== ============================================================
``translation_only``           soYoutZup_seYoutZup ``ldtrans`` (128 rows)
``sensor_fixtures``            soYoutZup with the three sensor fixtures, ``ld`` (1896 rows)
``source_and_sensor_fixtures`` those plus soXoutZup/soZoutYup/soXinYup with seYoutZup (3792)
============================== ============================================================

Each cell is the uncorrected test of :func:`openemt.calibrate.solve_held_out`: iterative solution
started from the Kim18 closed form of the concentric calibration (``XYZ_concentric_hr_cal``),
hemisphere from the ground truth, invalid solutions kept, ILEMT's stage-coordinates error.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .._errors import InputError
from .._result import DictResult
from ..evaluate import ACCURACY_KEYS as _KEYS
from ..geometry import SENSOR_FIXTURES, SOURCE_FIXTURES
from ._run import as_run

__all__ = [
    "TABLE3_COLUMNS",
    "TABLE3_PAPER",
    "TABLE3_ROWS",
    "Table3Reproduction",
    "reproduce_table3",
    "table3_test_masks",
]

#: Table III row -> calibration step of the paper sequence (ILEMT ``<step>_hr_cal``).
TABLE3_ROWS = {"translation_only": "trans_only", "sensor_fixture": "XYZ",
               "both_fixtures": "XYZ_all"}
TABLE3_COLUMNS = ("translation_only", "sensor_fixtures", "source_and_sensor_fixtures")
#: Table III column -> the test sets (:func:`table3_test_masks`) it joins.
_COLUMN_SETS = dict(zip(TABLE3_COLUMNS, (("translation_only",), ("sensor_fixtures",),
                                         ("sensor_fixtures", "source_only"))))


def _cells(*rows):
    return {c: dict(zip(_KEYS, v)) for c, v in zip(TABLE3_COLUMNS, rows)}


#: MacLachlan et al. 2025, Table III as printed (mm and degrees; RMS, max).
TABLE3_PAPER = {
    "translation_only": _cells((0.231, 0.613, 0.109, 0.308), (1.862, 5.514, 1.088, 2.809),
                               (4.122, 11.227, 1.793, 5.672)),
    "sensor_fixture": _cells((0.396, 0.977, 0.276, 0.501), (0.416, 1.022, 0.273, 0.637),
                             (4.580, 12.256, 1.826, 5.222)),
    "both_fixtures": _cells((0.844, 1.700, 0.399, 0.888), (0.895, 2.256, 0.540, 1.382),
                            (2.306, 6.121, 1.100, 3.395)),
}


def table3_test_masks(dataset) -> dict:
    """Row masks of the test sets (columns of Table III) in an ILEMT dataset.

    The source-and-sensor-fixture set is the sensor-fixture set plus ``source_only``, the ld
    rows of the other source fixtures with the home sensor fixture.

    Returns
    -------
    dict of str -> ndarray of bool, shape (N,)
        ``translation_only``, ``sensor_fixtures``, ``source_only``.
    """
    home_so, home_se = SOURCE_FIXTURES[0], SENSOR_FIXTURES[0]
    return {
        "translation_only": dataset.mask(pattern="ldtrans", source_fixture=home_so,
                                         sensor_fixture=home_se),
        "sensor_fixtures": dataset.mask(pattern="ld", source_fixture=home_so,
                                        sensor_fixture=SENSOR_FIXTURES),
        "source_only": dataset.mask(pattern="ld", source_fixture=SOURCE_FIXTURES[1:],
                                    sensor_fixture=home_se),
    }


@dataclass(frozen=True, eq=False)
class Table3Reproduction(DictResult):
    """MacLachlan et al. 2025, Table III reproduced.

    Attributes
    ----------
    cells : dict
        Row (``translation_only``, ``sensor_fixture``, ``both_fixtures``) -> column
        (``translation_only``, ``sensor_fixtures``, ``source_and_sensor_fixtures``) -> cell:
        ``trans_rms_mm``, ``trans_max_mm``, ``rot_rms_deg``, ``rot_max_deg``, ``n``,
        ``n_invalid``, ``n_nonfinite``, the paper's values (``paper``) and ours / paper
        (``ratio``).
    max_deviation : float
        Largest ``|ratio - 1|`` over all cells.
    within_5_percent : bool
    calibrations : dict
        Row -> calibration (ILEMT name).
    calibration_residues : dict
        Calibration step -> rms residue.
    test_sets : dict
        Column -> files of its test rows.
    notes : str
    seconds : dict

    ``to_dict()`` has one entry per row (its cells) followed by the other fields.
    """

    cells: dict
    max_deviation: float
    within_5_percent: bool
    calibrations: dict
    calibration_residues: dict
    test_sets: dict
    notes: str
    seconds: dict

    def _items(self) -> dict:
        items = super()._items()            # the rows of ``cells`` first, then the fields
        return {**items.pop("cells"), **items}


def _cell(trans, rot, n_invalid):
    from ..evaluate import error_summary

    s = error_summary(trans, rot)
    out = {k: s[k] for k in _KEYS}
    out.update(n=int(s["n"]), n_invalid=int(n_invalid), n_nonfinite=int(s["n_nonfinite"]))
    return out


def reproduce_table3(source, *, dataset=None) -> Table3Reproduction:
    """MacLachlan et al. 2025, Table III from an ILEMT folder (or a :class:`PaperRun` of it).

    Parameters
    ----------
    source : path-like or PaperRun
        The ILEMT folder (imported and calibrated here) or an existing run containing the
        ``trans_only``, ``XYZ``, ``XYZ_all`` and ``XYZ_concentric`` calibrations.
    dataset : Dataset, optional
        The folder already imported (skips the import).

    Returns
    -------
    Table3Reproduction
    """
    from ..calibrate import solve_held_out

    t_all = time.perf_counter()
    run = as_run(source, [*TABLE3_ROWS.values(), "XYZ_concentric"], correction=False,
                 dataset=dataset)
    ds = run.dataset
    masks = table3_test_masks(ds)
    empty = [k for k, m in masks.items() if not m.any()]
    if empty:
        raise InputError(f"expected test rows for {empty} in {str(run.folder)!r}, got none")
    sets = {k: ds.select(m) for k, m in masks.items()}
    conc = run.calibration("XYZ_concentric").model
    cells_of: dict = {}
    t0 = time.perf_counter()
    worst = 0.0
    for row, step in TABLE3_ROWS.items():
        cal = run.calibration(step)
        r = {k: solve_held_out(d, cal, concentric_model=conc) for k, d in sets.items()}
        cells = {col: _cell(np.concatenate([r[k].trans for k in ks]),
                            np.concatenate([r[k].rot for k in ks]),
                            sum(r[k].n_invalid for k in ks)) for col, ks in _COLUMN_SETS.items()}
        for col, cell in cells.items():
            paper = TABLE3_PAPER[row][col]
            cell["paper"] = dict(paper)
            cell["ratio"] = {k: cell[k] / paper[k] for k in _KEYS}
            worst = max(worst, max(abs(v - 1.0) for v in cell["ratio"].values()))
        cells_of[row] = cells
    seconds = dict(run.seconds)
    seconds["test_solves"] = time.perf_counter() - t0
    files = ds.file_names()
    test_sets = {col: sorted(set(files[np.logical_or.reduce([masks[k] for k in ks])]))
                 for col, ks in _COLUMN_SETS.items()}
    notes = ("Uncorrected; LM solution started from the Kim18 closed form of "
             "XYZ_concentric_hr_cal, hemisphere from the ground truth, invalid solutions "
             "kept (docs/paper-procedure.md#test-error). Paper values: MacLachlan et al. 2025, "
             "Table III.")
    seconds["total"] = time.perf_counter() - t_all
    return Table3Reproduction(
        cells=cells_of, max_deviation=worst, within_5_percent=bool(worst <= 0.05),
        calibrations={row: f"{step}_hr_cal" for row, step in TABLE3_ROWS.items()},
        calibration_residues={step: run.calibration(step).stats.get("rms_residue")
                              for step in TABLE3_ROWS.values()},
        test_sets=test_sets, notes=notes, seconds=seconds)
