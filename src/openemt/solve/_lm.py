"""Compiled batched Levenberg-Marquardt pose solver for any dipole model.

Per sample, the unknown pose ``(R, t)`` is updated by a translation increment and a local
rotation increment, ``t <- t + dt``, ``R <- exp([dphi]x) R`` (so no rotation-vector Jacobian is
needed). The model and its analytic derivatives come from the one compiled dipole kernel
``openemt.field._dipole_kernel.dipole_eval``. The residual is ``C_pred - C_meas`` over all
``n_source * n_sensor`` couplings (unnormalised, as ILEMT, docs/paper-procedure.md#iterative-solution).

Single-coil sensors (``n_sensor == 1``) are 5-DOF: the roll about the sensor axis is not
observable. The increment ``dphi`` is then restricted to the plane perpendicular to the sensor
axis; ``solve_lm`` reports the shortest-arc rotation taking the sensor coil's moment direction
to the solved axis (zero roll, with the coil position kept; ``canonical_5dof``).

Constraints: a hemisphere half-space ``t . n >= 0`` (per sample; ``n = 0`` means none) and an
optional position box, enforced by projecting every trial point (projected LM). ILEMT's retries
(docs/paper-procedure.md#iterative-solution) restart an invalid solve from the initial pose with one pose-vector
component's sign flipped, for each of the 6 components, and keep the first valid (else the best)
result.
"""

from __future__ import annotations

import numpy as np
from numba import njit, types
from numba.extending import overload

from ._closed_form import (
    CF_KIM18,
    _store_invalid,
    closed_form_one,
    closed_form_scratch,
    normalise_coupling,
    residuals_at,
)
from ._linalg import cholesky_solve, exp_so3, rotvec_from_matrix, store_pose
from ._model_kernels import is_board, model_eval, unpack_any
from ._packing import (
    O_CF_GAIN,
    O_EXTRAPOLATE,
    O_FIVE_DOF,
    O_MAX_ITER,
    O_RANK_TOL,
    O_RETRIES,
    O_RETRY_RELATIVE,
    O_RETRY_RESNORM,
    O_UNCONSTRAINED,
    O_USE_CLOSED_FORM,
    O_XTOL,
)
from ._result import ST_CONVERGED, ST_INVALID_INPUT
from ._validity import better_run, classify

__all__ = ["STOP_CONVERGED", "STOP_ITERATION_LIMIT", "lm_batch", "lm_track"]

#: how one LM run ended: its convergence test held (or no decrease was possible) ...
STOP_CONVERGED = 0
#: ... or it reached the iteration limit
STOP_ITERATION_LIMIT = 1


def closed_form_start(mdl, method, Cn, W, gain, n, rank_tol, R, t, cws):
    """The tracking kernel's closed-form restart (compiled code only): the closed form of a
    dipole model (:func:`~openemt.solve._closed_form.closed_form_one`); none for a board (its
    couplings are not a 3x3 concentric matrix), so that its kernels do not compile it."""
    raise NotImplementedError("closed_form_start runs in compiled kernels only")


@overload(closed_form_start)
def _closed_form_start(mdl, method, Cn, W, gain, n, rank_tol, R, t, cws):
    if isinstance(mdl, types.Array):
        return lambda mdl, method, Cn, W, gain, n, rank_tol, R, t, cws: closed_form_one(
            method, Cn, W, gain, n, rank_tol, R, t, cws)
    if is_board(mdl):
        return lambda mdl, method, Cn, W, gain, n, rank_tol, R, t, cws: ST_INVALID_INPUT
    return None


@njit(inline="always")
def _project(t, n, lo, hi, free):
    if free:
        return                  # O_UNCONSTRAINED: the constraints only judge the result
    d = t[0] * n[0] + t[1] * n[1] + t[2] * n[2]
    if d < 0.0:
        t[0] -= d * n[0]
        t[1] -= d * n[1]
        t[2] -= d * n[2]
    for a in range(3):
        if t[a] < lo[a]:
            t[a] = lo[a]
        elif t[a] > hi[a]:
            t[a] = hi[a]


