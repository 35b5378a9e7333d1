"""``--environment``: which environment terms a calibration fits, and how they are chosen.

Environment terms (:mod:`openemt.field._environment`) model what the workspace and the
acquisition add to the tracker's own field: induced dipoles of nearby metal, a gain
non-linearity per sensor channel, a coupling offset, and the coils' tilt (a board's; a dipole
model fits its coil moments' directions anyway). ``--environment`` takes

* ``auto`` (the default): the terms are chosen by cross-validation on the training rows only
  (the improved rig model: forward selection on position-grouped folds of the md rows,
  :func:`openemt.calibrate.select_terms`; a board: every candidate of
  :data:`PLANAR_CANDIDATES` -- none, tilt, an induced dipole, both -- on interleaved folds of
  the fitted grid points, :func:`planar_environment_cv`); the choice and each candidate's
  held-out error go to the calibration's ``provenance["environment"]``;
* ``none``: no environment term;
* an explicit list such as ``dipoles:2,gain,tilt`` (``dipoles:K`` induced dipoles, ``gain``,
  ``offset``, ``tilt``).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from .._errors import InputError
from ..field._environment import axis_poses

__all__ = ["ENVIRONMENT_NAMES", "PLANAR_CANDIDATES", "BoardEnvironmentFit", "EnvironmentChoice",
           "EnvironmentFit", "fit_board_environment", "known_pose_errors",
           "WitnessEstimator", "fit_environment", "improved_environment", "parse_environment", "planar_environment_cv"]

#: The names an explicit ``--environment`` list takes.
ENVIRONMENT_NAMES = ("dipoles", "gain", "offset", "tilt")

#: Folds of the board's cross-validation over grid points.
PLANAR_FOLDS = 4


@dataclass(frozen=True)
class EnvironmentChoice:
    """A parsed ``--environment``: ``mode`` (``auto``, ``none`` or ``given``) and, when given,
    ``dipoles`` (count), ``gain``, ``offset``, ``tilt``."""

    mode: str = "auto"
    dipoles: int = 0
    gain: bool = False
    offset: bool = False
    tilt: bool = False

    def names(self) -> list:
        return ([f"dipoles:{self.dipoles}"] if self.dipoles else []) + \
            [n for n in ("gain", "offset", "tilt") if getattr(self, n)]

    def label(self) -> str:
        return self.mode if self.mode != "given" else (",".join(self.names()) or "none")


def parse_environment(text) -> EnvironmentChoice:
    """``--environment`` text -> :class:`EnvironmentChoice` (InputError naming what was
    expected).

    Examples
    --------
    >>> parse_environment("dipoles:2,gain,tilt").names()
    ['dipoles:2', 'gain', 'tilt']
    >>> parse_environment("auto").mode
    'auto'
    """
    if isinstance(text, EnvironmentChoice):
        return text
    t = str("auto" if text is None else text).strip().lower()
    if t in ("auto", "none"):
        return EnvironmentChoice(mode=t)
    out = {"dipoles": 0, "gain": False, "offset": False, "tilt": False}
    for part in (p.strip() for p in t.split(",")):
        name, _, count = part.partition(":")
        if name not in ENVIRONMENT_NAMES or (count and name != "dipoles"):
            raise InputError(f"expected --environment auto, none or a list of "
                             f"{', '.join(ENVIRONMENT_NAMES)} (dipoles:K for K induced "
                             f"dipoles), got {text!r}")
        if name == "dipoles":
            try:
                k = int(count) if count else 1
            except ValueError:
                k = -1
            if not 1 <= k <= 8:
                raise InputError(f"expected dipoles:K with K from 1 to 8 in --environment, "
                                 f"got {part!r}")
            out["dipoles"] = k
        else:
            out[name] = True
    return EnvironmentChoice(mode="given", **out)


def improved_environment(choice: EnvironmentChoice) -> dict:
    """Keyword arguments of :func:`openemt.calibrate.improved_calibration` for a choice:
    ``auto`` tries :data:`openemt.calibrate.TERMS` by md cross-validation (as ``reproduce
    table2 --improved``), ``none`` fits the improved model alone, a given list fits those
    terms (one induced dipole at most)."""
    import dataclasses

    from ._heldout import IMPROVED_OPTIONS, TERMS

    if choice.mode == "auto":
        return {"terms": TERMS}
    if choice.mode == "none":
        return {}
    return {"options": dataclasses.replace(IMPROVED_OPTIONS, induced=bool(choice.dipoles),
                                           gain_nonlinear=choice.gain,
                                           coupling_offset=choice.offset)}


#: Candidate term sets ``--environment auto`` compares on a board, by name, simplest first
#: (the order ties are broken in): the board's gains and offsets alone, with the coils' tilt,
#: with one induced dipole, with both.
PLANAR_CANDIDATES = {"none": {}, "tilt": {"tilt": True}, "dipoles:1": {"dipoles": 1},
                     "tilt,dipoles:1": {"tilt": True, "dipoles": 1}}


def known_pose_errors(model, points, axes, couplings, iterations: int = 8) -> np.ndarray:
    """Position errors (m) of single-coil samples solved from their known poses: each
    sample's couplings ``(N, n_source)`` fitted by batched Gauss-Newton started at the known
    position and axis, under any coupling model of a single-coil sensor (a board, a board
    with environment terms). The model's error, not a cold start's, is what this scores; the
    least-squares pose is the one the 5-DOF solver converges to from there. The steps are
    the minimum-norm solutions in the translation and a left rotation (the roll about the
    sensor axis is not seen), so no rotation vector's singularity is met (an axis along -z
    is a half turn)."""
    from scipy.spatial.transform import Rotation

    P = axis_poses(points, axes)
    C = np.asarray(couplings, dtype=np.float64).reshape(len(P), -1)
    for _ in range(int(iterations)):
        jac = model.jacobians(P, params=False)
        n = len(P)
        J = np.concatenate([jac.d_translation, jac.d_rotation], axis=-1).reshape(n, -1, 6)
        r = C - jac.C.reshape(n, -1)
        step = np.einsum("nam,nm->na", np.linalg.pinv(J, rcond=1e-10), r)
        P = P.copy()
        P[:, :3, 3] += step[:, :3]
        P[:, :3, :3] = Rotation.from_rotvec(step[:, 3:]).as_matrix() @ P[:, :3, :3]
        if np.max(np.abs(step)) < 1e-12:
            break
    e = np.linalg.norm(P[:, :3, 3] - np.asarray(points, dtype=np.float64), axis=1)
    return np.where(np.isfinite(e), e, np.nan)


def board_dipole_starts(points, margins=(0.1, 0.25)) -> np.ndarray:
    """Start positions of an induced dipole over a board: the corners, edge and face centres
    of the grid points' bounding box grown by each of ``margins`` (m) -- below (the board's
    side), beside and above the volume, never inside it."""
    pts = np.asarray(points, dtype=np.float64)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    mid = 0.5 * (lo + hi)
    signs = [np.array(s) for s in itertools.product((-1, 0, 1), repeat=3) if any(s)]
    return np.array([np.where(s < 0, lo - m, np.where(s > 0, hi + m, mid))
                     for m in margins for s in signs])


@dataclass(frozen=True, eq=False)
class BoardEnvironmentFit:
    """A board fitted with environment terms (:func:`fit_board_environment`): ``board``
    (the fit of the board's own parameters, a :class:`~openemt.calibrate.PlanarFit`),
    ``terms`` (None without) and ``model`` (the board with them: an
    :class:`~openemt.field.EnvironmentModel`; the board alone without terms)."""

    board: object
    terms: object
    model: object


def _joint_lsq(board_model, terms, P, C, groups, max_nfev: int = 30):
    """Least squares of a board's ``groups`` and the environment terms together."""
    from scipy.optimize import least_squares

    from ..field import EnvironmentModel

    m0 = EnvironmentModel(board_model, terms)
    x0 = m0.params
    nb = np.size(board_model.params)
    pg = board_model.parameter_groups
    free = np.r_[np.concatenate([pg[g] for g in groups]), np.arange(nb, x0.size)]
    scale = np.sqrt(np.mean(C ** 2)) or 1.0

    def model(v):
        x = x0.copy()
        x[free] = v
        return m0.with_params(x)

    res = least_squares(lambda v: ((C - model(v).coupling(P)) / scale).ravel(), x0[free],
                        jac=lambda v: -(model(v).jacobians(P, params=True).d_params[..., free]
                                        / scale).reshape(-1, free.size),
                        method="lm", x_scale="jac", max_nfev=max_nfev * (1 + free.size))
    return model(res.x)


def fit_board_environment(data, start_model, fit_board, *, tilt: bool = False,
                          dipoles: int = 1, board=None) -> BoardEnvironmentFit:
    """Fit a board with ``dipoles`` induced dipoles to grid ``data``: the board alone
    (``fit_board(data, start_model, tilt=tilt)``, or ``board``, a fit of it already made),
    the dipoles on its residual (each started from the best of :func:`board_dipole_starts`,
    its moments linear there, then refined with every term), the board refitted to the
    couplings less the induced ones, then the board's gains, offsets (and tilts) and the
    terms refined together by Levenberg-Marquardt; last the board is fitted once more to the
    couplings less the induced ones from there (its standard errors, given the terms). The
    induced couplings do not depend on the board's parameters (the induced field is read by
    the board's sensor coil)."""
    from dataclasses import replace as _replace

    P = axis_poses(data.points, data.axes)
    C = np.asarray(data.couplings, dtype=np.float64)[:, :, None]
    bf = fit_board(data, start_model, tilt=tilt) if board is None else board
    if not dipoles:
        return BoardEnvironmentFit(bf, None, bf.model)
    ef = _fit_environment(bf.model, P, C, dipoles=dipoles,
                          positions=board_dipole_starts(data.points))

    def less_induced(board_model, terms):
        from ..field import EnvironmentModel

        ind = EnvironmentModel(board_model, terms).coupling(P) - board_model.coupling(P)
        return _replace(data, couplings=data.couplings - ind[:, :, 0])

    bf = fit_board(less_induced(bf.model, ef.terms), bf.model, tilt=tilt)
    groups = ("gains", "offsets") + (("tilts_in_plane",) if tilt else ())
    joint = _joint_lsq(bf.model, ef.terms, P, C, groups)
    bf = fit_board(less_induced(joint.base, joint.terms), joint.base, tilt=tilt)
    return BoardEnvironmentFit(bf, joint.terms, type(joint)(bf.model, joint.terms))


#: The induced dipole candidates are cross-validated on a board only where one dipole, at the
#: best of :func:`board_dipole_starts` with its moments solved there, takes at least this
#: fraction of the sum of squares off the residual of the board fitted with tilt on the first
#: fold's training points: a dipole fitted to noise takes about its parameter count over the
#: residual's degrees of freedom (24 of 100-150 on the grids of the tests), metal within
#: reach of the volume most of it.
DIPOLE_GATE = 0.5


def dipole_residual_gain(board_model, data) -> float:
    """The fraction of the board's residual sum of squares on grid ``data`` one induced
    dipole removes at the best of :func:`board_dipole_starts` (moments solved linearly,
    position not refined): the cheap evidence for :data:`DIPOLE_GATE`."""
    P = axis_poses(data.points, data.axes)
    r = np.asarray(data.couplings, dtype=np.float64)[:, :, None] - board_model.coupling(P)
    ss0 = float(np.sum(r ** 2))
    if not ss0 > 0:
        return 0.0
    best = min(_moments_for(board_model, q, P, r, board_model.n_source)[-1]
               for q in board_dipole_starts(data.points))
    return 1.0 - best / ss0


#: Candidates whose cross-validated position RMS is within this fraction of the least one
#: tie, and the simplest of them is chosen: a more complex term set has to beat the simpler
#: ones by more than the noise of the comparison (fold-to-fold and point-to-point scatter of
#: a few percent on the grids of the tests).
CV_TIE = 0.02


def _choose(cands, scores) -> str:
    """The simplest candidate (``cands`` is ordered simplest first) whose cross-validated
    position RMS is within :data:`CV_TIE` of the least one."""
    rms = {k: scores[k]["cv_position_rms_mm"] for k in cands if k in scores}
    rms = {k: v for k, v in rms.items() if v is not None and np.isfinite(v)}
    if not rms:
        return next(iter(cands))
    best = min(rms.values())
    return next(k for k in cands if k in rms and rms[k] <= best * (1 + CV_TIE))


def _folds(points, folds: int) -> np.ndarray:
    """Interleaved folds: point ``i`` (in the grid's order) in fold ``i % folds``, so each
    fold's points lie between the others' as a checkerboard's held-out points do (blocks of
    the volume would score a dipole's extrapolation to a region no training point reached,
    which a grid's held-out points never ask of it)."""
    return np.arange(len(points)) % int(folds)


def planar_environment_cv(data, start_model, fit, *, folds: int = PLANAR_FOLDS,
                          candidates=None) -> tuple[str, dict]:
    """Cross-validate the board's candidate term sets on ``data`` (the grid points of the
    fit): interleaved folds (:func:`_folds`), each candidate fitted
    on the others (``fit(data, start_model, tilt=...)`` fits the board alone; induced
    dipoles are fitted over the same fold's board fit by :func:`fit_board_environment`) and
    its held-out points solved from their known poses (:func:`known_pose_errors`).

    Returns the chosen name (:func:`_choose`: the simplest candidate within
    :data:`CV_TIE` of the least pooled held-out position RMS) and ``{name:
    {"cv_position_rms_mm", "n"}}`` (with ``skipped``, the reason, where the dipole
    candidates were not tried: :data:`DIPOLE_GATE`).
    """
    cands = PLANAR_CANDIDATES if candidates is None else candidates
    fold = _folds(data.points, folds)

    boards, scores = {}, {}
    gate = None
    for name, terms in cands.items():
        tilt, k_dip = bool(terms.get("tilt")), int(terms.get("dipoles", 0))
        if k_dip:
            if gate is None:
                # over the most general board fit (with tilt): a dipole has to explain what
                # the coils' own terms cannot
                k0 = int(fold.min())
                tr = fold != k0
                if (k0, True) not in boards:
                    boards[k0, True] = fit(data.subset(tr), start_model, tilt=True)
                gate = dipole_residual_gain(boards[k0, True].model, data.subset(tr))
            if gate < DIPOLE_GATE:
                scores[name] = {"cv_position_rms_mm": None, "n": 0,
                                "skipped": f"one induced dipole takes {gate:.0%} of the "
                                           f"board's residual (< {DIPOLE_GATE:.0%})"}
                continue
        err = []
        for k in range(folds):
            train, test = fold != k, fold == k
            if train.sum() < 7 or not test.any():
                continue
            if (k, tilt) not in boards:
                boards[k, tilt] = fit(data.subset(train), start_model, tilt=tilt)
            m = boards[k, tilt].model if not k_dip else fit_board_environment(
                data.subset(train), start_model, fit, tilt=tilt, dipoles=k_dip,
                board=boards[k, tilt]).model
            err.append(known_pose_errors(m, data.points[test], data.axes[test],
                                         data.couplings[test]))
        e = np.concatenate(err) if err else np.zeros(0)
        ok = np.isfinite(e)
        scores[name] = {"cv_position_rms_mm": float(np.sqrt(np.mean(e[ok] ** 2)) * 1e3)
                        if ok.any() else None, "n": int(ok.sum())}
    return _choose(cands, scores), scores


@dataclass(frozen=True, eq=False)
class EnvironmentFit:
    """Environment terms fitted to couplings at known poses (:func:`fit_environment`):
    ``terms``, ``model`` (the base with them), ``rms`` (RMS coupling residual, the couplings'
    units), ``rms_base`` (the base model's alone), ``nfev`` and ``status`` (of the last
    least-squares run)."""

    terms: object
    model: object
    rms: float
    rms_base: float
    nfev: int
    status: int


#: Directions of the start positions of a new induced dipole (unit vectors: the 6 axes and the
#: 8 diagonals) and their distances from the centre of the collection's positions (m).
_START_DIRECTIONS = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1],
                              [0, 0, -1]] + [[a, b, c] for a in (-1, 1) for b in (-1, 1)
                                             for c in (-1, 1)], dtype=np.float64)
