"""Held-out testing of improved calibrations and the ``--improved`` procedure.

Evidence for a model comes from the calibration (md) rows only: variants are compared by
cross-validation over md stage positions (each fold holds out whole grid points, so the test
positions are new, as the ld grid's are). The test files are used only to report errors.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np

from .._constants import ILEMT_POSITION_BOX_M
from .._result import Result
from ..evaluate import (
    ACCURACY_KEYS,
    STAGE_UNCERTAINTY_MM,
    error_breakdown,
    error_summary,
    pose_error_magnitudes,
    repeat_scatter,
)
from ..geometry import SOURCE_FIXTURES, pose_from_vector
from ..solve import refine_poses
from ._check import ILEMT_VALID_RESNORM
from ._identifiability import analyse_identifiability
from ._improved import ImprovedProblem, RigOptions, carry_parameters, fit_improved
from ._modes import MODES

__all__ = [
    "CANDIDATES",
    "IMPROVED_OPTIONS",
    "TERMS",
    "TERM_MAX_CONDITION",
    "TERM_MIN_GAIN",
    "CrossValidation",
    "ImprovedCalibration",
    "ImprovedTest",
    "ScoredPoses",
    "TermDecision",
    "cross_validate",
    "improved_calibration",
    "repeat_pairs",
    "select_terms",
    "solve_and_score",
    "transfer",
]

_SL = ("xy", "xz", "yz", "sx_sz", "sy_sz")

#: The ``--improved`` model: per-code sensor-fixture corrections, Rz angle scale and axis tilt,
#: octupoles of every source and sensor coil, and the stage's non-orthogonality and relative
#: axis scales (no uniform scale).
IMPROVED_OPTIONS = RigOptions(octupole_sensor=True, stage_linear=_SL)

#: Variants reported by cross-validation on md rows; the first is the paper's model.
CANDIDATES = {
    "paper": RigOptions(sensor_code_fix=False, rz_poly=0, rz_tilt=False, octupole_source=False),
    "fixture_codes": RigOptions(rz_poly=0, rz_tilt=False, octupole_source=False),
    "rig": RigOptions(octupole_source=False),
    "rig+octupole_source": RigOptions(),
    "rig+octupole": RigOptions(octupole_sensor=True),
    "improved": IMPROVED_OPTIONS,
}

#: Terms ``--improved`` tries on top of :data:`IMPROVED_OPTIONS`, in this order (RigOptions
#: changes; :mod:`openemt.calibrate._rig`): the Rz axis's error motions (second harmonic of
#: runout, wobble and angle error), the field induced in a conductive or magnetic object
#: (one dipole, a moment per carrier), a signal-level dependent gain per sensor channel and a
#: pose-independent coupling offset (crosstalk).
TERMS = {
    "rz_error_motion": {"rz_motion": 1},
    "induced_dipole": {"induced": True},
    "gain_nonlinearity": {"gain_nonlinear": True},
    "coupling_offset": {"coupling_offset": True},
}

#: Folds of the md cross-validation that decides on each term (whole grid positions held out).
SELECTION_FOLDS = 3

#: A term is kept when it lowers the md cross-validation translation RMS by at least this
#: fraction ...
TERM_MIN_GAIN = 0.01

#: ... and the fit with it is full rank with a column-scaled Jacobian condition below this.
TERM_MAX_CONDITION = 1e6


#: ``transfer(prob, x, rows)``: the problem of other ``rows`` with the fitted parameters ``x``
#: of ``prob`` (:func:`openemt.calibrate.carry_parameters`)
transfer = carry_parameters


@dataclass(frozen=True, eq=False)
class ScoredPoses(Result):
    """Rows solved with an improved model and scored against its ground truth.

    Attributes
    ----------
    trans, rot : ndarray, shape (N,)
        Error magnitudes (m, rad).
    summary : dict
        :func:`openemt.evaluate.error_summary` (mm, deg).
    positions : ndarray, shape (N, 3)
        Solved (and corrected, if a correction was given) positions (m).
    truth : ndarray, shape (N, 4, 4)
        Ground-truth poses of the model.
    residual : ndarray, shape (N,)
        Solution residuals.

    poses : ndarray, shape (N, 4, 4)
        Solved (and corrected) poses.

    ``to_dict()`` gives ``summary``.
    """

    _not_in_dict = ("trans", "rot", "positions", "truth", "residual", "poses")

    trans: np.ndarray
    rot: np.ndarray
    summary: dict
    positions: np.ndarray
    truth: np.ndarray
    residual: np.ndarray
    poses: np.ndarray | None = None

    def breakdown(self, rows):
        """:func:`openemt.evaluate.error_breakdown` of these errors on ``rows`` (the Dataset
        that was solved): by range, stage Rz and sensor fixture."""
        return error_breakdown(self.trans, self.rot, self.truth[:, :3, 3],
                               stage_rz=np.asarray(rows.stage)[:, 5],
                               sensor_fixture=rows.sensor_fixture)


@dataclass(frozen=True)
class CrossValidation(Result):
    """Pooled held-out errors of a position-grouped cross-validation.

    Attributes
    ----------
    trans_rms_mm, rot_rms_deg : float
        RMS of the finite held-out errors.
    n : int
        Held-out rows.
    """

    trans_rms_mm: float
    rot_rms_deg: float
    n: int


@dataclass(frozen=True)
class ImprovedTest(Result):
    """Table II rows of an improved calibration on test rows.

    Attributes
    ----------
    improved, improved_corrected : dict or None
        ``trans_rms_mm``, ``trans_max_mm``, ``rot_rms_deg``, ``rot_max_deg``,
        ``trans_uncert_mm`` (combined with the stage uncertainty) and ``n_invalid``;
        ``improved_corrected`` is None without an output correction.
    """

    improved: dict
    improved_corrected: dict | None


def solve_and_score(tp: ImprovedProblem, xt, rows, concentric_model, *, initial="kim18",
                    correction=None, model=None) -> ScoredPoses:
    """Solve ``rows`` with the improved model and score against its ground truth.

    The iterative dipole solution (Kim18 start from ``concentric_model``, hemisphere from the
    ground truth as ILEMT) is refined under the model a calibration file of the fit carries
    (:meth:`ImprovedProblem.full_model`: the octupole and environment terms, which predict
    the readings themselves), as ``openemt solve`` refines it; ``model`` (e.g. a written
    calibration's :attr:`~openemt.io.Calibration.coupling_model`) replaces it.
    """
    from ..solve import hemisphere_from_positions, solve_lm

    D = tp.poses(xt)
    model = tp.full_model(xt) if model is None else model
    dip = getattr(model, "dipole", model)
    hemi = hemisphere_from_positions(D[:, :3, 3])
    init = initial if isinstance(initial, str) else np.asarray(initial)
    couplings = rows.couplings
    res = solve_lm(couplings, dip, initial=init, hemisphere=hemi,
                   bounds=ILEMT_POSITION_BOX_M, concentric_model=concentric_model,
                   retry_resnorm=ILEMT_VALID_RESNORM)
    v, resid = res.pose_vectors, np.asarray(res.residual)
    if model is not dip:
        v, resid = refine_poses(model, couplings, v)
    return _score(tp, xt, pose_from_vector(v), D, resid, correction)


def _score(tp: ImprovedProblem, xt, M, D, resid, correction=None) -> ScoredPoses:
    """Solved poses ``M`` (with the output ``correction`` applied, if given) scored against
    the ground truth ``D`` of ``tp`` at ``xt``."""
    from ..correct import apply_linear_correction

    M = np.array(M, dtype=np.float64)
    if correction is not None:
        M[:, :3, 3] = apply_linear_correction(correction, M[:, :3, 3])
    F_se = tp.layout.fixtures(xt)[2]
    trans, rot = pose_error_magnitudes(M, D, sensor_fixture=F_se)
    return ScoredPoses(trans=trans, rot=rot, summary=error_summary(trans, rot),
                       positions=M[:, :3, 3], truth=D, residual=resid, poses=M)


def _fit(rows, start, options, initial=None):
    opt = (("so_fix",) if options.source_code_fix else ()) + MODES["XYZ"].optimize
    freeze = MODES["XYZ"].freeze
    if options.sensor_code_fix:
        # with a free translation per sensor-fixture code, shifting F_se along the Rz axis
        # (compensated by F_st and the codes' corrections) is a gauge: hold it, as Z_only does
        freeze = freeze + ("z_se_fix",)
    return fit_improved(rows, start, options, optimize=opt, freeze=freeze, initial=initial)


def cross_validate(md, start, options: RigOptions, concentric_model, *, folds: int = 3,
                   seed: int = 0, initial=None) -> CrossValidation:
    """Position-grouped K-fold cross-validation on calibration rows.

    Rows sharing a stage position (x, y, z) are held out together; the errors of every fold
    are pooled. ``initial`` (the fit of ``options`` on every row of ``md``, ``(problem, x)``)
    starts each fold's fit from it (:func:`openemt.calibrate.fit_improved`): the training
    rows alone decide where the fit converges, the start only shortens the way there.
    """
    return _cross_validate(md, start, options, concentric_model, folds, seed, initial)[0]


def _cross_validate(md, start, options, concentric_model, folds, seed=0, initial=None,
                    previous=None):
    """:func:`cross_validate`, and each fold's fit ``(problem, x)``. ``previous``: the fold
    fits of a model with fewer terms (same ``folds`` and ``seed``); each fold then starts
    from its parameters, the other terms' from ``initial``."""
    stage = md.stage if md.stage_logged is None else md.stage_logged
    key = np.round(stage[:, :3] * 1e4).astype(np.int64)
    _, group = np.unique(key, axis=0, return_inverse=True)
    group = group.ravel()
    rng = np.random.default_rng(seed)
    fold_of_group = rng.permutation(group.max() + 1) % folds
    fold = fold_of_group[group]
    trans, rot, fits = [], [], []
    for k in range(folds):
        train, test = md.select(fold != k), md.select(fold == k)
        start_k = initial
        if initial is not None and previous is not None:
            start_k = _overlay(initial, previous[k], train, options)
        f = _fit(train, start, options, start_k)
        prob, x = f.problem, f.x
        fits.append((prob, x))
        tp, xt = carry_parameters(prob, x, test)
        s = solve_and_score(tp, xt, test, concentric_model)
        trans.append(s.trans)
        rot.append(s.rot)
    s = error_summary(np.concatenate(trans), np.concatenate(rot))
    return CrossValidation(trans_rms_mm=s.trans_rms_mm, rot_rms_deg=s.rot_rms_deg,
                           n=s.n), fits


def _overlay(initial, previous, rows, options):
    """A start on ``rows`` under ``options``: the parameters of the fit ``previous`` (a model
    with fewer terms, on these rows) where it has them, those of ``initial`` for the rest."""
    tp, x0 = carry_parameters(*initial, rows, options)
    pp, px = previous
    _, xp = carry_parameters(pp, px, rows, options)
    x0[:tp.layout.size] = xp[:tp.layout.size]
    for name, sl in tp.extra.items():
        if pp.extra[name].stop - pp.extra[name].start == sl.stop - sl.start:
            x0[sl] = xp[sl]
    return tp, x0


@dataclass(frozen=True)
class TermDecision(Result):
    """Whether ``--improved`` kept a term of :data:`TERMS`, and why (md rows only).

    Attributes
    ----------
    term : str
    kept : bool
    reason : str
        One sentence with the evidence.
    md_cv_before, md_cv_after : dict
        :class:`CrossValidation` of the model without and with the term.
    rank, n_free : int
        Jacobian rank and free parameters of the fit with the term (all md rows).
    condition : float or None
        Column-scaled Jacobian condition of that fit (None when rank deficient).
    parameters : dict
        The term's fitted values and standard errors (``RigModel.to_dict`` entries).
    """

    term: str
    kept: bool
    reason: str
    md_cv_before: dict
    md_cv_after: dict
    rank: int
    n_free: int
    condition: float | None
    parameters: dict


def _flat(v) -> np.ndarray:
    """Numbers of a nested dict / list (a RigModel.to_dict entry), flattened."""
    if isinstance(v, dict):
        return np.concatenate([_flat(x) for x in v.values()] or [np.zeros(0)])
    return np.ravel(np.asarray(v, dtype=np.float64))


def _identified(f):
    """``(prob, x, free, ident, se)`` of a fit: its identifiability at the solution."""
    prob, x, free = f.problem, f.x, f.free
    r, J = prob.residuals_and_jacobian(x)
    ident = analyse_identifiability(J[:, free], r, free, prob.layout, (), warn=False)
    se = np.zeros(prob.size)
    se[free] = ident.standard_errors
    return prob, x, free, ident, se


def select_terms(md, start, concentric_model, *, base: RigOptions = IMPROVED_OPTIONS,
                 terms=None, folds: int = SELECTION_FOLDS):
    """Forward selection of :data:`TERMS` on calibration (md) rows only.

    Each term, in order, is added to the model kept so far and kept when (a) the
    position-grouped cross-validation translation RMS (:func:`cross_validate`) drops by at
    least :data:`TERM_MIN_GAIN` and (b) the fit with it on every md row is full rank with a
    condition below :data:`TERM_MAX_CONDITION`.

    Returns
    -------
    options : RigOptions
        ``base`` with the kept terms.
    decisions : list of TermDecision
    base_cv : CrossValidation
    fits : dict of str -> (ImprovedProblem, ndarray)
        The fit on every md row of the base model (``"base"``) and of each trial (the term's
        name), for the before/after scores.
    """
    return _select_terms(md, start, concentric_model, base, terms, folds)[:4]


def _select_terms(md, start, concentric_model, base, terms, folds):
    """:func:`select_terms`, and the chosen model's fit on every md row (an
    :class:`~openemt.calibrate.ImprovedFit`, or the :func:`_identified` tuple of a term's).

    Each fit on every md row starts from the model kept so far (the base from ``start``);
    each cross-validation fold of a term from the same fold's fit of the model kept so far,
    the term's own parameters from the fit on every md row (:func:`_cross_validate`).
    """
    terms = TERMS if terms is None else terms
    options = base
    kept_fit = _fit(md, start, options)
    warm = (kept_fit.problem, kept_fit.x)
    cv, folds_kept = _cross_validate(md, start, options, concentric_model, folds,
                                     initial=warm)
    base_cv, decisions = cv, []
    fits = {"base": warm}
    for name, change in terms.items():
        trial = dataclasses.replace(options, **change)
        fit_t = _identified(_fit(md, start, trial, warm))
        prob, x, free, ident, se = fit_t
        cv_t, folds_t = _cross_validate(md, start, trial, concentric_model, folds,
                                        initial=(prob, x), previous=folds_kept)
        fits[name] = (prob, x)
        cond = ident.to_dict()["condition"]
        gain = 1.0 - cv_t.trans_rms_mm / cv.trans_rms_mm
        full = ident.rank == ident.n_free and cond is not None and cond < TERM_MAX_CONDITION
        kept = bool(gain >= TERM_MIN_GAIN and full)
        ev = (f"md cross-validation {cv.trans_rms_mm:.3f} -> {cv_t.trans_rms_mm:.3f} mm "
              f"({-100 * gain:+.1f} %, needs <= {-100 * TERM_MIN_GAIN:.0f} %), rank "
              f"{ident.rank} of {ident.n_free}, condition "
              + (f"{cond:.3g}" if cond is not None else "inf"))
        params = {}
        if name in TERMS:           # the RigModel.to_dict entry of a term is named as it is
            params = {"value": prob.rig(x).to_dict()[name],
                      "standard_error": prob.rig(se).to_dict()[name]}
            v, e_ = _flat(params["value"]), _flat(params["standard_error"])
            weak = int(np.sum(np.abs(v) < 2 * e_))
            if weak:
                ev += (f"; {weak} of {v.size} of its parameters within 2 standard errors of "
                       "zero")
        reason = ("kept: " if kept else "not kept: ") + ev
        decisions.append(TermDecision(
            term=name, kept=kept, reason=reason, md_cv_before=cv.to_dict(),
            md_cv_after=cv_t.to_dict(), rank=ident.rank, n_free=ident.n_free, condition=cond,
            parameters=params))
        if kept:
            options, cv, kept_fit, warm, folds_kept = trial, cv_t, fit_t, fit_t[:2], folds_t
    return options, decisions, base_cv, fits, kept_fit


def repeat_pairs(a, b) -> tuple[np.ndarray, np.ndarray]:
    """Rows of datasets ``a`` and ``b`` at the same logged stage vector, source and sensor
    fixture (e.g. an md and an ld row of one grid point and angle): index arrays ``(i, j)``.
    Null rows (all-zero stage) are left out."""
    def keys(d):
        st = np.asarray(d.stage if d.stage_logged is None else d.stage_logged)
        q = np.round(st * 1e5).astype(np.int64)
        so = np.asarray(d.source_fixture).astype(str)
        se = np.asarray(d.sensor_fixture).astype(str)
        return [(tuple(v), c1, c2) if np.any(v) else None for v, c1, c2 in zip(q, so, se)]

    first = {}
    for i, k in enumerate(keys(a)):
        if k is not None:
            first.setdefault(k, i)
    pairs = [(first[k], j) for j, k in enumerate(keys(b)) if k is not None and k in first]
    if not pairs:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    i, j = np.array(pairs, dtype=np.int64).T
    return i, j


@dataclass(frozen=True, eq=False)
class ImprovedCalibration:
    """The improved calibration chosen and fitted on calibration rows.

    Attributes
    ----------
    name : str
        Chosen candidate (key of :data:`CANDIDATES`).
    options : RigOptions
    problem : ImprovedProblem
        Problem of the calibration rows.
    x : ndarray
        Fitted parameters (layout vector followed by the extra blocks).
    n_free : int
    rms_residue : float
    selection : dict of str -> CrossValidation
        Cross-validation result of every candidate (md rows only).
    correction : ndarray (4, 4) or None
        DLT output correction fitted on the calibration rows (docs/paper-procedure.md#output-correction).
    correction_stats : dict
    concentric_model : DipoleModel
        Model of the Kim18 start.
    identifiability : dict
        Jacobian rank and condition at the solution and the standard errors of the extra
        parameters (``rig_standard_errors``, shaped like ``rig``).
    terms : list of TermDecision
        The terms of :data:`TERMS` tried on md rows, kept or not (empty when none were tried).
    steps : dict of str -> (ImprovedProblem, ndarray)
        The md fit of the base model and of the model with each term tried, in order (for the
        before/after breakdown of :meth:`step_breakdowns`).
    md_scored : ScoredPoses or None
        The calibration rows solved with the final model (uncorrected).
    md_rows : Dataset or None
        The calibration rows.
    """

    name: str
    options: RigOptions
    problem: ImprovedProblem
    x: np.ndarray
    n_free: int
    rms_residue: float
    selection: dict
    correction: np.ndarray | None
    correction_stats: dict
    concentric_model: object
    identifiability: dict = field(default_factory=dict)
    seconds: dict = field(default_factory=dict)
    terms: list = field(default_factory=list)
    steps: dict = field(default_factory=dict)
    md_scored: object = None
    md_rows: object = None

    def noise_floor(self, rows, concentric_model=None):
        """Repeat-pose scatter (:func:`openemt.evaluate.repeat_scatter`) of the calibration
        rows and the ``rows`` measured at the same stage vector and fixtures
        (:func:`repeat_pairs`), both solved with this model: the noise floor of the data."""
        cm = self.concentric_model if concentric_model is None else concentric_model
        i, j = repeat_pairs(self.md_rows, rows)
        if i.size == 0:
            return repeat_scatter(np.zeros((0, 4, 4)), np.zeros((0, 4, 4)))
        sub = rows.select(j)
        tp, xt = carry_parameters(self.problem, self.x, sub)
        s = solve_and_score(tp, xt, sub, cm)
        return repeat_scatter(self.md_scored.poses[i], s.poses)

    def step_breakdowns(self, rows, concentric_model=None) -> dict:
        """Held-out breakdown (:meth:`ScoredPoses.breakdown`) of ``rows`` before and after each
        term tried: ``{step: {"kept": bool, "summary": ..., "breakdown": ...}}``, the first step
        the base model. Scores only: nothing is chosen from them."""
        cm = self.concentric_model if concentric_model is None else concentric_model
        kept = {d.term: d.kept for d in self.terms}
        out = {}
        for label, (prob, x) in self.steps.items():
            tp, xt = carry_parameters(prob, x, rows)
            s = solve_and_score(tp, xt, rows, cm)
            out[label] = {"kept": kept.get(label.rsplit("+", 1)[-1], True),
                          "summary": {k: s.summary[k] for k in ("trans_rms_mm", "rot_rms_deg")},
                          "breakdown": s.breakdown(rows).to_dict()}
        return out

    def extra_parameters(self) -> int:
        """Number of fitted parameters beyond the paper's XYZ mode (35 for 3 x 3 coils)."""
        paper = self.problem.layout.free_indices(MODES["XYZ"].optimize, MODES["XYZ"].freeze)
        return int(self.n_free - paper.size)

    def test(self, rows, concentric_model=None) -> ImprovedTest:
        """Rows ``improved`` and ``improved_corrected`` on test rows (errors as Table II),
        solved with the model of the calibration :meth:`to_calibration` writes (its
        ``coupling_model``: octupole and environment terms) and its output correction."""
        cm = self.concentric_model if concentric_model is None else concentric_model
        tp, xt = carry_parameters(self.problem, self.x, rows)
        cal = self.to_calibration()
        out = {}
        # one solve: the corrected row applies the output correction to the same poses
        plain = solve_and_score(tp, xt, rows, cm, model=cal.coupling_model)
        for name, corr in (("improved", None), ("improved_corrected", cal.linear_correction)):
            if name == "improved_corrected" and corr is None:
                out[name] = None
                continue
            res = plain if corr is None else _score(tp, xt, plain.poses, plain.truth,
                                                    plain.residual, corr)
            s = res.summary
            out[name] = {k: s[k] for k in ACCURACY_KEYS}
            out[name]["trans_uncert_mm"] = float(np.hypot(s["trans_rms_mm"],
                                                          STAGE_UNCERTAINTY_MM))
            resid = np.asarray(res.residual)
            out[name]["n_invalid"] = int(np.sum(~(np.isfinite(resid) & (resid < ILEMT_VALID_RESNORM))))
        return ImprovedTest(**out)

    def to_calibration(self, start=None):
        """The dipole part, fixtures and correction as a :class:`~openemt.io.Calibration`.

        The extra rig and octupole parameters go to ``extra["rig"]``;
        :func:`openemt.solve.solve` (and ``openemt solve``) uses the octupole terms through
        :attr:`~openemt.io.Calibration.coupling_model`.
        """
        from .. import __version__
        from ..io import Calibration

        lay = self.problem.layout
        F = lay.fixtures(self.x)
        n = self.problem.base.n_rows
        r = self.problem.residuals(self.x)
        prov = {"openemt_version": __version__, "mode": "improved",
                "start": None if start is None else {"mode": start.mode},
                "environment": self.environment_provenance()}
        terms = self.problem.rig(self.x).environment()
        return Calibration(
            model=lay.model(self.x, self.problem.base.gain), source_fixture=F[0],
            stage_fixture=F[1], sensor_fixture=F[2], linear_correction=self.correction,
            mode="improved", free=MODES["XYZ"].optimize + ("rig",), frozen=MODES["XYZ"].freeze,
            stats={"rms_residue": self.rms_residue, "sum_squared_residue": float(r @ r),
                   "num_points": int(n), "n_free": self.n_free, **{
                       k: v for k, v in self.correction_stats.items()}},
            provenance=prov,
            extra={"rig": self.problem.rig(self.x).to_dict(),
                   "rig_options": self.to_dict()["options"],
                   **({} if terms.empty else {"environment": terms.to_dict()})})

    def environment_provenance(self) -> dict:
        """How the environment terms were chosen: ``chosen`` (their names), ``method``
        (``cross-validation`` of the terms tried, or ``given``) and per term tried its md
        cross-validation before and after and whether it was kept (the held-out evidence)."""
        terms = self.problem.rig(self.x).environment()
        return {"chosen": terms.names(),
                "method": "cross-validation" if self.terms else "given",
                "candidates": [{"term": d.term, "kept": d.kept,
                                "cv_trans_rms_mm_before": d.md_cv_before["trans_rms_mm"],
                                "cv_trans_rms_mm_after": d.md_cv_after["trans_rms_mm"],
                                "reason": d.reason} for d in self.terms]}

    def to_dict(self) -> dict:
        """JSON-ready summary: variant, options, parameter counts, residue, the rig's
        parameters, identifiability, cross-validation, output correction, seconds."""
        rig = self.problem.rig(self.x).to_dict()
        return {"variant": self.name, "options": self.options.__dict__ | {
                    "stage_linear": list(self.options.stage_linear)},
                "n_free": self.n_free, "extra_parameters": self.extra_parameters(),
                "rms_residue": self.rms_residue, "rig": rig,
                "identifiability": self.identifiability,
                "selection_cv_md": {k: v.to_dict() for k, v in self.selection.items()},
                "correction": self.correction_stats,
                "terms": [d.to_dict() for d in self.terms],
                "seconds": self.seconds}


def improved_calibration(dataset, start, concentric_model, *, options=IMPROVED_OPTIONS,
                         name: str = "improved", candidates=None, folds: int = 9,
                         terms=None) -> ImprovedCalibration:
    """The ``--improved`` procedure: fit the improved model on the md rows of the home source
    fixture and the DLT output correction on the same rows (docs/paper-procedure.md#output-correction).

    Parameters
    ----------
    dataset : Dataset
        A whole ILEMT folder (only its home-source md rows are used).
    start : Calibration
        The paper's XYZ calibration (starting values).
    concentric_model : DipoleModel
        The concentric calibration's model (Kim18 start of the pose solver).
    options : RigOptions
        The model (default :data:`IMPROVED_OPTIONS`, fixed in advance for every folder).
    candidates : dict of str -> RigOptions, optional
        Also report position-grouped cross-validation of these variants on the md rows
        (``selection``); nothing is chosen from it.
    terms : dict of str -> dict, optional
        Terms tried on top of ``options`` by :func:`select_terms` (e.g. :data:`TERMS`); the
        model fitted is ``options`` with the kept ones, and ``name`` gets ``+term`` for each.
    """
    from ..correct import fit_dlt
    from ..geometry import vector_from_pose

    md = dataset.select(dataset.mask(pattern="md", source_fixture=SOURCE_FIXTURES[0]))
    t0 = time.perf_counter()
    selection = {k: cross_validate(md, start, o, concentric_model, folds=folds)
                 for k, o in (candidates or {}).items()}
    decisions, steps, chosen = [], {}, None
    if terms:
        options, decisions, _, fits, chosen = _select_terms(md, start, concentric_model,
                                                            options, terms, SELECTION_FOLDS)
        label = name
        steps[label] = fits["base"]
        for d in decisions:
            steps[f"{label}+{d.term}"] = fits[d.term]
            if d.kept:
                label = f"{label}+{d.term}"
        name = label
    t_sel = time.perf_counter() - t0
    t0 = time.perf_counter()
    if chosen is None:
        chosen = _fit(md, start, options)
    prob, x, free, ident, se = chosen if isinstance(chosen, tuple) else _identified(chosen)
    r = prob.residuals(x)
    # output correction on the calibration rows, solved from the truth (docs/paper-procedure.md#output-correction)
    D = prob.poses(x)
    s = solve_and_score(prob, x, md, concentric_model, initial=vector_from_pose(D))
    md_scored = solve_and_score(prob, x, md, concentric_model)
    ok = np.isfinite(s.residual) & (s.residual < ILEMT_VALID_RESNORM)
    corr, cstats = None, {"n_invalid": int((~ok).sum())}
    if ok.sum() >= 0.75 * len(ok):
        d = fit_dlt(s.positions[ok], D[ok, :3, 3])
        corr = np.asarray(d.matrix)
        cstats.update(method=str(d.method), uncorrected_mm=float(d.rms_uncorrected) * 1e3,
                      corrected_mm=float(d.rms_corrected) * 1e3)
    return ImprovedCalibration(
        name=name, options=options, problem=prob, x=x, n_free=int(free.size),
        rms_residue=float(np.sqrt(r @ r / prob.base.n_rows)), selection=selection,
        correction=corr, correction_stats=cstats, concentric_model=concentric_model,
        identifiability={"rank": ident.rank, "n_free": ident.n_free,
                         "condition": ident.to_dict()["condition"],
                         "rig_standard_errors": prob.rig(se).to_dict()},
        seconds={"cross_validation": t_sel, "fit_and_correction": time.perf_counter() - t0},
        terms=decisions, steps=steps, md_scored=md_scored, md_rows=md)
