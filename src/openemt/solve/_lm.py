"""Compiled batched Levenberg-Marquardt pose solver for any dipole model.

Per sample, the unknown pose ``(R, t)`` is updated by a translation increment and a local
rotation increment, ``t <- t + dt``, ``R <- exp([dphi]x) R`` (so no rotation-vector Jacobian is
needed). The model and its analytic derivatives come from the one compiled dipole kernel
``openemt.field._dipole_kernel.dipole_eval``. The residual is ``C_pred - C_meas`` over all
``n_source * n_sensor`` couplings (unnormalised, as ILEMT, docs/paper-procedure.md#iterative-solution).

Single-coil sensors (``n_sensor == 1``) are 5-DOF: the roll about the sensor axis is not
observable. The increment ``dphi`` is then restricted to the plane perpendicular to the sensor
axis, and the reported rotation is the shortest-arc rotation taking the sensor coil's moment
direction to the solved axis (zero roll, with the coil position kept).

Constraints: a hemisphere half-space ``t . n >= 0`` (per sample; ``n = 0`` means none) and an
optional position box, enforced by projecting every trial point (projected LM). ILEMT's retries
(docs/paper-procedure.md#iterative-solution) restart an invalid solve from the initial pose with one pose-vector
component's sign flipped, for each of the 6 components, and keep the first valid (else the best)
result.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..field._dipole_kernel import dipole_eval
from ._closed_form import closed_form_one, spectral_norm
from ._linalg import cholesky_solve, exp_so3, rotvec_from_matrix, store_nan_pose, store_pose

__all__ = ["lm_batch", "lm_track"]

_BIG = 1e300


@njit(cache=True, inline="always")
def _project(t, n, lo, hi):
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


@njit(cache=True, inline="always")
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


@njit(cache=True, inline="always")
def _eval(L_so, M_so, L_se, M_se, gain, Cm, R, t, Cp, dt, dphi, d1, d2, want):
    dipole_eval(L_so, M_so, L_se, M_se, gain, R, t, Cp, dt, dphi, d1, d2, want)
    ss = 0.0
    for i in range(Cm.shape[0]):
        for j in range(Cm.shape[1]):
            r = Cp[i, j] - Cm[i, j]
            ss += r * r
    return ss


@njit(cache=True)
def _lm_one(L_so, M_so, L_se, M_se, gain, Cm, R, t, n, lo, hi, five, max_iter, xtol,
            Cp, dt, dphi, Cp2, dt2, dphi2, d1, d2, Jb, JtJ, A, Lc, g, delta, basis, R2, t2, dR,
            phi):
    """Levenberg-Marquardt from ``(R, t)`` (updated in place). Returns (cost, iterations, code)
    with code 0 = converged (or stalled at a minimum), 1 = iteration limit."""
    n_so = Cm.shape[0]
    n_se = Cm.shape[1]
    _project(t, n, lo, hi)
    cost = _eval(L_so, M_so, L_se, M_se, gain, Cm, R, t, Cp, dt, dphi, d1, d2, True)
    lam = 1e-4
    lam_small = 1e-3
    prev_rel = 0.0
    it = 0
    code = 1
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
            if ok and lam <= lam_small:
                # converged: the Gauss-Newton step is below tolerance; apply it without a new
                # evaluation (the cost changes by O(step^2), far below rounding of the test)
                st2 = delta[0] * delta[0] + delta[1] * delta[1] + delta[2] * delta[2]
                sr2 = 0.0
                for c in range(nr):
                    sr2 += delta[3 + c] * delta[3 + c]
                tn = np.sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2])
                if np.sqrt(st2) <= xtol * (tn + xtol) and np.sqrt(sr2) <= xtol:
                    for a in range(3):
                        t[a] += delta[a]
                    _project(t, n, lo, hi)
                    for a in range(3):
                        acc = 0.0
                        for c in range(nr):
                            acc += basis[a, c] * delta[3 + c]
                        phi[a] = acc
                    exp_so3(phi, dR)
                    for a in range(3):
                        for b in range(3):
                            R2[a, b] = (dR[a, 0] * R[0, b] + dR[a, 1] * R[1, b]
                                        + dR[a, 2] * R[2, b])
                    for a in range(3):
                        for b in range(3):
                            R[a, b] = R2[a, b]
                    return cost, it, 0
            if ok:
                # trust limit: one step moves the sensor by at most half its distance (keeps
                # an unconstrained solve from running off to infinity, where C -> 0)
                st2 = delta[0] * delta[0] + delta[1] * delta[1] + delta[2] * delta[2]
                tn2 = t[0] * t[0] + t[1] * t[1] + t[2] * t[2]
                if st2 > 0.25 * tn2 and tn2 > 0.0:
                    f = np.sqrt(0.25 * tn2 / st2)
                    for a in range(npar):
                        delta[a] *= f
                for a in range(3):
                    t2[a] = t[a] + delta[a]
                _project(t2, n, lo, hi)
                for a in range(3):
                    acc = 0.0
                    for c in range(nr):
                        acc += basis[a, c] * delta[3 + c]
                    phi[a] = acc
                exp_so3(phi, dR)
                for a in range(3):
                    for b in range(3):
                        R2[a, b] = dR[a, 0] * R[0, b] + dR[a, 1] * R[1, b] + dR[a, 2] * R[2, b]
                # linear-rate prediction: if this step is much smaller than the previous
                # accepted one and the step after it would be below tolerance, this is the
                # last step; its Jacobian is not needed
                rel = max(np.sqrt(delta[0] * delta[0] + delta[1] * delta[1]
                                  + delta[2] * delta[2]) / (np.sqrt(tn2) + xtol),
                          np.sqrt(phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2]))
                final = (prev_rel > 0.0 and lam <= lam_small and rel < 0.5 * prev_rel
                         and rel * rel / prev_rel <= xtol)
                cost2 = _eval(L_so, M_so, L_se, M_se, gain, Cm, R2, t2, Cp2, dt2, dphi2, d1, d2,
                              not final)
                if cost2 <= cost:
                    if final:
                        for a in range(3):
                            t[a] = t2[a]
                            for b in range(3):
                                R[a, b] = R2[a, b]
                        return cost2, it, 0
                    accepted = True
                    prev_rel = rel
                    break
            lam *= 10.0
            if lam > 1e12:
                break
        if not accepted:
            code = 0  # no decrease possible: at a minimum within rounding
            break
        # accept
        step_t = 0.0
        norm_t = 0.0
        step_r = 0.0
        for a in range(3):
            step_t += (t2[a] - t[a]) ** 2
            norm_t += t2[a] * t2[a]
            step_r += phi[a] * phi[a]
            t[a] = t2[a]
            for b in range(3):
                R[a, b] = R2[a, b]
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
            code = 0
            break
    return cost, it, code


@njit(cache=True)
def _canonical_5dof(R, t, L_se, M_se):
    """Replace R by the zero-roll rotation with the same sensor axis (coil position kept)."""
    p = np.empty(3)
    for a in range(3):
        p[a] = R[a, 0] * L_se[0, 0] + R[a, 1] * L_se[1, 0] + R[a, 2] * L_se[2, 0] + t[a]
    m0 = M_se[:, 0] / np.sqrt(np.sum(M_se[:, 0] ** 2))
    a = np.empty(3)
    for i in range(3):
        a[i] = R[i, 0] * m0[0] + R[i, 1] * m0[1] + R[i, 2] * m0[2]
    # shortest arc m0 -> a
    c = m0[0] * a[0] + m0[1] * a[1] + m0[2] * a[2]
    w = np.empty(3)
    w[0] = m0[1] * a[2] - m0[2] * a[1]
    w[1] = m0[2] * a[0] - m0[0] * a[2]
    w[2] = m0[0] * a[1] - m0[1] * a[0]
    sn = np.sqrt(np.sum(w * w))
    if sn < 1e-12 and c < 0.0:
        # 180 degrees: about any axis perpendicular to m0
        if abs(m0[0]) < 0.9:
            w[0], w[1], w[2] = 0.0, m0[2], -m0[1]
        else:
            w[0], w[1], w[2] = -m0[2], 0.0, m0[0]
        w /= np.sqrt(np.sum(w * w))
        w *= np.pi
    elif sn > 0.0:
        w *= np.arctan2(sn, c) / sn
    exp_so3(w, R)
    for i in range(3):
        t[i] = p[i] - (R[i, 0] * L_se[0, 0] + R[i, 1] * L_se[1, 0] + R[i, 2] * L_se[2, 0])


@njit(cache=True)
def _solve_sample(L_so, M_so, L_se, M_se, gain, Cm, cn, init, fallback, has_fallback, n, lo,
                  hi, five, max_iter, xtol, thr, retries, R, t, Rb, tb, ws_f):
    """Solve one sample from pose vector ``init`` with ILEMT's retry rule; the best pose goes
    to ``Rb, tb``. Returns (residual, iterations, code)."""
    (Cp, dt, dphi, Cp2, dt2, dphi2, d1, d2, Jb, JtJ, A, Lc, g, delta, basis, R2, t2, dR, phi,
     v0) = ws_f
    best = _BIG
    best_code = 1
    total_it = 0
    n_bases = 2 if has_fallback else 1
    n_flips = 6 if retries else 0
    # plain solves from each base first, then ILEMT's sign-flip retries of the last base
    for trial in range(n_bases + n_flips):
        src = init
        if has_fallback and trial >= 1:
            src = fallback
        for a in range(6):
            v0[a] = src[a]
        # ILEMT: an initial pose outside the hemisphere gets its translation negated
        if v0[0] * n[0] + v0[1] * n[1] + v0[2] * n[2] < 0.0:
            v0[0], v0[1], v0[2] = -v0[0], -v0[1], -v0[2]
        if trial >= n_bases:
            c = trial - n_bases
            v0[c] = -v0[c]
        for a in range(3):
            t[a] = v0[a]
            phi[a] = v0[3 + a]
        exp_so3(phi, R)
        cost, it, code = _lm_one(L_so, M_so, L_se, M_se, gain, Cm, R, t, n, lo, hi, five,
                                 max_iter, xtol, Cp, dt, dphi, Cp2, dt2, dphi2, d1, d2, Jb,
                                 JtJ, A, Lc, g, delta, basis, R2, t2, dR, phi)
        total_it += it
        res = cost / cn
        if res < best:
            best = res
            best_code = code
            for a in range(3):
                tb[a] = t[a]
                for b in range(3):
                    Rb[a, b] = R[a, b]
        if best < thr:
            break
    return best, total_it, best_code


@njit(cache=True)
def _workspace(n_so, n_se):
    m = n_so * n_se
    return (np.empty((n_so, n_se)), np.empty((n_so, n_se, 3)), np.empty((n_so, n_se, 3)),
            np.empty((n_so, n_se)), np.empty((n_so, n_se, 3)), np.empty((n_so, n_se, 3)),
            np.empty((n_so, n_se, 3)), np.empty((n_so, n_se, 3)), np.empty((m, 6)),
            np.empty((6, 6)), np.empty((6, 6)), np.empty((6, 6)), np.empty(6), np.empty(6),
            np.empty((3, 3)), np.empty((3, 3)), np.empty(3), np.empty((3, 3)), np.empty(3),
            np.empty(6))


@njit(cache=True)
def _finish(k, Cm, cn, res, it, code, Rb, tb, n, lo, hi, five, L_se, M_se, thr, ambig_tol,
            poses, vecs, status, residual, iterations, rv):
    if five:
        _canonical_5dof(Rb, tb, L_se, M_se)
    rotvec_from_matrix(Rb, rv)
    store_pose(k, Rb, tb, rv, poses, vecs)
    residual[k] = res
    iterations[k] = it
    on_box = False
    for a in range(3):
        if tb[a] <= lo[a] or tb[a] >= hi[a]:
            on_box = True
    nt = np.sqrt(tb[0] * tb[0] + tb[1] * tb[1] + tb[2] * tb[2])
    dn = tb[0] * n[0] + tb[1] * n[1] + tb[2] * n[2]
    has_h = n[0] != 0.0 or n[1] != 0.0 or n[2] != 0.0
    if on_box:
        status[k] = 4
    elif has_h and dn <= ambig_tol * nt:
        status[k] = 3
    elif code == 1:
        status[k] = 1
    elif not res < thr:
        status[k] = 5
    else:
        status[k] = 0


@njit(cache=True)
def _bad_input(Cm, cn):
    if not (cn > 0.0 and np.isfinite(cn)):
        return True
    for i in range(Cm.shape[0]):
        for j in range(Cm.shape[1]):
            if not np.isfinite(Cm[i, j]):
                return True
    return False


@njit(cache=True)
def _mark_invalid(k, poses, vecs, status, residual, iterations):
    store_nan_pose(k, poses, vecs)
    status[k] = 2
    residual[k] = np.nan
    iterations[k] = 0


@njit(cache=True, nogil=True)
def lm_batch(L_so, M_so, L_se, M_se, gain, C, cnorm, init, nvec, lo, hi, five, max_iter, xtol,
             thr, ambig_tol, retries, poses, vecs, status, residual, iterations):
    """Independent LM solves of every sample (releases the GIL: callers may run row blocks in
    threads)."""
    N = C.shape[0]
    n_so = C.shape[1]
    n_se = C.shape[2]
    ws = _workspace(n_so, n_se)
    G = np.empty((n_se, n_se))
    R = np.empty((3, 3))
    t = np.empty(3)
    Rb = np.empty((3, 3))
    tb = np.empty(3)
    rv = np.empty(3)
    dummy = np.empty(6)
    for k in range(N):
        cn = cnorm[k]
        if cn < 0.0:
            cn = spectral_norm(C[k], G)
        if _bad_input(C[k], cn) or not np.all(np.isfinite(init[k])):
            _mark_invalid(k, poses, vecs, status, residual, iterations)
            continue
        res, it, code = _solve_sample(L_so, M_so, L_se, M_se, gain, C[k], cn, init[k], dummy,
                                      False, nvec[k], lo, hi, five, max_iter, xtol, thr,
                                      retries, R, t, Rb, tb, ws)
        _finish(k, C[k], cn, res, it, code, Rb, tb, nvec[k], lo, hi, five, L_se, M_se, thr,
                ambig_tol, poses, vecs, status, residual, iterations, rv)


@njit(cache=True, nogil=True)
def lm_track(L_so, M_so, L_se, M_se, gain, C, cnorm, first, use_cf, Wso, Wse, cf_gain, nvec, lo,
             hi, five, max_iter, xtol, thr, ambig_tol, retries, poses, vecs, status, residual,
             iterations):
    """Sequential tracking: each sample starts from the previous valid solution (the first from
    ``first``). An invalid result is re-solved from the Kim18 closed form of the sample under
    the concentric moments ``Wso = M_so^-T``, ``Wse = M_se^-1`` (if ``use_cf``), then with the
    sign-flip retries."""
    N = C.shape[0]
    n_so = C.shape[1]
    n_se = C.shape[2]
    ws = _workspace(n_so, n_se)
    G = np.empty((n_se, n_se))
    R = np.empty((3, 3))
    t = np.empty(3)
    Rb = np.empty((3, 3))
    tb = np.empty(3)
    rv = np.empty(3)
    prev = first.copy()
    fb = np.empty(6)
    C0 = np.empty((3, 3))
    U = np.empty((3, 3))
    V = np.empty((3, 3))
    B = np.empty((3, 3))
    s = np.empty(3)
    ncf = np.zeros(3)
    for k in range(N):
        cn = cnorm[k]
        if cn < 0.0:
            cn = spectral_norm(C[k], G)
        if _bad_input(C[k], cn):
            _mark_invalid(k, poses, vecs, status, residual, iterations)
            continue
        res, it, code = _solve_sample(L_so, M_so, L_se, M_se, gain, C[k], cn, prev, prev,
                                      False, nvec[k], lo, hi, five, max_iter, xtol, thr, False,
                                      R, t, Rb, tb, ws)
        if not res < thr and (use_cf or retries):
            has_fb = False
            if use_cf:
                ncf[:] = nvec[k]
                if ncf[0] == 0.0 and ncf[1] == 0.0 and ncf[2] == 0.0:
                    ncf[0] = 1.0
                st = closed_form_one(2, C[k], Wso, Wse, cf_gain, ncf, 1e-6, 0.0, R, t, C0, U,
                                     s, V, B)
                if st != 2:
                    has_fb = True
                    rotvec_from_matrix(R, rv)
                    for a in range(3):
                        fb[a] = t[a]
                        fb[3 + a] = rv[a]
            Rsave = Rb.copy()
            tsave = tb.copy()
            res2, it2, code2 = _solve_sample(L_so, M_so, L_se, M_se, gain, C[k], cn,
                                             fb if has_fb else prev, prev, False, nvec[k], lo,
                                             hi, five, max_iter, xtol, thr, retries, R, t, Rb,
                                             tb, ws)
            it += it2
            if res2 < res:
                res = res2
                code = code2
            else:
                Rb[:, :] = Rsave
                tb[:] = tsave
        _finish(k, C[k], cn, res, it, code, Rb, tb, nvec[k], lo, hi, five, L_se, M_se, thr,
                ambig_tol, poses, vecs, status, residual, iterations, rv)
        if status[k] == 0:
            for a in range(6):
                prev[a] = vecs[k, a]