_START_DIRECTIONS /= np.linalg.norm(_START_DIRECTIONS, axis=1, keepdims=True)
_START_DISTANCES_M = (0.15, 0.3)


def _target(C, quadrature):
    """The couplings a fit matches: complex (phase-calibrated: in-phase real part,
    quadrature imaginary part) where ``quadrature`` says so (None: where they are complex
    with a quadrature part), else real (the signed real coupling of complex ones)."""
    from ..io import signed_real

    C = np.asarray(C)
    if np.iscomplexobj(C):
        if quadrature or (quadrature is None and np.any(C.imag)):
            return C.astype(np.complex128)
        return signed_real(C) if quadrature is None else C.real.astype(np.float64)
    return np.asarray(C, dtype=np.float64)


def _predict(m, P, complex_: bool):
    return m.complex_coupling(P) if complex_ else m.coupling(P)


class _HeldBase:
    """A base model held at fixed poses ``P``: its couplings there computed once, no
    parameters of its own, its sensor coils as point dipoles (what the induced dipoles are
    read by). The terms' least squares evaluate the model thousands of times at the same
    poses; a board's couplings are the costly part of each evaluation."""

    solver_family = "model"

    def __init__(self, base, P):
        from ..field._environment import sensor_dipoles

        self.gain, self.L_se, self.M_se = sensor_dipoles(base)
        self.n_source, self.n_sensor, self.kind = base.n_source, base.n_sensor, base.kind
        self.params = np.zeros(0)
        self._P = P
        self._C = np.asarray(base.coupling(P), dtype=np.float64)

    def coupling(self, P):
        if P is not self._P and not (np.shape(P) == self._P.shape
                                     and np.array_equal(P, self._P)):
            raise ValueError("a held base model is evaluated at its own poses only")
        return self._C

    def jacobians(self, P, params: bool = True):
        from ..field import ModelJacobians

        z = np.zeros(self._C.shape + (3,))
        return ModelJacobians(self.coupling(P).copy(), z, z,
                              np.zeros(self._C.shape + (0,)) if params else None)


