"""Levenberg-Marquardt pose solving for any coupling model (:class:`openemt.field.CouplingModel`).

The dipole model and the 5-DOF board have compiled solvers of their own
(:mod:`openemt.solve._lm`, :mod:`openemt.solve._planar`); every other model -- a board read by a
multi-coil 6-DOF sensor, a model added later -- is solved here from the interface alone: the
model's couplings and pose Jacobian, batched over samples with numpy, one damping factor per
sample (Marquardt 1963 scaling). The residual is the coupling misfit divided by the measured
norm, and every sample is judged by the one validity rule (:mod:`openemt.solve._validity`).

Starts: given poses or pose vectors, ``'track'`` (blocks of samples start from the last
converged pose of the previous block; a sample that fails from there is solved again cold) and
``'cold'`` (every sample from the model's own cold start: :func:`sensor_coil_starts` for a
board with a multi-coil sensor).
"""

from __future__ import annotations

import numpy as np

from .._errors import InputError
from ..geometry import nearest_rotation, pose_from_rt, pose_from_vector, vector_from_pose
from ._planar import _rule_options
from ._result import SolveResult, Status
from ._validity import check_validity_options, classify

__all__ = ["ModelSolver", "PackedModelSolver", "coil_solvers", "sensor_coil_starts"]

#: Samples solved together from one start while tracking.
TRACK_BLOCK = 32


#: Rolls tried about a coil's measured axis when the sensor's other coils gave no 5-DOF fit.
N_ROLLS = 24


def _align(a, u) -> np.ndarray:
    """Rotations ``(N, 3, 3)`` taking the unit vector ``a`` (3,) to each ``u`` (N, 3) by the
    smallest angle."""
    from ..geometry import rotvec_between

    v = np.concatenate([np.zeros((len(u), 3)), rotvec_between(a, u)], axis=1)
    return pose_from_vector(v)[:, :3, :3]


def _roll_starts(model, C, p, u, k):
    """Best of :data:`N_ROLLS` poses whose coil ``k`` sits at ``p`` (N, 3) with axis ``u``
    (N, 3), turned about that axis: the one whose couplings fit ``C`` best."""
    a = model.board.sensor.coil_axes()[k]
    lk = model.board.sensor.coil_positions()[k]
    R0 = _align(a, u)
    n = len(C)
    best = np.full(n, np.inf)
    out = np.full((n, 4, 4), np.nan)
    for th in np.linspace(0.0, 2 * np.pi, N_ROLLS, endpoint=False):
        Rr = pose_from_vector(np.concatenate([np.zeros((n, 3)), u * th], axis=1))[:, :3, :3]
        R = Rr @ R0
        P = pose_from_rt(R, p - np.einsum("nab,b->na", R, lk))
        r = np.linalg.norm((model.coupling(P) - C).reshape(n, -1), axis=1)
        take = r < best
        best[take], out[take] = r[take], P[take]
    return out


def coil_solvers(model, options=None) -> list:
    """The 5-DOF board solvers (:class:`~openemt.solve._planar.PreparedPlanar`) of each
    sensor coil of ``model`` alone, prepared once for :func:`sensor_coil_starts`."""
    from ._planar import PreparedPlanar

    kw = {} if options is None else options
    return [PreparedPlanar(model.sensor_coil_model(k), **kw) for k in range(model.n_sensor)]


