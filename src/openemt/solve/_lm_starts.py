"""Starts and batch helpers of the compiled Levenberg-Marquardt solver: the model check, the
closed-form and multi-start initial poses, the batched kernel call and the 5-DOF canonical form
(used by :class:`openemt.solve._prepared.PreparedLM`, behind :func:`openemt.solve.solve_lm`)."""

from __future__ import annotations

import numba
import numpy as np

from .._errors import InputError
from ..field import DipoleModel, check_dipole_model
from ..geometry import pose_from_vector, vector_from_pose
from ._closed_form import (
    check_couplings,
    new_outputs,
    result_from_outputs,
    solve_kim18,
    solve_kuipers,
    solve_svd,
)
from ._hemisphere import DEFAULT_HEMISPHERE, hemisphere_vectors
from ._lm import lm_batch
from ._packing import O_MAX_ITER, O_RETRIES, O_RETRY_RELATIVE
from ._result import Status
from ._validity import SAME_MINIMUM_RTOL

__all__ = ["canonical_5dof"]

_CLOSED = {"kim18": solve_kim18, "svd": solve_svd, "kuipers": solve_kuipers}


def _check_model(model) -> DipoleModel:
    check_dipole_model(model)
    n_so, n_se = model.n_source, model.n_sensor
    need = 5 if n_se == 1 else 6
    if n_so * n_se < need or (n_se > 1 and n_so < 2):
        raise InputError(f"expected at least {need} couplings (n_source * n_sensor) and >= 2 "
                         f"source coils for a {need}-DOF solve, got {n_so}x{n_se}")
    return model


def _concentric_for(model, concentric_model):
    """The concentric model used for closed-form starts, or None when none applies."""
    if concentric_model is not None:
        check_dipole_model(concentric_model, "concentric_model")
        return concentric_model
    if model.n_source == 3 and model.n_sensor == 3:
        if model.is_concentric:
            return model
        # the same moments with the coil offsets dropped: a good start when offsets << range
        return model.replace(L_so=np.zeros((3, 3)), L_se=np.zeros((3, 3)))
    return None


def closed_form_start(couplings, model, conc, method, hemi, explicit, n_correct=4):
    """Closed-form start under the concentric model ``conc``. When ``conc`` only drops the
    model's coil offsets (no concentric model given), the measured couplings are corrected by
    the offset effect at the current estimate, ``C - (C_model(P) - C_conc(P))``, and the closed
    form re-solved ``n_correct`` times (a fixed-point iteration that removes most of the
    offset bias for sources with coil offsets of a few centimetres)."""
    f = _CLOSED[method]

    def closed(c):
        # a start: judged by the LM solution, not here
        return f(c, conc, hemisphere=hemi, max_relative_residual=None, max_range=None)

    res = closed(couplings)
    if explicit or model.is_concentric:
        return res.pose_vectors
    C, _ = check_couplings(couplings)
    for _ in range(n_correct):
        ok = np.all(np.isfinite(res.pose_vectors), axis=1)
        if not np.any(ok):
            break
        C2 = C.copy()
        with np.errstate(invalid="ignore", over="ignore"):
            C2[ok] -= model.coupling(res.poses[ok]) - conc.coupling(res.poses[ok])
        nxt = closed(C2)
        keep = ~np.all(np.isfinite(nxt.pose_vectors), axis=1)
        vecs = np.where(keep[:, None], res.pose_vectors, nxt.pose_vectors)
        poses = np.where(keep[:, None, None], res.poses, nxt.poses)
        res = res.replace(poses=poses, pose_vectors=vecs)
    return res.pose_vectors


def _table_starts(C, couplings, model, conc, hemi, nvec, table, k=4):
    """Cold-start candidates of a non-concentric 3x3 model (no concentric model given),
    ``(k + 1, N, 6)`` ordered per sample by their coupling residual under ``model``, lowest
    first (a candidate that is not finite last): the Kim18 closed form under the concentric
    model ``conc`` and the ``k`` nearest positions of the invariant table ``table``
    (:class:`~openemt.solve._cold_start.InvariantTable`) with their Procrustes rotations."""
    kim18 = _CLOSED["kim18"](couplings, conc, hemisphere=hemi, max_relative_residual=None,
                             max_range=None).pose_vectors
    return np.swapaxes(table.candidates(C, nvec, kim18, k), 0, 1)


