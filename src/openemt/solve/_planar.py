"""5-DOF pose solution on a finite-coil board model (Anser-style planar field generators).

Unknowns: the sensor position ``p`` (3) and its coil axis ``u`` (2 angles: the step is taken
in the plane tangent to the current axis, ``u <- normalise(u + a e1 + b e2)``, so there is no
pole). Residuals: the ``n_coils`` couplings divided by the measured coupling norm. The model
and its analytic Jacobian come from the compiled segment kernel
(:mod:`openemt.field._segments`); a sample is solved by Levenberg-Marquardt (Marquardt 1963,
diagonal scaling) started

- ``"track"``: from the previous sample's solution while that one converged (warm-started
  tracking), else cold;
- ``"grid"`` (cold): from the best of a grid of candidate positions above the board, each with
  its least-squares axis (a linear 3-unknown problem per candidate); the next-best candidates
  are tried when the first does not converge;
- an array of poses ``(N, 4, 4)``: from those.

Each sample gets the status of the one validity rule of every solver
(:mod:`openemt.solve._validity`, docs/solve.md): ``INVALID_INPUT``, ``OUT_OF_VOLUME``,
``AMBIGUOUS`` (on the board plane, where mirror poses give the same couplings),
``MAX_ITERATIONS``, ``NOT_CONVERGED`` (relative residual above ``max_relative_residual``),
``CONVERGED``. The 5-DOF pose's rotation is the smallest one taking the sensor z axis to ``u``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .._errors import InputError
from ..field._segments import coupling_point, sensor_rule
from ._hemisphere import hemisphere_vectors
from ._linalg import cholesky_solve
from ._packing import pack_options
from ._result import SolveResult, Status
from ._validity import (
    MAX_RANGE_M,
    MAX_RELATIVE_RESIDUAL,
    check_validity_options,
    classify,
    relative_residual,
)

__all__ = ["PreparedPlanar", "planar_seed_grid", "solve_planar"]

_INVALID = np.int8(Status.INVALID_INPUT)
_CONV = np.int8(Status.CONVERGED)
_NOT_CONV_CODE = np.int8(Status.NOT_CONVERGED)


@njit(cache=True, inline="always")
def _tangent(u, e1, e2):
    # e1: the global axis least aligned with u, projected off u; e2 = u x e1
    ax = np.abs(u)
    if ax[0] <= ax[1] and ax[0] <= ax[2]:
        e1[0], e1[1], e1[2] = 1.0, 0.0, 0.0
    elif ax[1] <= ax[2]:
        e1[0], e1[1], e1[2] = 0.0, 1.0, 0.0
    else:
        e1[0], e1[1], e1[2] = 0.0, 0.0, 1.0
    d = e1[0] * u[0] + e1[1] * u[1] + e1[2] * u[2]
    for a in range(3):
        e1[a] -= d * u[a]
    n = np.sqrt(e1[0] ** 2 + e1[1] ** 2 + e1[2] ** 2)
    for a in range(3):
        e1[a] /= n
    e2[0] = u[1] * e1[2] - u[2] * e1[1]
    e2[1] = u[2] * e1[0] - u[0] * e1[2]
    e2[2] = u[0] * e1[1] - u[1] * e1[0]


@njit(cache=True)
def _lm(S, off, g, nodes, wts, c, p, u, max_iter, xtol, C, dp, du, fresh):
    """LM from ``(p, u)`` (updated in place). ``C, dp, du`` hold the model and its derivatives
    at ``(p, u)`` on return; on entry too when ``fresh`` (a tracked sample starts where the
    previous one ended, so its model need not be evaluated again). Returns (iterations,
    hit_limit)."""
    nc = c.shape[0]
    cn = 0.0
    for i in range(nc):
        cn += c[i] * c[i]
    inv = 1.0 / np.sqrt(cn)
    Cn = np.empty(nc)
    dpn = np.empty((nc, 3))
    dun = np.empty((nc, 3))
    # True at run time, typed bool: the one coupling_point specialisation every kernel calls
    # (a literal True compiles a second, about 1.2 s of CPU on an empty cache)
    grad = nc >= 0
    if not fresh:
        coupling_point(S, off, g, p, u, nodes, wts, C, dp, du, grad)
    cost = 0.0
    for i in range(nc):
        cost += ((c[i] - C[i]) * inv) ** 2
    e1 = np.empty(3)
    e2 = np.empty(3)
    J = np.empty((nc, 5))
    A = np.empty((5, 5))
    gv = np.empty(5)
    dx = np.empty(5)
    pn = np.empty(3)
    un = np.empty(3)
    Lc = np.empty((5, 5))
    lam = 1e-8
    it = 0
    while it < max_iter:
        it += 1
        _tangent(u, e1, e2)
        for i in range(nc):
            for a in range(3):
                J[i, a] = dp[i, a] * inv
            J[i, 3] = (du[i, 0] * e1[0] + du[i, 1] * e1[1] + du[i, 2] * e1[2]) * inv
            J[i, 4] = (du[i, 0] * e2[0] + du[i, 1] * e2[1] + du[i, 2] * e2[2]) * inv
        for a in range(5):
            s = 0.0
            for i in range(nc):
                s += J[i, a] * (c[i] - C[i]) * inv
            gv[a] = s
            for b in range(a, 5):
                s = 0.0
                for i in range(nc):
                    s += J[i, a] * J[i, b]
                A[a, b] = s
                A[b, a] = s
        accepted = False
        small = False
        while lam < 1e12:
            Al = A.copy()
            for a in range(5):
                Al[a, a] += lam * (A[a, a] + 1e-30)
            if not cholesky_solve(Al, gv, 5, dx, Lc):
                lam *= 10.0
                continue
            for a in range(3):
                pn[a] = p[a] + dx[a]
            nu = 0.0
            for a in range(3):
                un[a] = u[a] + dx[3] * e1[a] + dx[4] * e2[a]
                nu += un[a] * un[a]
            nu = np.sqrt(nu)
            for a in range(3):
                un[a] /= nu
            step = np.sqrt(dx[0] ** 2 + dx[1] ** 2 + dx[2] ** 2)
            ang = np.sqrt(dx[3] ** 2 + dx[4] ** 2)
            small = step <= xtol and ang <= xtol
            if small:
                break               # the current point is within xtol of the minimum
            coupling_point(S, off, g, pn, un, nodes, wts, Cn, dpn, dun, grad)
            cn2 = 0.0
            for i in range(nc):
                cn2 += ((c[i] - Cn[i]) * inv) ** 2
            if cn2 <= cost:
                accepted = True
                p[:] = pn
                u[:] = un
                C[:] = Cn
                dp[:, :] = dpn
                du[:, :] = dun
                cost = cn2
                lam = max(lam * 0.1, 1e-12)
                # near a minimum LM converges at least linearly with a small factor (the
                # relative residual): after an accepted step of 100 xtol the rest is < xtol
                small = step <= 100.0 * xtol and ang <= 100.0 * xtol
                break
            lam *= 10.0
        if small or not accepted:
            return it, False        # converged (step below the tolerance) or stalled
    return it, True


@njit(cache=True)
def _seed(F, Pg, c, order_out, min_sep):
    """Rank grid candidates: ``F (G, nc, 3)`` fields at grid points. For each, the axis ``u``
    minimising ``||c - F u||`` is normalised; candidates ranked by that residual, and the best
    ones at least ``min_sep`` apart written to ``order_out``."""
    G, nc = F.shape[0], F.shape[1]
    res = np.empty(G)
    U = np.empty((G, 3))
    M = np.empty((3, 3))
    v = np.empty(3)
    for k in range(G):
        for a in range(3):
            s = 0.0
            for i in range(nc):
                s += F[k, i, a] * c[i]
            v[a] = s
            for b in range(3):
                s = 0.0
                for i in range(nc):
                    s += F[k, i, a] * F[k, i, b]
                M[a, b] = s
        x = np.linalg.solve(M + 1e-30 * np.eye(3), v)
        n = np.sqrt(x[0] ** 2 + x[1] ** 2 + x[2] ** 2)
        if not n > 0:
            res[k] = np.inf
            U[k] = 0.0
            continue
        x /= n
        r = 0.0
        for i in range(nc):
            d = c[i] - (F[k, i, 0] * x[0] + F[k, i, 1] * x[1] + F[k, i, 2] * x[2])
            r += d * d
        res[k] = r
        U[k] = x
    # the best candidates, each at least min_sep from those already taken (distinct basins)
    idx = np.argsort(res)
    n_out = 0
    for j in range(G):
        q = idx[j]
        far = True
        for m in range(n_out):
            e = Pg[q] - Pg[order_out[m]]
            if e[0] * e[0] + e[1] * e[1] + e[2] * e[2] < min_sep * min_sep:
                far = False
                break
        if far:
            order_out[n_out] = q
            n_out += 1
            if n_out == order_out.shape[0]:
                break
    for m in range(n_out, order_out.shape[0]):
        order_out[m] = idx[m]
    return U


def _rule_options(ambiguity_tol, max_rel, max_range):
    """The options array of the shared validity rule (:func:`openemt.solve._validity.classify`)."""
    return pack_options(ambiguity_tol=ambiguity_tol, max_relative_residual=max_rel,
                        max_range=max_range)


@njit(inline="always")
def _status(hit, rho, t, n, box, opts):
    return classify(hit, rho, t, n, box, opts)


@njit(cache=True)
def _batch(S, off, g, nodes, wts, Cm, P0, U0, mode, F, Pg, min_sep, n_tries, max_iter, xtol,
           nvec, box, opts, pos, axes, status, rho, iters):
    """mode 0: given starts; 1: grid (cold) each sample; 2: tracking."""
    N, nc = Cm.shape
    Cmat = np.empty((nc, 1))
    Cp = np.empty((nc, 1))
    p = np.empty(3)
    u = np.empty(3)
    bp = np.empty(3)
    bu = np.empty(3)
    probe_iter = min(max_iter, 12)
    C = np.empty(Cm.shape[1])
    dp = np.empty((Cm.shape[1], 3))
    du = np.empty((Cm.shape[1], 3))
    model_ok = False
    order = np.empty(min(n_tries, F.shape[0]), dtype=np.int64)
    prev_ok = False
    # False at run time, typed bool: a literal False given to _lm (or a variable that starts
    # as one) would compile a second specialisation of it, numba trying the literal type
    # first (about 2.5 s of CPU on an empty cache)
    not_fresh = N < 0
    for k in range(N):
        c = Cm[k]
        ok = True
        cn = 0.0
        for i in range(nc):
            if not np.isfinite(c[i]):
                ok = False
            cn += c[i] * c[i]
        if not ok or not cn > 0.0:
            status[k] = _INVALID
            pos[k, :] = np.nan
            axes[k, :] = np.nan
            rho[k] = np.nan
            iters[k] = 0
            prev_ok = False
            continue
        for i in range(nc):
            Cmat[i, 0] = c[i]
        total = 0
        best_rho = np.inf
        best_st = _NOT_CONV_CODE
        warm = mode == 0 or (mode == 2 and prev_ok)
        kept_last = False            # pos[k] is where the last LM run ended (C, dp, du valid)
        if warm:
            fresh = not_fresh
            if mode == 0:
                p[:] = P0[k]
                u[:] = U0[k]
            else:
                p[:] = pos[k - 1]
                u[:] = axes[k - 1]
                fresh = model_ok
            it, hit = _lm(S, off, g, nodes, wts, c, p, u, max_iter, xtol, C, dp, du, fresh)
            total += it
            for i in range(nc):
                Cp[i, 0] = C[i]
            best_rho = relative_residual(Cp, Cmat)
            best_st = _status(hit, best_rho, p, nvec, box, opts)
            pos[k] = p
            axes[k] = u
            kept_last = True
        if not warm or (mode == 2 and best_st != _CONV):
            # cold: short LM runs from distinct grid candidates, then the best one to the end
            cand = _seed(F, Pg, c, order, min_sep)
            brho = np.inf
            for m in range(order.shape[0]):
                j = order[m]
                p[:] = Pg[j]
                u[:] = cand[j]
                it, hit = _lm(S, off, g, nodes, wts, c, p, u, probe_iter, xtol, C, dp, du,
                              not_fresh)
                total += it
                for i in range(nc):
                    Cp[i, 0] = C[i]
                r = relative_residual(Cp, Cmat)
                if r < brho:
                    brho = r
                    bp[:] = p
                    bu[:] = u
            kept_last = False
            if brho < np.inf:
                p[:] = bp
                u[:] = bu
                it, hit = _lm(S, off, g, nodes, wts, c, p, u, max_iter, xtol, C, dp, du,
                              not_fresh)
                total += it
                for i in range(nc):
                    Cp[i, 0] = C[i]
                r = relative_residual(Cp, Cmat)
                st = _status(hit, r, p, nvec, box, opts)
                if not warm or (st == _CONV or r < best_rho):
                    best_rho = r
                    best_st = st
                    pos[k] = p
                    axes[k] = u
                    kept_last = True
        model_ok = kept_last
        status[k] = best_st
        rho[k] = best_rho
        iters[k] = total
        prev_ok = best_st == _CONV


def planar_seed_grid(model, *, spacing=0.03, height=(0.02, 0.40)) -> np.ndarray:
    """Candidate start positions ``(G, 3)``: a grid over the board's coils (plus 0.1 m all
    round) at heights from ``height[0]`` to ``height[1]`` on the side of the board normal."""
    centers = np.stack([c.center for c in model.board.coils])
    normal = model.board.coils[0].normal
    lo, hi = centers.min(0) - 0.1, centers.max(0) + 0.1
    # the grid spans the board plane; heights along the normal (the mean coil normal)
    frame = np.linalg.svd(np.eye(3) - np.outer(normal, normal))[0][:, :2]
    xy = (centers - centers.mean(0)) @ frame
    ext_lo, ext_hi = xy.min(0) - 0.1, xy.max(0) + 0.1
    a = np.arange(ext_lo[0], ext_hi[0] + 1e-12, spacing)
    b = np.arange(ext_lo[1], ext_hi[1] + 1e-12, spacing)
    z = np.geomspace(height[0], height[1], 9)
    A, B, Z = np.meshgrid(a, b, z, indexing="ij")
    del lo, hi
    return (centers.mean(0) + np.outer(A.ravel(), frame[:, 0]) + np.outer(B.ravel(), frame[:, 1])
            + np.outer(Z.ravel(), normal))


def _grid_fields(model, grid):
    from ..field._segments import segment_fields

    F = segment_fields(model.segments, model.segment_offsets, grid)       # (nc, G, 3)
    return np.ascontiguousarray(np.transpose(F, (1, 0, 2)) * model.gains[None, :, None])


def pose_from_axis(points, axes) -> np.ndarray:
    """Poses ``(N, 4, 4)``: the smallest rotation taking z to each unit axis, and the points."""
    from ..geometry import pose_from_vector, rotvec_between

    u = np.asarray(axes, np.float64)
    rv = rotvec_between([0.0, 0.0, 1.0], u)

    good = np.all(np.isfinite(rv), axis=1) & np.all(np.isfinite(points), axis=1)
    vec = np.full((len(u), 6), np.nan)
    vec[good] = np.column_stack([points[good], rv[good]])
    poses = np.full((len(u), 4, 4), np.nan)
    if good.any():
        poses[good] = pose_from_vector(vec[good])
    return poses, vec


def solve_planar(couplings, model, *, initial="track", max_iter=50, xtol=1e-9,
                 max_relative_residual=MAX_RELATIVE_RESIDUAL, max_range=MAX_RANGE_M,
                 bounds=None, ambiguity_tol=1e-9, hemisphere=None, n_tries=12,
                 seed_grid=None, min_sep=0.04) -> SolveResult:
    """Solve 5-DOF sensor poses from couplings on a finite-coil board model.

    Parameters
    ----------
    couplings : array_like, shape (N, n_coils) or (N, n_coils, 1)
        Measured couplings (any units consistent with the model's gains, e.g. tesla).
    model : openemt.board.BoardModel
    initial : {"track", "grid"} or array (N, 4, 4)
        Warm-started tracking (cold grid start for the first sample and after a failure),
        a cold grid start for every sample, or given start poses (sensor z = coil axis).
    max_iter, xtol
        Iteration limit per start and the step (m, rad) below which LM has converged.
    max_relative_residual, max_range, bounds, ambiguity_tol
        The validity rule (docs/solve.md); ``bounds`` is a position box half-width (m).
    hemisphere : None, "none", str such as "+z", or array (3,)
        Side of the sources the sensor is on: a solution with ``t . n <= ambiguity_tol |t|``
        is AMBIGUOUS. Default: the common coil normal of a planar board (no check for coils
        of different normals).
    seed_grid : array (G, 3), optional
        Cold-start candidate positions (default :func:`planar_seed_grid`, for planar boards).
    n_tries, min_sep
        A cold start runs a short LM (12 iterations) from each of the ``n_tries`` best grid
        candidates at least ``min_sep`` (m) apart and continues the one of least residual.

    Returns
    -------
    SolveResult
        Poses whose z axis is the sensor axis; ``residual`` is ILEMT's resnorm
        (``rho**2 ||C||``) and ``relative_residual``, where the result type has it, the
        relative residual ``rho`` the status is judged by.
    """
    return PreparedPlanar(model, max_iter=max_iter, xtol=xtol,
                          max_relative_residual=max_relative_residual, max_range=max_range,
                          bounds=bounds, ambiguity_tol=ambiguity_tol, hemisphere=hemisphere,
                          n_tries=n_tries, seed_grid=seed_grid,
                          min_sep=min_sep).solve(couplings, initial)


class PreparedPlanar:
    """:func:`solve_planar` for one board model and one set of options, prepared once: the
    options checked, the seed grid's fields, the sensor's quadrature rule, the side of the
    board and the validity rule's packed options computed here; :meth:`solve` then only checks
    the couplings and runs the kernel (same results as :func:`solve_planar`, bit for bit).
    The parameters are those of :func:`solve_planar` other than ``couplings`` and ``initial``.
    """

    def __init__(self, model, *, max_iter=50, xtol=1e-9,
                 max_relative_residual=MAX_RELATIVE_RESIDUAL, max_range=MAX_RANGE_M,
                 bounds=None, ambiguity_tol=1e-9, hemisphere=None, n_tries=12,
                 seed_grid=None, min_sep=0.04):
        from ..board import BoardModel

        if not isinstance(model, BoardModel):
            raise TypeError(f"expected a BoardModel, got {type(model).__name__}")
        max_rel, max_rng = check_validity_options(max_relative_residual, max_range)
        if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) \
                or max_iter < 1:
            raise InputError(f"expected a positive integer max_iter, got {max_iter!r}")
        self.model = model
        grid = planar_seed_grid(model) if seed_grid is None else np.asarray(seed_grid,
                                                                            np.float64)
        self.grid = np.ascontiguousarray(grid)
        self.F = _grid_fields(model, grid)
        self.nodes, self.wts = sensor_rule(model.sensor_length)
        if hemisphere is None:
            nvec = np.ascontiguousarray(model.front)   # a planar board: its front side, else none
        elif isinstance(hemisphere, str) and hemisphere == "none":
            nvec = np.zeros(3)
        else:
            nvec = np.ascontiguousarray(hemisphere_vectors(hemisphere, 1, allow_none=False)[0])
        self.nvec = nvec
        if bounds is None:
            lo, hi = np.full(3, -np.inf), np.full(3, np.inf)
        else:
            try:
                b = float(bounds)
            except (TypeError, ValueError):
                raise InputError(f"expected a bounds half-width (m) for a board, got "
                                 f"{bounds!r}") from None
            if not b > 0:
                raise InputError(f"expected a positive bounds half-width (m), got {bounds!r}")
            lo, hi = np.full(3, -b), np.full(3, b)
        self.box = np.ascontiguousarray(np.stack([lo, hi]))
        self.rule = _rule_options(ambiguity_tol, max_rel, max_rng)
        self.gains = np.ascontiguousarray(model.gains)
        self.min_sep, self.n_tries = float(min_sep), int(n_tries)
        self.max_iter, self.xtol = int(max_iter), float(xtol)

    def solve(self, couplings, initial="track") -> SolveResult:
        """:func:`solve_planar` of ``couplings`` from ``initial`` (see there)."""
        model = self.model
        C = np.asarray(couplings, dtype=np.float64)
        if C.ndim == 3 and C.shape[2] == 1:
            C = C[:, :, 0]
        if C.ndim != 2 or C.shape[1] != model.n_coils:
            raise InputError(f"expected couplings of shape (N, {model.n_coils}) or "
                             f"(N, {model.n_coils}, 1), got {np.shape(couplings)}")
        N = len(C)
        P0 = np.zeros((N, 3))
        U0 = np.zeros((N, 3))
        if isinstance(initial, str):
            if initial not in ("track", "grid"):
                raise InputError(f"expected initial 'track', 'grid' or poses, got {initial!r}")
            mode = 2 if initial == "track" else 1
        else:
            init = np.asarray(initial, dtype=np.float64)
            if init.shape != (N, 4, 4):
                raise InputError(f"expected initial poses of shape ({N}, 4, 4), got "
                                 f"{init.shape}")
            P0 = np.ascontiguousarray(init[:, :3, 3])
            U0 = np.ascontiguousarray(init[:, :3, 2])
            mode = 0
        pos = np.full((N, 3), np.nan)
        axes = np.full((N, 3), np.nan)
        status = np.zeros(N, np.int8)
        rho = np.full(N, np.nan)
        iters = np.zeros(N, np.int32)
        _batch(model.segments, model.segment_offsets, self.gains, self.nodes, self.wts,
               np.ascontiguousarray(C), P0, U0, mode, self.F, self.grid, self.min_sep,
               self.n_tries, self.max_iter, self.xtol, self.nvec, self.box, self.rule,
               pos, axes, status, rho, iters)
        poses, vec = pose_from_axis(pos, axes)
        # ``residual`` is ILEMT's resnorm as for every solver (squared residual norm over the
        # measured norm, the spectral norm of a single column); the status is judged by ``rho``
        resnorm = rho ** 2 * np.linalg.norm(C, axis=1)
        return SolveResult(poses, vec, status, resnorm, iters, None, "planar-lm",
                           relative_residual=rho)