def sensor_coil_starts(model, couplings, options=None, solvers=None):
    """Cold starts ``(N, 4, 4)`` for a board read by a sensor of several coils: each coil is
    solved on its own by the 5-DOF board solver (position and axis), the rotation is the one
    that best takes the sensor's coil axes (and their cross product) to the measured axes, and
    the position the mean of the coil positions less their rotated offsets. Where only some
    coils have a 5-DOF fit, the pose is the best of :data:`N_ROLLS` rolls about the first such
    coil's axis; rows where no coil has one are NaN. ``solvers``: the coils' solvers of
    :func:`coil_solvers` (``options`` are theirs), made here if not given."""
    C = np.asarray(couplings, dtype=np.float64)
    n, ne = C.shape[0], model.n_sensor
    if solvers is None:
        solvers = coil_solvers(model, options)
    p = np.empty((n, ne, 3))
    u = np.empty((n, ne, 3))
    coil_ok = np.zeros((n, ne), bool)
    for k in range(ne):
        res = solvers[k].solve(C[:, :, k], "grid")
        coil_ok[:, k] = res.status == int(Status.CONVERGED)
        p[:, k] = res.poses[:, :3, 3]
        u[:, k] = res.poses[:, :3, 2]
    ok = coil_ok.all(axis=1)
    A = model.board.sensor.coil_axes()
    L = model.board.sensor.coil_positions()
    body = np.vstack([A, np.cross(A[0], A[1]) / np.linalg.norm(np.cross(A[0], A[1]))])
    x = np.cross(u[:, 0], u[:, 1])
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    # the rotations taking the body vectors closest to the measured ones
    R = nearest_rotation(np.einsum("nka,kb->nab", np.concatenate([u, x[:, None]], axis=1), body))
    t = (p - np.einsum("nab,kb->nka", R, L)).mean(axis=1)
    P = pose_from_rt(R, t)
    P[~ok] = np.nan
    for k in range(ne):                       # some coils fitted: roll about the first one
        rows = np.flatnonzero(~ok & coil_ok[:, k] & ~coil_ok[:, :k].any(axis=1))
        if rows.size:
            P[rows] = _roll_starts(model, C[rows], p[rows, k], u[rows, k], k)
    return P