def _merge(result, rows, again):
    """``result`` with rows ``rows`` replaced by those of ``again`` (solved for them) that have
    a lower relative residual (:func:`_keep_better`); the iterations of both runs are added."""
    out = _keep_better(result, rows, again)
    iterations = out.iterations.copy()
    iterations[rows] = result.iterations[rows] + again.iterations
    return out.replace(iterations=iterations)


def _row_hemispheres(nvec):
    """The closed-form start's hemisphere of rows with hemisphere vectors ``nvec``: their own,
    and the closed forms' default where there is none (as ``solve`` passes them)."""
    return np.where(np.any(nvec != 0.0, axis=1)[:, None], nvec,
                    hemisphere_vectors(DEFAULT_HEMISPHERE, 1))


def _table_solve(C, cnorm, couplings, model, conc, hemi, mdl, nvec, box, opts, table, level,
                 k=4, same_tol=1e-6):
    """The cold solve of a non-concentric 3x3 model (docs/solve.md#cold-start).

    LM from the best candidate of ``_table_starts``. A sample whose relative residual is above
    ``level``, or that reached the iteration limit, is solved again from the next candidate
    (keeping the lower residual), and so on, until it is below the level or *settled*: a
    second candidate converged to the same position (within ``same_tol`` m) and the residual
    passes the retry test (``opts[O_RETRY_RELATIVE]``, the validity threshold by default),
    from a start distinct from the kept run's (``_distinct``): two different starts found one
    minimum whose residual is the data's, not a wrong
    minimum's. Samples still pending after all candidates are solved as before this start
    existed (Kim18 start with ILEMT's sign-flip retries), keeping the lower residual. Last, one
    polishing step from every solution. ``iterations`` counts every run of a sample.

    Returns the result and the settled rows' mask (the caller's exploration skips them).
    """
    cands = _table_starts(C, couplings, model, conc, hemi, nvec, table, k)
    plain = opts.copy()
    plain[O_RETRIES] = 0.0
    result = _run_batch(C, cnorm, cands[0], mdl, nvec, box, plain)
    settled = np.zeros(C.shape[0], dtype=bool)

    def pending(rows):
        r = result.relative_residual[rows]
        with np.errstate(invalid="ignore"):
            bad = ~(r <= level) | (result.status[rows] == Status.MAX_ITERATIONS)
        return rows[bad & (result.status[rows] != Status.INVALID_INPUT) & ~settled[rows]]

    redo = pending(np.arange(C.shape[0]))
    if redo.size:
        # the second candidate, then the previous default start (the offset-corrected Kim18
        # closed form): an independent start; where it finds the same minimum, that minimum
        # is settled; then the other candidates
        v = np.full(cands[0].shape, np.nan)
        v[redo] = closed_form_start(couplings[redo], model, conc, "kim18",
                                     _row_hemispheres(nvec[redo]), False)
        starts = [(cands[1], False), (v, True)] + [(c, False) for c in cands[2:]]
    else:
        starts = []
    for v, independent in starts:
        redo = redo[np.all(np.isfinite(v[redo]), axis=1)]
        if not redo.size:
            break
        again = _run_batch(C[redo], cnorm[redo], v[redo], mdl, nvec[redo], box, plain)
        with np.errstate(invalid="ignore"):
            same = ((np.linalg.norm(again.pose_vectors[:, :3]
                                    - result.pose_vectors[redo, :3], axis=1) <= same_tol)
                    & (again.status != Status.MAX_ITERATIONS)
                    & (result.status[redo] != Status.MAX_ITERATIONS) & independent)
        result = _merge(result, redo, again)
        with np.errstate(invalid="ignore"):
            settled[redo] = same & (result.relative_residual[redo] <= opts[O_RETRY_RELATIVE])
        redo = pending(redo)
    rows = np.flatnonzero(settled)
    if rows.size:
        # a settled minimum: also the 2 best table entries away from it (another region
        # whose couplings look alike), which the exploration's multi-start grid would
        # otherwise be needed for
        far = table.candidates(C[rows], nvec[rows], np.full((rows.size, 6), np.nan), 2,
                               away=result.pose_vectors[rows, :3])
        probe = plain.copy()
        probe[O_MAX_ITER] = 20
        for j in range(2):
            v = far[:, j]
            sub = rows[np.all(np.isfinite(v), axis=1)]
            v = v[np.all(np.isfinite(v), axis=1)]
            if not sub.size:
                continue
            # a 20-iteration probe; where it is already lower, finished from there
            again = _run_batch(C[sub], cnorm[sub], v, mdl, nvec[sub], box, probe)
            with np.errstate(invalid="ignore"):
                lower = again.relative_residual < result.relative_residual[sub]
            result.iterations[sub] += again.iterations
            sub = sub[lower]
            if sub.size:
                result = _merge(result, sub, _run_batch(C[sub], cnorm[sub],
                                                        again.pose_vectors[lower], mdl,
                                                        nvec[sub], box, plain))
    if redo.size and opts[O_RETRIES] != 0.0:
        init = closed_form_start(couplings[redo], model, conc, "kim18",
                                  _row_hemispheres(nvec[redo]), False)
        result = _merge(result, redo, _run_batch(C[redo], cnorm[redo], init, mdl, nvec[redo],
                                                 box, opts))
    # polish: one more Gauss-Newton step from each solution (the LM stops once its next step
    # is predicted below xtol, which leaves up to ~xtol * |t| of the minimum; this step brings
    # it to rounding, as the start it came from no longer decides how close it stopped)
    rows = np.flatnonzero(np.all(np.isfinite(result.pose_vectors), axis=1))
    result = _merge(result, rows, _run_batch(C[rows], cnorm[rows], result.pose_vectors[rows],
                                             mdl, nvec[rows], box, plain))
    return result, settled