@njit(inline="always")
def _rot_basis(R, M_se, five, basis):
    """Rotation increment directions (columns of ``basis``); returns their number."""
    if not five:
        for i in range(3):
            for j in range(3):
                basis[i, j] = 1.0 if i == j else 0.0
        return 3
    a0 = R[0, 0] * M_se[0, 0] + R[0, 1] * M_se[1, 0] + R[0, 2] * M_se[2, 0]
    a1 = R[1, 0] * M_se[0, 0] + R[1, 1] * M_se[1, 0] + R[1, 2] * M_se[2, 0]
    a2 = R[2, 0] * M_se[0, 0] + R[2, 1] * M_se[1, 0] + R[2, 2] * M_se[2, 0]
    na = np.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    a0 /= na
    a1 /= na
    a2 /= na
    # e1: a unit vector perpendicular to a (cross with the least aligned axis)
    if abs(a0) <= abs(a1) and abs(a0) <= abs(a2):
        e0, e1_, e2 = 0.0, a2, -a1
    elif abs(a1) <= abs(a2):
        e0, e1_, e2 = -a2, 0.0, a0
    else:
        e0, e1_, e2 = a1, -a0, 0.0
    ne = np.sqrt(e0 * e0 + e1_ * e1_ + e2 * e2)
    e0 /= ne
    e1_ /= ne
    e2 /= ne
    basis[0, 0], basis[1, 0], basis[2, 0] = e0, e1_, e2
    basis[0, 1] = a1 * e2 - a2 * e1_
    basis[1, 1] = a2 * e0 - a0 * e2
    basis[2, 1] = a0 * e1_ - a1 * e0
    return 2


@njit(inline="always")
def _eval(geo, Cm, R, t, Cp, jac, want):
    model_eval(geo, R, t, Cp, jac, want)
    ss = 0.0
    for i in range(Cm.shape[0]):
        for j in range(Cm.shape[1]):
            r = Cp[i, j] - Cm[i, j]
            ss += r * r
    return ss


@njit(inline="always")
def _trial(R, t, delta, basis, nr, n, lo, hi, free, t2, phi, dR, R2):
    """The pose ``(R2, t2)`` one step ``delta`` from ``(R, t)``, projected onto the
    constraints (``phi`` receives the rotation increment)."""
    for a in range(3):
        t2[a] = t[a] + delta[a]
    _project(t2, n, lo, hi, free)
    for a in range(3):
        acc = 0.0
        for c in range(nr):
            acc += basis[a, c] * delta[3 + c]
        phi[a] = acc
    exp_so3(phi, dR)
    for a in range(3):
        for b in range(3):
            R2[a, b] = dR[a, 0] * R[0, b] + dR[a, 1] * R[1, b] + dR[a, 2] * R[2, b]


@njit(inline="always")
def _copy_pose(R_from, t_from, R_to, t_to):
    for a in range(3):
        t_to[a] = t_from[a]
        for b in range(3):
            R_to[a, b] = R_from[a, b]