def _lsq(base, terms, P, target, free_mask=None, max_nfev: int = 100):
    """Least squares of the environment terms alone (the base model held); a complex
    ``target`` is matched in phase and in quadrature."""
    from scipy.optimize import least_squares

    from ..field import EnvironmentModel
    from ..field._environment import MAX_DIPOLE_DISTANCE_M

    cplx = np.iscomplexobj(target)
    if cplx:
        terms = terms.with_phases()
    base = _HeldBase(base, P)
    nb = 0
    v0 = terms.vector()
    free = np.ones(v0.size, bool) if free_mask is None else free_mask
    scale = np.sqrt(np.mean(np.abs(target) ** 2)) or 1.0
    parts = (target.real, target.imag) if cplx else (target,)

    def model(v):
        full = v0.copy()
        full[free] = v
        return EnvironmentModel(base, terms.with_vector(full))

    K, size = terms.n_dipoles, terms.dipole_size
    n_res = target.size * len(parts)

    def fun(v):
        full = v0.copy()
        full[free] = v
        q = full[:K * size].reshape(K, size)[:, :3] if K else np.zeros((0, 3))
        if not np.abs(q).max(initial=0.0) <= MAX_DIPOLE_DISTANCE_M:
            # a trial step that carries a dipole out of range (one drifting away to mimic a
            # uniform field): a cost the step cannot win with, so LM rejects it and damps
            return np.full(n_res, 1e6)
        m = model(v)
        if not cplx:
            return ((target - m.coupling(P)) / scale).ravel()
        C = m.complex_coupling(P)
        return np.concatenate([((t - c) / scale).ravel()
                               for t, c in zip(parts, (C.real, C.imag))])

    def jac(v):
        m = model(v)
        J = m.jacobians(P, params=True).d_params[..., nb:][..., free]
        J = [J] + ([m.quadrature_jacobians(P)[1][..., free]] if cplx else [])
        return -np.concatenate([(j / scale).reshape(-1, int(free.sum())) for j in J])

    res = least_squares(fun, v0[free], jac=jac, method="lm", max_nfev=max_nfev * (1 + v0.size),
                        x_scale="jac")
    full = v0.copy()
    full[free] = res.x
    return terms.with_vector(full), res


