"""Fitting a calibration with ``scipy.optimize.least_squares`` and the analytic Jacobian."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._errors import InputError
from .._result import Result
from ..io import Calibration, Dataset
from ._engine import fit_problem, fit_provenance, residue_block
from ._identifiability import Identifiability
from ._layout import ParameterLayout
from ._modes import CalibrationMode, get_mode, select_rows
from ._objective import CalibrationProblem, build_problem

__all__ = ["CalibrationFit", "ResidueStats", "fit", "residue_stats"]


@dataclass(frozen=True)
class ResidueStats(Result):
    """Residue of a calibration on the rows a mode uses (docs/paper-procedure.md#calibration-objective).

    Attributes
    ----------
    rms_residue : float
        ``sqrt(sum_squared_residue / num_points)``.
    sum_squared_residue : float
        Sum of the squared normalised coupling residuals.
    num_points : int
        Rows (not matrix entries).
    """

    rms_residue: float
    sum_squared_residue: float
    num_points: int


@dataclass(frozen=True, eq=False)
class CalibrationFit:
    """Everything about one calibration fit.

    Attributes
    ----------
    calibration : Calibration
        The fitted calibration (mode, free/frozen groups, standard errors, stats filled in).
    mode : CalibrationMode
    layout : ParameterLayout
    problem : CalibrationProblem
        The rows that were fitted.
    x : ndarray, shape (layout.size,)
        Full parameter vector at the solution.
    free : ndarray of int
        Full-vector indices of the fitted parameters.
    residuals : ndarray, shape (m,)
        Normalised residuals at the solution.
    identifiability : Identifiability or None
    nfev : int
        Residual evaluations.
    seconds : float
        Wall time of the optimisation.
    """

    calibration: Calibration
    mode: CalibrationMode
    layout: ParameterLayout
    problem: CalibrationProblem
    x: np.ndarray
    free: np.ndarray
    residuals: np.ndarray
    identifiability: Identifiability | None
    nfev: int
    seconds: float


def check_inputs(dataset, start):
    """A Dataset and a start Calibration of its coil counts (TypeError, InputError)."""
    if not isinstance(dataset, Dataset):
        raise TypeError(f"expected `dataset` to be an openemt.io.Dataset, got "
                        f"{type(dataset).__name__}")
    if not isinstance(start, Calibration):
        raise TypeError(f"expected `start` to be an openemt.io.Calibration, got "
                        f"{type(start).__name__}")
    if (dataset.n_source, dataset.n_sensor) != (start.model.n_source, start.model.n_sensor):
        raise InputError(f"expected a dataset with {start.model.n_source} x "
                         f"{start.model.n_sensor} coils like the start calibration, got "
                         f"{dataset.n_source} x {dataset.n_sensor}")


def _rows(dataset, mode, select):
    if not select:
        return dataset
    mask = select_rows(dataset, mode)
    if not mask.any():
        raise InputError(f"expected rows for mode {mode.name!r} (source fixtures "
                         f"{mode.source_fixtures}, sensor fixtures {mode.sensor_fixtures}, "
                         f"patterns {mode.patterns}), got none")
    return dataset.select(mask)


def _setup(dataset, start, mode, select, optimize, freeze):
    """The checked inputs of :func:`fit`: mode, groups, rows, layout, start vector, free
    indices (raises on inputs it cannot fit)."""
    check_inputs(dataset, start)
    mode = get_mode(mode)
    opt = tuple(mode.optimize if optimize is None else optimize)
    frz = tuple(mode.freeze if freeze is None else freeze)
    data = _rows(dataset, mode, select)
    layout = ParameterLayout.for_model(start.model)
    x0 = layout.pack_calibration(start)
    if mode.concentric:
        x0[layout.slices["L_so"]] = 0.0
        x0[layout.slices["L_se"]] = 0.0
        opt = tuple(g for g in opt if g not in ("d_so_pos", "d_se_pos"))
    free = layout.free_indices(opt, frz)
    if free.size == 0:
        raise InputError(f"expected at least one free parameter, got none (optimize {opt}, "
                         f"freeze {frz})")
    return mode, opt, frz, data, layout, x0, free


def check_fit_inputs(dataset, start, mode="XYZ", *, select: bool = True, optimize=None,
                     freeze=None) -> None:
    """Raise what :func:`fit` raises on inputs it cannot fit (same arguments), without
    fitting: a command checks its inputs before it says it is fitting."""
    _setup(dataset, start, mode, select, optimize, freeze)


def residue_stats(dataset, calibration, mode="XYZ", *, select=True) -> ResidueStats:
    """Residue of a calibration on the rows of ``dataset`` a mode uses
    (docs/paper-procedure.md#calibration-objective).

    Examples
    --------
    >>> import openemt
    >>> from openemt.calibrate import residue_stats
    >>> folder = openemt.datasets.path("cal_9_15_premo_cmu")
    >>> data = openemt.import_ilemt_folder(folder)
    >>> cal = openemt.read_ilemt_calibration(folder / "output" / "XYZ_hr_cal.mat")
    >>> st = residue_stats(data, cal, "XYZ")
    >>> st.num_points, round(st.rms_residue, 6)
    (426, 0.004847)
    """
    check_inputs(dataset, calibration)
    mode = get_mode(mode)
    data = _rows(dataset, mode, select)
    layout = ParameterLayout.for_model(calibration.model)
    prob = build_problem(data, layout, calibration.model.gain)
    return ResidueStats(**residue_block(prob.residuals(layout.pack_calibration(calibration)),
                                 prob.n_rows))


def fit(dataset, start, mode="XYZ", *, select: bool = True, optimize=None, freeze=None,
        max_nfev: int = 200, tol: float = 1e-12, uncertainty: bool = True, warn: bool = True
        ) -> CalibrationFit:
    """Fit a calibration to a dataset, starting from another calibration.

    Parameters
    ----------
    dataset : Dataset
        Couplings (signs applied) with stage vectors and fixture codes.
    start : Calibration
        Starting values; every parameter that is not free keeps its value from here.
    mode : str or CalibrationMode
        One of :data:`~openemt.calibrate.MODES` (``XYZ``, ``concentric``, ``XYZ_all``, ...).
    select : bool
        Use only the rows the mode names (fixtures, patterns); ``False`` uses every row.
    optimize, freeze : sequence of str, optional
        Override the mode's free and frozen groups.
    max_nfev, tol : int, float
        Passed to ``least_squares`` (``ftol = xtol = gtol = tol``).
    uncertainty : bool
        Compute rank, condition and standard errors at the solution.
    warn : bool
        Warn when a free group is not determined by the data.

    Returns
    -------
    CalibrationFit

    Examples
    --------
    The paper's main calibration (``XYZ_hr_cal``) of the bundled recording, from its base
    calibration; the residue is the one stored in the authors' file:

    >>> import openemt
    >>> folder = openemt.datasets.path("cal_9_15_premo_cmu")
    >>> data = openemt.import_ilemt_folder(folder)
    >>> start = openemt.read_ilemt_calibration(folder / "base_calibration.mat")
    >>> result = openemt.fit_calibration(data, start, mode="XYZ")
    >>> result.calibration.stats["num_points"], round(result.calibration.stats["rms_residue"], 6)
    (426, 0.004847)

    References
    ----------
    MacLachlan et al. 2025 §VI; docs/ilemt-data.md#dipole-model, docs/paper-procedure.md#calibration-objective.
    """
    mode, opt, frz, data, layout, x0, free = _setup(dataset, start, mode, select, optimize,
                                                    freeze)
    prob = build_problem(data, layout, start.model.gain)
    groups = [g for g in opt if g not in frz]
    f = fit_problem(prob, x0, free, groups, tol=tol, max_nfev=max_nfev,
                    uncertainty=uncertainty, warn=warn)
    x, r, ident, se_full, seconds = (f.x, f.residuals, f.identifiability, f.standard_errors,
                                     f.seconds)
    stats = f.stats
    F_so, F_st, F_se = layout.fixtures(x)
    provenance = fit_provenance(mode.name, data, start_calibration=start)
    se = {k: v for k, v in layout.as_fields(se_full).items()} if uncertainty else {}
    cal = Calibration(model=layout.model(x, start.model.gain), source_fixture=F_so,
                      stage_fixture=F_st, sensor_fixture=F_se, linear_correction=None,
                      mode=mode.name, free=tuple(g for g in opt if g not in frz), frozen=frz,
                      standard_errors=se, stats=stats, provenance=provenance,
                      extra={k: v for k, v in start.extra.items()
                             if k not in ("rig", "rig_options")})
    return CalibrationFit(calibration=cal, mode=mode, layout=layout, problem=prob, x=x,
                          free=free, residuals=r, identifiability=ident,
                          nfev=int(f.result.nfev), seconds=seconds)