@njit(cache=True)
def _lm_one(geo, Cm, R, t, n, box, opts, lmw):
    """Levenberg-Marquardt from ``(R, t)`` (updated in place). Returns ``(cost, iterations,
    stop, fresh)`` with ``stop`` = ``STOP_CONVERGED`` (converged, or stalled at a minimum) or
    ``STOP_ITERATION_LIMIT``, and ``fresh`` whether ``lmw[0]`` holds the model's couplings at
    the pose returned (every way out but the converged step applied without an evaluation), so
    that the validity rule's residual there needs no second evaluation (:func:`_finish`)."""
    Cp, jac, Cp2, jac2, Jb, JtJ, A, Lc, g, delta, basis, R2, t2, dR, phi = lmw
    dt = jac[0]
    dphi = jac[1]
    dt2 = jac2[0]
    dphi2 = jac2[1]
    lo = box[0]
    hi = box[1]
    M_se = geo[3]
    five = opts[O_FIVE_DOF] != 0.0
    free = opts[O_UNCONSTRAINED] != 0.0
    max_iter = int(opts[O_MAX_ITER])
    xtol = opts[O_XTOL]
    n_so = Cm.shape[0]
    n_se = Cm.shape[1]
    _project(t, n, lo, hi, free)
    with_jac = n_so > 0  # True at run time: one dipole_eval specialisation for all callers
    cost = _eval(geo, Cm, R, t, Cp, jac, with_jac)
    lam = 1e-4
    lam_small = 1e-3
    prev_rel = 0.0
    it = 0
    stop = STOP_ITERATION_LIMIT
    while it < max_iter:
        it += 1
        nr = _rot_basis(R, M_se, five, basis)
        npar = 3 + nr
        # projected Jacobian columns, Jb (m, npar)
        row = 0
        for i in range(n_so):
            for j in range(n_se):
                Jb[row, 0] = dt[i, j, 0]
                Jb[row, 1] = dt[i, j, 1]
                Jb[row, 2] = dt[i, j, 2]
                for c in range(nr):
                    Jb[row, 3 + c] = (dphi[i, j, 0] * basis[0, c] + dphi[i, j, 1] * basis[1, c]
                                      + dphi[i, j, 2] * basis[2, c])
                row += 1
        m = row
        for p in range(npar):
            acc = 0.0
            row = 0
            for i in range(n_so):
                for j in range(n_se):
                    acc += Jb[row, p] * (Cp[i, j] - Cm[i, j])
                    row += 1
            g[p] = -acc
            for q in range(p + 1):
                acc = 0.0
                for r in range(m):
                    acc += Jb[r, p] * Jb[r, q]
                JtJ[p, q] = acc
                JtJ[q, p] = acc
        accepted = False
        while True:
            for p in range(npar):
                for q in range(npar):
                    A[p, q] = JtJ[p, q]
                A[p, p] = JtJ[p, p] * (1.0 + lam) + 1e-300
            ok = cholesky_solve(A, g, npar, delta, Lc)
            if ok:
                st2 = delta[0] * delta[0] + delta[1] * delta[1] + delta[2] * delta[2]
                tn2 = t[0] * t[0] + t[1] * t[1] + t[2] * t[2]
                # converged: the Gauss-Newton step is below tolerance; apply it without a new
                # evaluation (the cost changes by O(step^2), far below rounding of the test)
                converged = False
                if lam <= lam_small:
                    sr2 = 0.0
                    for c in range(nr):
                        sr2 += delta[3 + c] * delta[3 + c]
                    converged = (np.sqrt(st2) <= xtol * (np.sqrt(tn2) + xtol)
                                 and np.sqrt(sr2) <= xtol)
                # trust limit: one step moves the sensor by at most half its distance (keeps
                # an unconstrained solve from running off to infinity, where C -> 0)
                if not converged and st2 > 0.25 * tn2 and tn2 > 0.0 and not free:
                    f = np.sqrt(0.25 * tn2 / st2)
                    for a in range(npar):
                        delta[a] *= f
                # one trial-pose site for both (the step's code is inlined once, not twice)
                _trial(R, t, delta, basis, nr, n, lo, hi, free, t2, phi, dR, R2)
                if converged:
                    _copy_pose(R2, t2, R, t)
                    return cost, it, STOP_CONVERGED, False
                # linear-rate prediction: if this step is much smaller than the previous
                # accepted one and the step after it would be below tolerance, this is the
                # last step; its Jacobian is not needed
                rel = max(np.sqrt(delta[0] * delta[0] + delta[1] * delta[1]
                                  + delta[2] * delta[2]) / (np.sqrt(tn2) + xtol),
                          np.sqrt(phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2]))
                final = (prev_rel > 0.0 and lam <= lam_small and rel < 0.5 * prev_rel
                         and rel * rel / prev_rel <= xtol)
                cost2 = _eval(geo, Cm, R2, t2, Cp2, jac2, not final)
                if cost2 <= cost:
                    if final:
                        _copy_pose(R2, t2, R, t)
                        for i in range(n_so):
                            for j in range(n_se):
                                Cp[i, j] = Cp2[i, j]
                        return cost2, it, STOP_CONVERGED, True
                    accepted = True
                    prev_rel = rel
                    break
            lam *= 10.0
            if lam > 1e12:
                break
        if not accepted:
            stop = STOP_CONVERGED  # no decrease possible: at a minimum within rounding
            break
        # accept
        step_t = 0.0
        norm_t = 0.0
        step_r = 0.0
        for a in range(3):
            step_t += (t2[a] - t[a]) ** 2
            norm_t += t2[a] * t2[a]
            step_r += phi[a] * phi[a]
        _copy_pose(R2, t2, R, t)
        for i in range(n_so):
            for j in range(n_se):
                Cp[i, j] = Cp2[i, j]
                for a in range(3):
                    dt[i, j, a] = dt2[i, j, a]
                    dphi[i, j, a] = dphi2[i, j, a]
        small_cost = cost2 <= 1e-300
        cost = cost2
        lam = max(lam * 0.1, 1e-12)
        if small_cost or (np.sqrt(step_t) <= xtol * (np.sqrt(norm_t) + xtol)
                          and np.sqrt(step_r) <= xtol):
            stop = STOP_CONVERGED
            break
    return cost, it, stop, True