def _moments_for(base, q, P, target, n_source):
    """The best moments of one dipole at ``q`` for the residual ``target`` (linear), and the
    residual's sum of squares after them; with a complex ``target`` also the phases (the
    complex moment ``mu exp(1j phi)`` of each source coil: the best rank-one fit of its
    least-squares complex moment, a real vector times a phase)."""
    from ..field import DipoleModel, coupling_jacobians
    from ..field._environment import sensor_dipoles

    gain, L, M = sensor_dipoles(base)
    d = DipoleModel(gain=gain, L_so=np.repeat(np.asarray(q, float)[:, None], n_source, axis=1),
                    M_so=np.ones((3, n_source)), L_se=L, M_se=M)
    dM = coupling_jacobians(d, P).d_M_so                       # (N, n_so, n_se, 3)
    cplx = np.iscomplexobj(target)
    mu = np.zeros((n_source, 3))
    ph = np.zeros(n_source)
    ss = 0.0
    for i in range(n_source):
        A = dM[:, i].reshape(-1, 3)
        b = target[:, i].ravel()
        if not cplx:
            sol, *_ = np.linalg.lstsq(A, b, rcond=None)
            mu[i] = sol
            ss += float(np.sum((b - A @ sol) ** 2))
            continue
        sol, *_ = np.linalg.lstsq(A, np.c_[b.real, b.imag], rcond=None)   # (3, 2)
        # rank one in the metric of A: A sol ~ (A v) [cos phi, sin phi]
        _, _, vt = np.linalg.svd(A @ sol, full_matrices=False)
        c = vt[0] if vt[0, 0] >= 0 else -vt[0]
        mu[i] = sol @ c
        ph[i] = np.arctan2(c[1], c[0])
        fit = (A @ mu[i])[:, None] * c
        ss += float(np.sum((b.real - fit[:, 0]) ** 2 + (b.imag - fit[:, 1]) ** 2))
    return (mu, ph, ss) if cplx else (mu, ss)