def _bounds(bounds):
    if bounds is None:
        return np.full(3, -np.inf), np.full(3, np.inf)
    b = np.asarray(bounds, dtype=np.float64)
    if b.ndim == 0:
        if not b > 0:
            raise InputError(f"expected a positive `bounds` half-width in m, got {float(b)}")
        return np.full(3, -float(b)), np.full(3, float(b))
    if b.shape != (3, 2) or not np.all(b[:, 0] < b[:, 1]):
        raise InputError(f"expected `bounds` as a half-width or a (3, 2) array of [low, high] "
                         f"with low < high, got shape {b.shape}")
    return np.ascontiguousarray(b[:, 0]), np.ascontiguousarray(b[:, 1])


def _multistart_init(C, cnorm, mdl, model, nvec, box, opts):
    """Best of a coarse set of starts per sample: 14 directions x 4 orientations at the
    distance suggested by the coupling magnitude (30 iterations each, no retries)."""
    dirs = [np.eye(3)[i] * s for i in range(3) for s in (1.0, -1.0)]
    dirs += [np.array([a, b, c]) / np.sqrt(3) for a in (1, -1) for b in (1, -1) for c in (1, -1)]
    rots = [np.zeros(3), np.array([np.pi, 0, 0]), np.array([0, np.pi, 0]),
            np.array([0, 0, np.pi])]
    scale = model.gain * np.linalg.norm(model.M_so) * np.linalg.norm(model.M_se)
    fro = np.linalg.norm(C.reshape(C.shape[0], -1), axis=1)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        dist = np.cbrt(scale / fro)
    dist = np.where(np.isfinite(dist) & (dist > 0), dist, 0.1)
    quick = opts.copy()
    quick[O_MAX_ITER] = 30
    quick[O_RETRIES] = 0.0
    n = C.shape[0]
    best_res = np.full(n, np.inf)
    best = np.zeros((n, 6))
    best[:, 0] = dist
    for d in dirs:
        for r in rots:
            init = np.empty((n, 6))
            init[:, :3] = dist[:, None] * d
            init[:, 3:] = r
            out = _run_batch(C, cnorm, init, mdl, nvec, box, quick)
            better = out.relative_residual < best_res
            best_res[better] = out.relative_residual[better]
            best[better] = out.pose_vectors[better]
    return best