@njit(inline="always")
def _acceptable(cost, res_fac, fn, opts):
    """No retry needed: the retry test (ILEMT's resnorm test and/or the relative residual)
    holds for the normalised cost ``cost`` (``res_fac`` converts it to the resnorm, ``fn`` is
    the normalised coupling's Frobenius norm)."""
    return (cost * res_fac < opts[O_RETRY_RESNORM]
            and np.sqrt(cost) <= opts[O_RETRY_RELATIVE] * fn)


@njit(inline="always")
def _solve_sample(geo, Cm, res_fac, fn, start, n, box, opts, sw, lmw):
    """Solve one sample from the pose vector ``start``, with ILEMT's sign-flip retries if
    ``opts[O_RETRIES]``; the best pose goes to ``sw``'s ``Rb, tb`` (NaN if no run gave a
    finite cost). Returns ``(cost, iterations, stop, fresh)`` of the best run, ``fresh``
    whether ``lmw[0]`` still holds the couplings it predicts there (normalised, as ``Cm``:
    the best run was the last and ended on an evaluation, :func:`_lm_one`)."""
    R, t, Rb, tb, v0, rv = sw
    best = np.inf
    best_stop = STOP_ITERATION_LIMIT
    best_fresh = False
    total_it = 0
    tb[:] = np.nan
    Rb[:, :] = np.nan
    n_flips = 6 if opts[O_RETRIES] != 0.0 else 0
    # the plain solve first, then ILEMT's sign-flip retries
    for trial in range(1 + n_flips):
        for a in range(6):
            v0[a] = start[a]
        # ILEMT: an initial pose outside the hemisphere gets its translation negated
        if v0[0] * n[0] + v0[1] * n[1] + v0[2] * n[2] < 0.0 and opts[O_UNCONSTRAINED] == 0.0:
            v0[0], v0[1], v0[2] = -v0[0], -v0[1], -v0[2]
        if trial >= 1:
            v0[trial - 1] = -v0[trial - 1]
        for a in range(3):
            t[a] = v0[a]
            rv[a] = v0[3 + a]
        exp_so3(rv, R)
        cost, it, stop, fresh = _lm_one(geo, Cm, R, t, n, box, opts, lmw)
        total_it += it
        if better_run(cost, stop == STOP_CONVERGED, best, best_stop == STOP_CONVERGED):
            best = cost
            best_stop = stop
            best_fresh = fresh
            _copy_pose(R, t, Rb, tb)
        else:
            best_fresh = False      # this run's evaluations overwrote the best one's
        if _acceptable(best, res_fac, fn, opts):
            break
    return best, total_it, best_stop, best_fresh