def fit_environment(model, poses, couplings, *, dipoles: int = 1, gain: bool = False,
                    offset: bool = False, start=None, max_nfev: int = 100,
                    quadrature: bool | None = None) -> EnvironmentFit:
    """Fit environment terms (:class:`openemt.field.EnvironmentTerms`) to ``couplings``
    ``(N, n_source, n_sensor)`` measured at known ``poses`` with the metal in place, the base
    ``model`` held (it is the tracker's clean calibration).

    Complex couplings are phase-calibrated (the in-phase part real, the quadrature
    imaginary): where they carry a quadrature part (``quadrature=None``, or always with
    ``quadrature=True``) the induced moments get a phase per source coil's carrier and the
    terms are fitted to both parts, so the model predicts the quadrature too
    (:meth:`openemt.field.EnvironmentModel.complex_coupling`); otherwise (real couplings,
    complex ones without quadrature) the moments are real and the fit is to the signed real
    coupling (``quadrature=False``: to the real part of complex couplings).

    Induced dipoles are added one at a time: the new one starts from the best of 28 positions
    around the collection (the 6 axes and 8 diagonals at 0.15 and 0.3 m from the centre of its
    positions; at each the moments are linear, solved exactly; over a board,
    :func:`fit_board_environment` starts from :func:`board_dipole_starts`), then every term
    is refined by Levenberg-Marquardt. ``start`` (terms) instead
    refines those terms from where they are (an online re-estimate, e.g. from witness
    sensors). ``rms`` and ``rms_base`` are over the complex residual's magnitude when the fit
    is complex.
    """
    return _fit_environment(model, poses, couplings, dipoles=dipoles, gain=gain,
                            offset=offset, start=start, max_nfev=max_nfev,
                            quadrature=quadrature)