class ModelSolver:
    """Batched Levenberg-Marquardt for any coupling model (see the module docstring).

    Parameters
    ----------
    model : coupling model
    options : SolveOptions
        ``max_iter`` (default 50), ``xtol`` (default 1e-9, as the board solver: the step in
        m / rad below which a sample has converged), ``max_relative_residual``, ``max_range``, ``bounds`` (a position
        box half-width, m), ``hemisphere`` (default: the board's front side, if the model is a
        board of one coil normal), ``retry_resnorm`` (a converged sample above this ILEMT
        resnorm is solved again cold, as a failed one is) and ``initial`` (default
        ``'track'``).
    """

    serial = True

    def __init__(self, model, options):
        from ._hemisphere import hemisphere_vectors
        from ._options import DEFAULT

        refused = options.changed(("retries", "explore_above",
                                   "concentric_model", "covariance", "fallback"))
        if refused:
            raise InputError(f"expected no {', '.join(refused)} with a {model.kind!r} model "
                             f"(options of the dipole LM solver), got them set")
        self.model = model
        self.options = options
        self.n_source, self.n_sensor, self.dof = model.n_source, model.n_sensor, model.dof
        self.max_iter = 50 if options.max_iter is None else int(options.max_iter)
        self.xtol = 1e-9 if options.xtol is None else float(options.xtol)
        max_rel, max_rng = check_validity_options(options.max_relative_residual,
                                                  options.max_range)
        h = options.hemisphere
        if h is None or (isinstance(h, str) and h == "none"):
            self.nvec = np.zeros(3)
        elif isinstance(h, str) and h == DEFAULT:
            self.nvec = np.asarray(getattr(model, "front", np.zeros(3)), dtype=np.float64)
        elif isinstance(h, str) or np.shape(h) == (3,):
            self.nvec = hemisphere_vectors(h, 1, allow_none=False)[0]
        else:                                            # one per sample: checked per call
            self.nvec = h
        b = np.inf if options.bounds is None else float(options.bounds)
        self.box = np.ascontiguousarray(np.stack([np.full(3, -b), np.full(3, b)]))
        tol = 1e-9 if options.ambiguity_tol is None else options.ambiguity_tol
        self.rule = _rule_options(tol, max_rel, max_rng)   # the board solver's rule
        self.retry_resnorm = options.retry_resnorm
        self._initial = "track" if options.initial is None else options.initial
        self.cold_start = model.cold_start
        self._coil_solvers = None            # prepared at the first cold start
        if isinstance(self._initial, str) and self._initial not in ("track", "cold"):
            raise InputError(f"expected initial 'track', 'cold' or start poses for a "
                             f"{model.kind!r} model, got {self._initial!r}")

    # -- starts ------------------------------------------------------------------------------
    def cold_starts(self, C) -> np.ndarray:
        if hasattr(self.model, "sensor_coil_model") and self.n_sensor > 1:
            # a start need only be near: the coils' 5-DOF fits are accepted up to 50 % misfit
            if self._coil_solvers is None:
                self._coil_solvers = coil_solvers(self.model, {"max_relative_residual": 0.5})
            return sensor_coil_starts(self.model, C, solvers=self._coil_solvers)
        raise InputError(f"expected start poses for a {self.model.kind!r} model with "
                         f"{self.n_sensor} sensor coil(s) (it has no cold start), got none")

    # -- the iteration -----------------------------------------------------------------------
    def refine(self, C, start_vectors):
        """LM from start pose vectors ``(N, 6)``: vectors, hit-the-limit flags, relative
        residuals and iterations. One model evaluation per iteration: the Jacobian of a trial
        point is computed with its couplings and kept when the step is taken."""
        n = len(C)
        x = np.array(start_vectors, dtype=np.float64)
        Cf = C.reshape(n, -1)
        norm = np.linalg.norm(Cf, axis=1)
        w = np.where(norm > 0, 1.0 / np.where(norm > 0, norm, 1.0), 0.0)
        lam = np.full(n, 1e-3)
        iters = np.zeros(n, np.int32)
        done = ~np.all(np.isfinite(x), axis=1)
        cost = np.full(n, np.inf)
        m = Cf.shape[1]
        J = np.zeros((n, m, 6))
        r = np.zeros((n, m))

        def evaluate(v, rows):
            jac = self.model.jacobians(pose_from_vector(v), params=False)
            Jv = jac.pose_vector(v[:, 3:]).reshape(len(rows), m, 6) * w[rows, None, None]
            rv = (Cf[rows] - jac.C.reshape(len(rows), m)) * w[rows, None]
            return Jv, rv, np.einsum("nm,nm->n", rv, rv)

        act = np.flatnonzero(~done)
        if act.size:
            J[act], r[act], cost[act] = evaluate(x[act], act)
        done |= ~np.isfinite(cost)
        eye = np.eye(6)
        for _ in range(self.max_iter):
            act = np.flatnonzero(~done)
            if not act.size:
                break
            Ja, ra = J[act], r[act]
            JtJ = np.einsum("nma,nmb->nab", Ja, Ja)
            g = np.einsum("nma,nm->na", Ja, ra)
            diag = np.maximum(np.einsum("naa->na", JtJ), 1e-30)
            A = JtJ + lam[act, None, None] * diag[:, :, None] * eye
            try:
                dx = np.linalg.solve(A, g[..., None])[..., 0]
            except np.linalg.LinAlgError:
                dx = np.stack([np.linalg.lstsq(a, b, rcond=None)[0] for a, b in zip(A, g)])
            trial = x[act] + dx
            Jt, rt, new = evaluate(trial, act)
            better = np.isfinite(new) & (new < cost[act])
            iters[act] += 1
            take = act[better]
            x[take], J[take], r[take], cost[take] = trial[better], Jt[better], rt[better], \
                new[better]
            lam[act] = np.where(better, np.maximum(lam[act] / 10, 1e-12),
                                np.minimum(lam[act] * 10, 1e12))
            small = np.linalg.norm(dx, axis=1) < self.xtol
            # converged: a step below xtol (taken, or refused because nothing smaller helps)
            done[act[small | (lam[act] >= 1e12)]] = True
        hit = ~done
        rho = np.sqrt(cost)
        return x, hit, rho, iters

    def _judge(self, x, hit, rho, nvec) -> np.ndarray:
        status = np.empty(len(x), np.int8)
        for i in range(len(x)):
            if not np.all(np.isfinite(x[i])):
                status[i] = int(Status.NOT_CONVERGED)
                continue
            status[i] = classify(bool(hit[i]), float(rho[i]), np.ascontiguousarray(x[i, :3]),
                                 np.ascontiguousarray(nvec[i]), self.box, self.rule)
        return status

    def _solve_from(self, C, start_vectors, nvec):
        x, hit, rho, iters = self.refine(C, start_vectors)
        return x, self._judge(x, hit, rho, nvec), rho, iters

    def __call__(self, couplings, initial=None) -> SolveResult:
        C = np.asarray(couplings)
        if np.iscomplexobj(C):
            from ..io import signed_real

            C = signed_real(C)
        C = np.asarray(C, dtype=np.float64)
        if C.ndim != 3 or C.shape[1:] != (self.n_source, self.n_sensor):
            raise InputError(f"expected couplings of shape (N, {self.n_source}, "
                             f"{self.n_sensor}), got {np.shape(couplings)}")
        n = len(C)
        bad = ~np.all(np.isfinite(C.reshape(n, -1)), axis=1) | ~np.any(C.reshape(n, -1), axis=1)
        start = self._initial if initial is None else initial
        x = np.full((n, 6), np.nan)
        status = np.full(n, int(Status.INVALID_INPUT), np.int8)
        rho = np.full(n, np.nan)
        iters = np.zeros(n, np.int32)
        good = np.flatnonzero(~bad)
        if isinstance(self.nvec, np.ndarray) and self.nvec.shape == (3,):
            nvec = np.broadcast_to(self.nvec, (n, 3))
        else:
            from ._hemisphere import hemisphere_vectors

            nvec = hemisphere_vectors(self.nvec, n, allow_none=False)
        self._nvec = nvec
        if isinstance(start, str):
            if start == "cold":
                v0 = vector_from_pose(self.cold_starts(C[good])) if good.size else x[:0]
                x[good], status[good], rho[good], iters[good] = self._solve_from(
                    C[good], v0, nvec[good])
            elif start == "track":
                self._track(C, good, x, status, rho, iters)
            else:
                raise InputError(f"expected initial 'track', 'cold' or start poses, got "
                                 f"{start!r}")
        else:
            s = np.asarray(start, dtype=np.float64)
            if s.shape == (n, 4, 4):
                s = vector_from_pose(s)
            if s.shape != (n, 6):
                raise InputError(f"expected start poses ({n}, 4, 4) or pose vectors ({n}, 6), "
                                 f"got shape {s.shape}")
            x[good], status[good], rho[good], iters[good] = self._solve_from(C[good], s[good],
                                                                             nvec[good])
            self._retry_cold(C, x, status, rho, iters, nvec)
        poses = np.full((n, 4, 4), np.nan)
        ok = np.all(np.isfinite(x), axis=1)
        poses[ok] = pose_from_vector(x[ok])
        vec = np.where(ok[:, None], vector_from_pose(np.where(ok[:, None, None], poses,
                                                              np.eye(4))), np.nan)
        norm2 = np.linalg.norm(C.reshape(n, -1), axis=1)
        return SolveResult(poses, vec, status, rho ** 2 * norm2, iters, None,
                           f"{self.model.kind}-lm", relative_residual=rho)

    def _retry_cold(self, C, x, status, rho, iters, nvec):
        again = (status != int(Status.CONVERGED)) & (status != int(Status.INVALID_INPUT))
        if self.retry_resnorm is not None:       # ILEMT's resnorm above the limit: retry too
            resnorm = rho ** 2 * np.linalg.norm(C.reshape(len(C), -1), axis=1)
            again |= (status == int(Status.CONVERGED)) & ~(resnorm <= self.retry_resnorm)
        again = np.flatnonzero(again)
        if not again.size:
            return
        v0 = vector_from_pose(self.cold_starts(C[again]))
        xc, sc, rc, ic = self._solve_from(C[again], v0, nvec[again])
        take = sc == int(Status.CONVERGED)
        for a, b in ((x, xc), (status, sc), (rho, rc)):
            a[again[take]] = b[take]
        iters[again] += ic

    def _track(self, C, good, x, status, rho, iters):
        """Blocks of :data:`TRACK_BLOCK` samples; each starts from the last two converged
        samples of the previous block, extrapolated at constant velocity to its own row (from
        the last one alone after a gap or at the start)."""
        nvec = self._nvec
        last = prev = None                   # (row, pose vector) of the last two converged
        for lo in range(0, good.size, TRACK_BLOCK):
            rows = good[lo:lo + TRACK_BLOCK]
            if last is None:
                v0 = vector_from_pose(self.cold_starts(C[rows[:1]]))
                last = (rows[0], v0[0]) if np.all(np.isfinite(v0)) else None
            if last is None:
                x[rows], status[rows], rho[rows], iters[rows] = self._solve_from(
                    C[rows], vector_from_pose(self.cold_starts(C[rows])), nvec[rows])
            else:
                start = np.tile(last[1], (rows.size, 1))
                if prev is not None and 0 < last[0] - prev[0] <= TRACK_BLOCK:
                    rate = (last[1] - prev[1]) / (last[0] - prev[0])
                    start = start + np.outer(rows - last[0], rate)
                x[rows], status[rows], rho[rows], iters[rows] = self._solve_from(
                    C[rows], start, nvec[rows])
                sub = (x[rows], status[rows], rho[rows], iters[rows])
                self._retry_cold(C[rows], *sub, nvec[rows])
                x[rows], status[rows], rho[rows], iters[rows] = sub
            conv = np.flatnonzero(status[rows] == int(Status.CONVERGED))
            if conv.size >= 2:
                prev, last = (rows[conv[-2]], x[rows[conv[-2]]]), (rows[conv[-1]],
                                                                   x[rows[conv[-1]]])
            elif conv.size == 1:
                prev, last = last, (rows[conv[-1]], x[rows[conv[-1]]])
            else:
                prev = last = None


