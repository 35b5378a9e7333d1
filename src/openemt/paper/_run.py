"""One import of an ILEMT folder and one run of the paper's calibration sequence, shared by the
table reproductions and the report (docs/paper-procedure.md#run-sequence)."""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._errors import InputError

__all__ = ["PaperRun", "load_paper_run", "sequence_steps"]


def sequence_steps(names=None) -> tuple:
    """The steps of :data:`openemt.calibrate.PAPER_SEQUENCE` needed to produce ``names``.

    Parameters
    ----------
    names : iterable of str, optional
        Step names (``XYZ``, ``XYZ_all``, ``trans_only``, ...); ``None`` means every step.

    Returns
    -------
    tuple of SequenceStep
        The named steps and the steps they start from, in sequence order.
    """
    from ..calibrate import PAPER_SEQUENCE

    by_name = {s.name: s for s in PAPER_SEQUENCE}
    if names is None:
        return tuple(PAPER_SEQUENCE)
    names = [names] if isinstance(names, str) else list(names)
    need: set[str] = set()
    for n in names:
        if n not in by_name:
            raise InputError(f"expected a step of the paper sequence {tuple(by_name)}, got {n!r}")
        while n != "base" and n not in need:
            need.add(n)
            n = by_name[n].start
    return tuple(s for s in PAPER_SEQUENCE if s.name in need)


@dataclass(frozen=True, eq=False)
class PaperRun:
    """An imported ILEMT folder with the calibrations of the paper's run sequence.

    Attributes
    ----------
    folder : Path
    dataset : Dataset
        Every row of the folder (signs applied, stage compensated).
    base : Calibration
        ``base_calibration.mat``.
    fits : dict of str -> CalibrationFit
        Sequence step name -> fit (see :func:`openemt.calibrate.run_sequence`).
    correction : bool
        Whether the output corrections were fitted.
    seconds : dict
        Wall time of the import and of the sequence.
    skipped : tuple of str
        Requested steps the sequence skipped (no rows for their mode in this folder, or their
        start step was skipped).
    """

    folder: Path
    dataset: object
    base: object
    fits: dict
    correction: bool
    seconds: dict = field(default_factory=dict)
    skipped: tuple = ()

    def calibration(self, name: str):
        """The calibration produced by step ``name`` (``XYZ`` is ILEMT's ``XYZ_hr_cal``)."""
        if name not in self.fits:
            raise KeyError(f"expected one of the calibrations {tuple(self.fits)}, got {name!r}")
        return self.fits[name].calibration

    def has(self, *names: str) -> bool:
        return all(n in self.fits for n in names)


def corrected_poses(P, L):
    """Poses with the linear output correction ``L`` (4, 4) applied to their positions."""
    from ..correct import apply_linear_correction

    out = np.array(P, dtype=np.float64)
    out[:, :3, 3] = apply_linear_correction(L, out[:, :3, 3])
    return out


def check_paper_folder(folder) -> Path:
    """Refuse a path that is not an ILEMT data folder with ``base_calibration.mat``; returns the
    path of that file."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"expected an ILEMT data folder, got {str(folder)!r}")
    base_path = folder / "base_calibration.mat"
    if not base_path.is_file():
        raise FileNotFoundError(f"expected {base_path.name} in the ILEMT folder, got none in "
                                f"{str(folder)!r}")
    return base_path


def load_paper_run(folder, *, steps=None, correction: bool = True, dataset=None) -> PaperRun:
    """Import an ILEMT folder and run (part of) the paper's calibration sequence once.

    Parameters
    ----------
    folder : path-like
        ILEMT data folder with ``base_calibration.mat`` and the ``.dat`` files.
    steps : iterable of str, optional
        Calibrations wanted (their start steps are added); default: the whole sequence.
    correction : bool
        Fit the output corrections (docs/paper-procedure.md#output-correction) where the sequence asks for them.
    dataset : Dataset, optional
        The folder already imported (skips the import).

    Returns
    -------
    PaperRun
    """
    from ..calibrate import run_sequence
    from ..io import import_ilemt_folder, read_calibration

    folder = Path(folder)
    base_path = check_paper_folder(folder)
    seconds = {}
    t0 = time.perf_counter()
    ds = import_ilemt_folder(folder) if dataset is None else dataset
    base = read_calibration(base_path)
    seconds["import"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    wanted = sequence_steps(steps)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fits = run_sequence(ds, base, wanted, correction=correction)
    seconds["calibration_sequence"] = time.perf_counter() - t0
    seconds["calibration_steps"] = {k: f.calibration.stats.get("seconds") for k, f in
                                    fits.items()}
    skipped = tuple(st.name for st in wanted if st.name not in fits)
    return PaperRun(folder=folder, dataset=ds, base=base, fits=fits, correction=correction,
                    seconds=seconds, skipped=skipped)


def as_run(source, steps, *, correction: bool = True, dataset=None) -> PaperRun:
    """``source`` if it is a PaperRun with the wanted steps, else a fresh run of the folder
    (``dataset``: the folder already imported).

    Raises ValueError if a wanted calibration is missing (e.g. the folder has no rows for it).
    """
    run = source if isinstance(source, PaperRun) else \
        load_paper_run(source, steps=steps, correction=correction, dataset=dataset)
    missing = [s.name for s in sequence_steps(steps) if s.name not in run.fits]
    if missing:
        raise InputError(f"expected the calibrations {missing} of the paper sequence, got only "
                         f"{tuple(run.fits)} (no rows for the others in {str(run.folder)!r})")
    return run