def _start_positions(P) -> np.ndarray:
    centre = P[:, :3, 3].mean(axis=0)
    return np.array([centre + dist * u for dist in _START_DISTANCES_M
                     for u in _START_DIRECTIONS])


def _fit_environment(model, poses, couplings, *, dipoles=1, gain=False, offset=False,
                     start=None, max_nfev=100, quadrature=None, positions=None
                     ) -> EnvironmentFit:
    from ..field import EnvironmentModel, EnvironmentTerms

    P = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    target = _target(couplings, quadrature)
    cplx = np.iscomplexobj(target)
    base_rms = float(np.sqrt(np.mean(np.abs(target - model.coupling(P)) ** 2)))
    ns, ne = model.n_source, model.n_sensor
    cands = _start_positions(P) if positions is None else np.asarray(positions, float)
    if start is not None:
        terms, res = _lsq(model, start, P, target, max_nfev=max_nfev)
    else:
        terms = EnvironmentTerms(np.zeros((0, 3)), np.zeros((0, ns, 3)),
                                 np.zeros(ne) if gain else None,
                                 np.zeros((ns, ne)) if offset else None,
                                 np.zeros((0, ns)) if cplx else None)
        res = None
        if gain or offset:
            terms, res = _lsq(model, terms, P, target, max_nfev=max_nfev)
        for _ in range(int(dipoles)):
            resid = target - _predict(EnvironmentModel(model, terms), P, cplx) \
                if not terms.empty else target - model.coupling(P)
            best = None
            for q in cands:
                out = _moments_for(model, q, P, resid, ns)
                if best is None or out[-1] < best[0]:
                    best = (out[-1], q, out[:-1])
            _, q, got = best
            ph = None if not cplx else np.concatenate([terms.phases.reshape(-1, ns),
                                                       got[1][None]])
            terms = EnvironmentTerms(np.r_[terms.positions, q[None]],
                                     np.concatenate([terms.moments.reshape(-1, ns, 3),
                                                     got[0][None]]),
                                     terms.gain_beta, terms.offset, ph)
            terms, res = _lsq(model, terms, P, target, max_nfev=max_nfev)
    fitted = EnvironmentModel(model, terms) if not terms.empty else model
    pred = _predict(fitted, P, cplx) if not terms.empty else model.coupling(P)
    rms = float(np.sqrt(np.mean(np.abs(target - pred) ** 2)))
    return EnvironmentFit(terms, fitted, rms, base_rms, int(getattr(res, "nfev", 0)),
                          int(getattr(res, "status", 0)))