@njit(inline="always")
def _workspace(n_so, n_se):
    """Scratch of one solve: ``(lmw, sw, Cn, G)`` -- the LM run's arrays, the sample's poses
    ``(R, t, Rb, tb, v0, rv)``, the normalised coupling and spectral-norm scratch."""
    m = n_so * n_se
    # the model derivatives the LM does not use share one scratch pair
    d1 = np.empty((n_so, n_se, 3))
    d2 = np.empty((n_so, n_se, 3))
    jac = (np.empty((n_so, n_se, 3)), np.empty((n_so, n_se, 3)), d1, d2)
    jac2 = (np.empty((n_so, n_se, 3)), np.empty((n_so, n_se, 3)), d1, d2)
    lmw = (np.empty((n_so, n_se)), jac, np.empty((n_so, n_se)), jac2, np.empty((m, 6)),
           np.empty((6, 6)), np.empty((6, 6)), np.empty((6, 6)), np.empty(6), np.empty(6),
           np.empty((3, 3)), np.empty((3, 3)), np.empty(3), np.empty((3, 3)), np.empty(3))
    sw = (np.empty((3, 3)), np.empty(3), np.empty((3, 3)), np.empty(3), np.empty(6),
          np.empty(3))
    return lmw, sw, np.empty((n_so, n_se)), np.empty((n_se, n_se))


@njit(inline="always")
def _finish(k, mdl, Ck, s, cn, fn, n, box, opts, it, stop, fresh, sw, lmw, out):
    """Store sample ``k``'s best pose (in ``sw``) and judge it by the validity rule, with the
    residuals at the pose stored and the couplings' own scale (from the couplings its solve
    last predicted, still in ``lmw[0]``, when ``fresh``; else evaluated)."""
    Rb = sw[2]
    tb = sw[3]
    rv = sw[5]
    poses, vecs, status, residual, relres, iterations = out
    finite = True
    for a in range(3):
        finite = finite and np.isfinite(tb[a])
        for b in range(3):
            finite = finite and np.isfinite(Rb[a, b])
    rotvec_from_matrix(Rb, rv)
    store_pose(k, Rb, tb, rv, poses, vecs)
    rho = np.nan
    residual[k] = np.nan
    if finite:
        residual[k], rho = residuals_at(unpack_any(mdl, 1.0), Rb, tb, Ck, s, cn, fn, lmw[0],
                                        lmw[1], fresh)
    relres[k] = rho
    iterations[k] = it
    status[k] = classify(stop == STOP_ITERATION_LIMIT, rho, tb, n, box, opts)


@njit(cache=True, nogil=True)
def lm_batch(mdl, C, cnorm, init, nvec, box, opts, out):
    """Independent LM solves of every sample (releases the GIL: callers may run row blocks in
    threads).

    ``mdl``: packed model (:func:`~openemt.solve._packing.pack_model`); ``C`` (N, n_so, n_se)
    real couplings; ``cnorm`` (N,) their spectral norms (negative: compute); ``init`` (N, 6)
    start pose vectors; ``nvec`` (N, 3) hemispheres; ``box`` (2, 3) position box; ``opts`` the
    options array (``O_*``); ``out`` the arrays of ``new_outputs``.
    """
    N = C.shape[0]
    lmw, sw, Cn, G = _workspace(C.shape[1], C.shape[2])
    for k in range(N):
        s, cn, fn = normalise_coupling(C[k], cnorm[k], Cn, G)
        finite = True
        for a in range(6):
            finite = finite and np.isfinite(init[k, a])
        if not s > 0.0 or not finite:
            _store_invalid(k, out)
            continue
        geo = unpack_any(mdl, s)
        res_fac = s * (s / cn)  # normalised sum of squares -> resnorm
        it, stop, fresh = _solve_sample(geo, Cn, res_fac, fn, init[k], nvec[k], box, opts, sw,
                                        lmw)[1:]
        _finish(k, mdl, C[k], s, cn, fn, nvec[k], box, opts, it, stop, fresh, sw, lmw, out)