def _run_batch(C, cnorm, init, mdl, nvec, box, opts):
    n = C.shape[0]
    out = new_outputs(n)
    init = np.ascontiguousarray(init, dtype=np.float64)

    def block(a, b):
        lm_batch(mdl, C[a:b], cnorm[a:b], init[a:b], nvec[a:b], box, opts,
                 tuple(o[a:b] for o in out))

    threads = numba.get_num_threads()
    if threads <= 1 or n < 512:
        block(0, n)
    else:
        # the kernel releases the GIL: row blocks in a thread pool use all cores
        from concurrent.futures import ThreadPoolExecutor

        edges = np.linspace(0, n, 4 * threads + 1).astype(int)
        with ThreadPoolExecutor(threads) as pool:
            list(pool.map(block, edges[:-1], edges[1:]))
    return result_from_outputs(out, "lm")


def canonical_5dof(result, model):
    """A 5-DOF result (single-coil sensor) with every finite rotation replaced by the zero-roll
    one with the same sensor axis: the shortest-arc rotation taking the coil's moment direction
    ``m0`` to the solved axis ``R m0``, with the coil position ``R L_se + t`` kept. The roll
    about the axis is not observable, so the couplings (and residuals) do not change."""
    m0 = model.M_se[:, 0] / np.linalg.norm(model.M_se[:, 0])
    l0 = model.L_se[:, 0]
    ok = np.all(np.isfinite(result.pose_vectors), axis=1)
    R = result.poses[ok, :3, :3]
    p = R @ l0 + result.poses[ok, :3, 3]
    a = R @ m0
    w = np.cross(m0, a)
    sn = np.linalg.norm(w, axis=1)
    c = a @ m0
    with np.errstate(invalid="ignore", divide="ignore"):
        rv = w * np.where(sn > 0, np.arctan2(sn, c) / sn, 0.0)[:, None]
    # 180 degrees: about an axis perpendicular to m0
    perp = np.array([0.0, m0[2], -m0[1]]) if abs(m0[0]) < 0.9 else np.array([-m0[2], 0.0, m0[0]])
    rv[(sn < 1e-12) & (c < 0)] = np.pi * perp / np.linalg.norm(perp)
    P = pose_from_vector(np.hstack([np.zeros_like(p), rv]))
    P[:, :3, 3] = p - P[:, :3, :3] @ l0
    poses = result.poses.copy()
    vecs = result.pose_vectors.copy()
    poses[ok] = P
    vecs[ok] = vector_from_pose(P)
    return result.replace(poses=poses, pose_vectors=vecs)


def _keep_better(result, rows, again):
    """``result`` with rows ``rows`` replaced by those of ``again`` (solved for them) that have
    a lower relative residual, or at the same minimum met the convergence test where the kept
    run hit its iteration limit (:func:`~openemt.solve._validity.better_run`)."""
    r, b = again.relative_residual, result.relative_residual[rows]
    ok_new = again.status != Status.MAX_ITERATIONS
    ok_old = result.status[rows] != Status.MAX_ITERATIONS
    with np.errstate(invalid="ignore"):
        # better_run's rule, batched (a NaN residual is never better, nor replaced)
        same = np.abs(r - b) <= SAME_MINIMUM_RTOL * np.abs(b)
        better = np.where(same & (ok_new != ok_old), ok_new, r < b)
    return result.with_rows(rows[better], again, better)


def _first_start(C, cnorm, model, conc, mdl, nvec, box, opts, hemisphere):
    """Start of tracking: the Kim18 closed form (if a concentric model applies) of the first
    sample with finite non-zero couplings, else the multi-start solution of that sample; the
    unit distance along the hemisphere if there is no such sample."""
    flat = C.reshape(C.shape[0], -1)
    ok = np.flatnonzero(np.all(np.isfinite(flat), axis=1) & np.any(flat != 0, axis=1))
    if not ok.size:
        first = np.zeros(6)
        first[:3] = nvec[0] if np.any(nvec[0]) else (1.0, 0.0, 0.0)
        return first
    k0 = ok[0]
    if conc is not None:
        hemi = (nvec[k0] if hemisphere is not None and np.any(nvec[k0])
                else DEFAULT_HEMISPHERE)
        first = solve_kim18(C[k0:k0 + 1], conc, hemisphere=hemi, max_relative_residual=None,
                            max_range=None).pose_vectors[0]
        if np.all(np.isfinite(first)):
            return first
    return _multistart_init(C[k0:k0 + 1], cnorm[k0:k0 + 1], mdl, model, nvec[k0:k0 + 1], box,
                            opts)[0]