class WitnessEstimator:
    """Environment terms re-estimated online from fixed witness sensors at known poses (for a
    moving object: a C-arm, a tray carried through the workspace).

    ``update(couplings)`` takes the witnesses' couplings of one moment ``(n_witness, n_source,
    n_sensor)`` and returns the model to solve the tracked sensors with at that moment: the
    base ``model`` with ``dipoles`` induced dipoles refitted from the last moment's terms
    (:func:`fit_environment` with ``start``, ``max_nfev`` evaluations per parameter), or fitted
    afresh where the warm start does not bring the witnesses' residual below ``gain`` times
    the clean model's (the first moment, a jump). ``last`` is the last :class:`EnvironmentFit`.
    With ``n_witness * n_source * n_sensor`` equations for ``dipoles * (3 + 3 n_source)``
    unknowns, a 3 x 3 tracker needs two witnesses per dipole at least; four or more around the
    volume make it well posed.
    """

    def __init__(self, model, witness_poses, *, dipoles: int = 1, max_nfev: int = 20,
                 gain: float = 0.5):
        self.model = model
        self.poses = np.asarray(witness_poses, dtype=np.float64).reshape(-1, 4, 4)
        self.dipoles, self.max_nfev, self.gain = int(dipoles), int(max_nfev), float(gain)
        need = self.dipoles * (3 + 3 * model.n_source)
        if len(self.poses) * model.n_source * model.n_sensor < need:
            raise InputError(f"expected at least {need} witness couplings for {self.dipoles} "
                             f"induced dipole(s), got {len(self.poses)} witness(es) of "
                             f"{model.n_source * model.n_sensor}")
        self.last = None

    def update(self, couplings):
        f = None
        if self.last is not None and not self.last.terms.empty:
            f = fit_environment(self.model, self.poses, couplings, start=self.last.terms,
                                max_nfev=self.max_nfev)
        if f is None or not f.rms < self.gain * f.rms_base:
            f = fit_environment(self.model, self.poses, couplings, dipoles=self.dipoles)
        self.last = f
        return f.model
