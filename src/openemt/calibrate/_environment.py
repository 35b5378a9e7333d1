"""``--environment``: which environment terms a calibration fits, and how they are chosen.

Environment terms (:mod:`openemt.field._environment`) model what the workspace and the
acquisition add to the tracker's own field: induced dipoles of nearby metal, a gain
non-linearity per sensor channel, a coupling offset, and the coils' tilt (a board's; a dipole
model fits its coil moments' directions anyway). ``--environment`` takes

* ``auto`` (the default): the terms are chosen by cross-validation on the training rows only
  (the improved rig model: forward selection on position-grouped folds of the md rows,
  :func:`openemt.calibrate.select_terms`; a board: every candidate of
  :data:`PLANAR_CANDIDATES` on position-grouped folds of the fitted grid points); the choice and
  each candidate's held-out error go to the calibration's ``provenance["environment"]``;
* ``none``: no environment term;
* an explicit list such as ``dipoles:2,gain,tilt`` (``dipoles:K`` induced dipoles, ``gain``,
  ``offset``, ``tilt``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._errors import InputError

__all__ = ["ENVIRONMENT_NAMES", "PLANAR_CANDIDATES", "EnvironmentChoice", "EnvironmentFit",
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


#: Candidate term sets ``--environment auto`` compares on a board, by name.
PLANAR_CANDIDATES = {"none": {}, "tilt": {"tilt": True}}


def _pose_vectors(points, axes) -> np.ndarray:
    """Pose vectors ``(N, 6)`` at ``points`` whose z axis is ``axes`` (the shortest rotation
    from z; a half turn about x for -z)."""
    u = np.asarray(axes, dtype=np.float64)
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    w = np.cross([0.0, 0.0, 1.0], u)
    s = np.linalg.norm(w, axis=1)
    ang = np.arctan2(s, u[:, 2])
    k = np.where(s[:, None] > 1e-12, w / np.maximum(s, 1e-300)[:, None], [1.0, 0.0, 0.0])
    return np.c_[np.asarray(points, dtype=np.float64), k * ang[:, None]]


def known_pose_errors(model, points, axes, couplings) -> np.ndarray:
    """Position errors (m) of single-coil samples solved from their known poses: each
    sample's couplings ``(N, n_source)`` fitted by the batched Gauss-Newton of
    :func:`openemt.solve.refine_poses` started at the known position and axis, under any
    coupling model of a single-coil sensor (a board, a board with environment terms). The
    model's error, not a cold start's, is what this scores; the least-squares pose is the
    one the 5-DOF solver converges to from there."""
    from ..solve import refine_poses

    C = np.asarray(couplings, dtype=np.float64).reshape(len(points), -1, 1)
    v, _ = refine_poses(model, C, _pose_vectors(points, axes))
    e = np.linalg.norm(v[:, :3] - np.asarray(points, dtype=np.float64), axis=1)
    return np.where(np.all(np.isfinite(v), axis=1), e, np.nan)


def _folds(points, folds: int) -> np.ndarray:
    """Position-grouped folds: the points ordered along their widest axis, in blocks, the
    two halves of the blocks interleaved."""
    pts = np.asarray(points, dtype=np.float64)
    order = np.argsort(pts[:, int(np.argmax(np.ptp(pts, axis=0)))], kind="stable")
    fold = np.empty(len(pts), dtype=np.int64)
    fold[order] = np.arange(len(pts)) * folds // len(pts)
    return (fold + np.arange(len(pts)) % 2 * (folds // 2)) % folds


def planar_environment_cv(data, start_model, fit, *, folds: int = PLANAR_FOLDS,
                          candidates=None) -> tuple[str, dict]:
    """Cross-validate the board's candidate term sets on ``data`` (the grid points of the
    fit): folds of alternate regions of the volume (position-grouped), each candidate fitted
    on the others and its held-out points solved from their known poses
    (:func:`known_pose_errors`). ``fit(data, start_model, **terms)`` fits one and returns
    an object with ``model``.

    Returns the chosen name (least pooled held-out position RMS; ties go to the simpler,
    earlier candidate) and ``{name: {"cv_position_rms_mm", "n"}}``.
    """
    from ..solve import GridData

    cands = PLANAR_CANDIDATES if candidates is None else candidates
    fold = _folds(data.points, folds)

    def subset(mask):
        return GridData(data.points[mask], data.axes[mask], data.couplings[mask],
                        data.coil_names)

    scores = {}
    for name, terms in cands.items():
        err = []
        for k in range(folds):
            train, test = fold != k, fold == k
            if train.sum() < 7 or not test.any():
                continue
            f = fit(subset(train), start_model, **terms)
            err.append(known_pose_errors(f.model, data.points[test], data.axes[test],
                                         data.couplings[test]))
        e = np.concatenate(err) if err else np.zeros(0)
        e = e[np.isfinite(e)]
        scores[name] = {"cv_position_rms_mm": float(np.sqrt(np.mean(e ** 2)) * 1e3)
                        if e.size else None, "n": int(e.size)}
    finite = {k: v["cv_position_rms_mm"] for k, v in scores.items()
              if v["cv_position_rms_mm"] is not None and np.isfinite(v["cv_position_rms_mm"])}
    if not finite:
        return next(iter(cands)), scores
    best = min(finite.values())
    chosen = next(k for k in cands if k in finite and finite[k] <= best * (1 + 1e-9))
    return chosen, scores


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


def _lsq(base, terms, P, target, free_mask=None, max_nfev: int = 100):
    """Least squares of the environment terms alone (the base model held); a complex
    ``target`` is matched in phase and in quadrature."""
    from scipy.optimize import least_squares

    from ..field import EnvironmentModel

    cplx = np.iscomplexobj(target)
    if cplx:
        terms = terms.with_phases()
    nb = np.size(base.params)
    v0 = terms.vector()
    free = np.ones(v0.size, bool) if free_mask is None else free_mask
    scale = np.sqrt(np.mean(np.abs(target) ** 2)) or 1.0
    parts = (target.real, target.imag) if cplx else (target,)

    def model(v):
        full = v0.copy()
        full[free] = v
        return EnvironmentModel(base, terms.with_vector(full))

    def fun(v):
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
    positions; at each the moments are linear, solved exactly) or of ``positions`` when
    given, then every term is refined by Levenberg-Marquardt. ``start`` (terms) instead
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