@njit(cache=True, nogil=True)
def lm_track(mdl, C, cnorm, first, W, nvec, box, opts, out):
    """Sequential tracking: each sample starts from the previous valid solution (the first from
    ``first``). A sample failing the retry test is re-solved from the Kim18 closed form of the
    sample under the concentric whitening ``W = [M_so^-T, M_se^-1]`` and gain
    ``opts[O_CF_GAIN]`` (if ``opts[O_USE_CLOSED_FORM]``), then with the sign-flip retries.
    With ``opts[O_EXTRAPOLATE]`` a sample whose two predecessors both converged starts from
    their constant-velocity extrapolation (when they are less than 1 cm and 0.1 rad apart).
    Arguments as :func:`lm_batch`."""
    N = C.shape[0]
    lmw, sw, Cn, G = _workspace(C.shape[1], C.shape[2])
    R, t, Rb, tb, _, rv = sw
    status = out[2]
    vecs = out[1]
    cws = closed_form_scratch()
    start = np.empty(6)
    prev = first.copy()
    prev2 = first.copy()
    guess = np.empty(6)
    extrapolate = opts[O_EXTRAPOLATE] != 0.0
    k1 = -2                          # the last two converged samples (prev, prev2)
    k2 = -2
    # the first try of each sample: from the previous pose, without retries
    plain = opts.copy()
    plain[O_RETRIES] = 0.0
    kim18 = np.int64(CF_KIM18)
    ncf = np.zeros(3)
    Rsave = np.empty((3, 3))
    tsave = np.empty(3)
    use_cf = opts[O_USE_CLOSED_FORM] != 0.0
    retries = opts[O_RETRIES] != 0.0
    for k in range(N):
        s, cn, fn = normalise_coupling(C[k], cnorm[k], Cn, G)
        if not s > 0.0:
            _store_invalid(k, out)
            continue
        geo = unpack_any(mdl, s)
        res_fac = s * (s / cn)  # normalised sum of squares -> resnorm
        guess[:] = prev
        if extrapolate and k1 == k - 1 and k2 == k - 2:
            dt2 = 0.0
            dr2 = 0.0
            for a in range(3):
                dt2 += (prev[a] - prev2[a]) ** 2
                dr2 += (prev[3 + a] - prev2[3 + a]) ** 2
            if dt2 < 1e-4 and dr2 < 1e-2:
                for a in range(6):
                    guess[a] = 2.0 * prev[a] - prev2[a]
        # the plain try from the guess, then (if it fails the retry test) the restart: one
        # _solve_sample call site, so that its code is compiled once into this kernel
        cost = np.inf
        it = 0
        stop = STOP_ITERATION_LIMIT
        fresh = False
        run_opts = plain
        run_start = guess
        for attempt in range(2):
            if attempt == 1:
                if _acceptable(cost, res_fac, fn, opts) or not (use_cf or retries):
                    break
                for a in range(6):  # element by element: a slice copy compiles a shape check
                    start[a] = prev[a]
                if use_cf:
                    for a in range(3):
                        ncf[a] = nvec[k, a]
                    if ncf[0] == 0.0 and ncf[1] == 0.0 and ncf[2] == 0.0:
                        ncf[0] = 1.0
                    if closed_form_start(mdl, kim18, Cn, W, opts[O_CF_GAIN] / s, ncf,
                                         opts[O_RANK_TOL], R, t, cws) != ST_INVALID_INPUT:
                        rotvec_from_matrix(R, rv)
                        for a in range(3):
                            start[a] = t[a]
                            start[3 + a] = rv[a]
                _copy_pose(Rb, tb, Rsave, tsave)
                run_opts = opts
                run_start = start
            cost2, it2, stop2, fresh2 = _solve_sample(geo, Cn, res_fac, fn, run_start,
                                                      nvec[k], box, run_opts, sw, lmw)
            it += it2
            if attempt == 0 or cost2 < cost:
                cost = cost2
                stop = stop2
                fresh = fresh2
            else:                    # the restart did no better: the first try's pose,
                _copy_pose(Rsave, tsave, Rb, tb)
                fresh = False        # whose couplings the restart's evaluations overwrote
        _finish(k, mdl, C[k], s, cn, fn, nvec[k], box, opts, it, stop, fresh, sw, lmw, out)
        if status[k] == ST_CONVERGED:
            for a in range(6):
                prev2[a] = prev[a]
                prev[a] = vecs[k, a]
            k2 = k1
            k1 = k