class PackedModelSolver(ModelSolver):
    """:class:`ModelSolver`'s starts, cold retries and validity rule with the iteration done
    by the compiled LM kernels (:func:`~openemt.solve._lm.lm_batch`,
    :func:`~openemt.solve._lm.lm_track`), for a model whose packed form they accept
    (:mod:`openemt.solve._model_kernels`; a board read by a multi-coil sensor:
    :func:`~openemt.solve._model_kernels.pack_board`).

    Tracking solves sample by sample, each from the constant-velocity extrapolation of the
    last two converged poses (from the last one after a gap; the first from the model's cold
    start); a sample that does not converge (or, with ``retry_resnorm``,
    converges above it) is solved again from the cold start, as :class:`ModelSolver` does.
    The LM is the dipole solver's (docs/solve.md#compiled-models): full 6-DOF steps with a
    local rotation increment, its step tolerance ``xtol`` relative to the distance from the
    origin for the translation, without its projections onto the hemisphere and box
    (``O_UNCONSTRAINED``: they only judge the result, as here). The answers are :class:`ModelSolver`'s to 1e-9 m
    (``tests/test_board_lm.py``); ``residual`` is, as there, ``rho**2 ||C||_F``.
    """

    def __init__(self, model, options, packed):
        from ._packing import O_AMBIGUITY_TOL, O_MAX_RANGE, O_MAX_RELATIVE_RESIDUAL, pack_options

        super().__init__(model, options)
        self.packed = packed
        rule = self.rule
        self.opts = pack_options(max_iter=self.max_iter, xtol=self.xtol,
                                 retry_resnorm=np.inf, retry_relative=np.inf,
                                 ambiguity_tol=rule[O_AMBIGUITY_TOL],
                                 max_relative_residual=rule[O_MAX_RELATIVE_RESIDUAL],
                                 max_range=rule[O_MAX_RANGE], unconstrained=1,
                                 extrapolate=1)

    def _outputs(self, out, starts):
        from ._closed_form import ST_INVALID_INPUT

        _, vecs, status, _, rho, iters = out
        # a start that is not finite (no cold start for the row) is NOT_CONVERGED, as in
        # ModelSolver; the kernel calls such a row invalid input
        bad = ~np.all(np.isfinite(starts), axis=1) & (status == ST_INVALID_INPUT)
        status[bad] = int(Status.NOT_CONVERGED)
        return vecs, status, rho, iters

    def _solve_from(self, C, start_vectors, nvec):
        from ._closed_form import new_outputs
        from ._lm import lm_batch

        n = len(C)
        s = np.ascontiguousarray(start_vectors, dtype=np.float64).reshape(n, 6)
        out = new_outputs(n)
        if n:
            lm_batch(self.packed, np.ascontiguousarray(C), np.full(n, -1.0), s,
                     np.ascontiguousarray(nvec, dtype=np.float64), self.box, self.opts, out)
        return self._outputs(out, s)

    def _track(self, C, good, x, status, rho, iters):
        from ._closed_form import new_outputs
        from ._lm import lm_track

        if not good.size:
            return
        first = vector_from_pose(self.cold_starts(C[good[:1]]))[0]
        if not np.all(np.isfinite(first)):          # no cold start for the first sample
            return super()._track(C, good, x, status, rho, iters)
        n = good.size
        out = new_outputs(n)
        nvec = np.ascontiguousarray(self._nvec[good], dtype=np.float64)
        Cg = np.ascontiguousarray(C[good])
        lm_track(self.packed, Cg, np.full(n, -1.0), first, np.zeros((2, 3, 3)), nvec,
                 self.box, self.opts, out)
        sub = tuple(a.copy() for a in self._outputs(out, np.zeros((n, 6))))
        self._retry_cold(Cg, *sub, nvec)
        x[good], status[good], rho[good], iters[good] = sub
