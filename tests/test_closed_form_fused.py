"""The closed-form batch kernel judges each pose with the concentric model's residual in the same
pass (``concentric_eval`` in blocks of samples). It must give exactly what the per-sample path
it replaced gives: normalise, solve, then the full dipole model (``dipole_eval``) at the pose."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from openemt.field import DipoleModel
from openemt.field._dipole_kernel import concentric_eval, dipole_eval
from openemt.geometry import pose_from_vector
from openemt.solve import Status, solve_kim18, solve_kuipers, solve_svd
from openemt.solve._closed_form import (
    _METHODS,
    check_couplings,
    closed_form_one,
    closed_form_scratch,
    new_outputs,
    normalise_coupling,
    residuals_at,
    whitening,
)
from openemt.solve._hemisphere import hemisphere_vectors
from openemt.solve._linalg import rotvec_from_matrix, rotvec_from_quat, store_nan_pose, store_pose
from openemt.solve._packing import M_GAIN, O_RANK_TOL, pack_model, pack_options, unpack_model
from openemt.solve._result import ST_INVALID_INPUT
from openemt.solve._validity import classify

SOLVERS = {"svd": solve_svd, "kuipers": solve_kuipers, "kim18": solve_kim18}


@njit
def _per_sample_path(method, C, cnorm, W, mdl, nvec, opts, out):
    """The path before the fused kernel: one sample at a time, residual by ``dipole_eval``."""
    poses, vecs, status, residual, relres, iterations = out
    R = np.empty((3, 3))
    t = np.empty(3)
    cws = closed_form_scratch()
    q = cws[5]
    Cn = np.empty((3, 3))
    G = np.empty((3, 3))
    Cp = np.empty((3, 3))
    rv = np.empty(3)
    dummy = np.empty((3, 3, 3))
    jac = (dummy, dummy, dummy, dummy)
    box = np.empty((2, 3))
    box[0] = -np.inf
    box[1] = np.inf
    geo = unpack_model(mdl, 1.0)
    for k in range(C.shape[0]):
        iterations[k] = 0
        n = nvec[0] if nvec.shape[0] == 1 else nvec[k]
        s, cn, fn = normalise_coupling(C[k], cnorm[k], Cn, G)
        if not s > 0.0 or closed_form_one(method, Cn, W, mdl[M_GAIN] / s, n, opts[O_RANK_TOL],
                                          R, t, cws) == ST_INVALID_INPUT:
            store_nan_pose(k, poses, vecs)
            status[k] = ST_INVALID_INPUT
            residual[k] = np.nan
            relres[k] = np.nan
            continue
        if q[0] >= 0.0:
            rotvec_from_quat(q, rv)
        else:
            rotvec_from_matrix(R, rv)
        store_pose(k, R, t, rv, poses, vecs)
        residual[k], rho = residuals_at(geo, R, t, C[k], s, cn, fn, Cp, jac, False)
        relres[k] = rho
        status[k] = classify(False, rho, t, n, box, opts)


def _reference(name, couplings, model, hemisphere):
    C, cnorm = check_couplings(couplings, 3, 3)
    uniform = isinstance(hemisphere, str)
    nvec = hemisphere_vectors(hemisphere, 1 if uniform else C.shape[0], allow_none=False)
    opts = pack_options(rank_tol=1e-6, ambiguity_tol=1e-6, max_relative_residual=0.01,
                        max_range=3.0)
    out = new_outputs(C.shape[0])
    _per_sample_path(_METHODS[name], C, cnorm, whitening(model), pack_model(model), nvec, opts,
                     out)
    return out


def _model(rng):
    """A concentric model with non-orthogonal, unequal moments and a non-default gain."""
    return DipoleModel.concentric(M_so=np.eye(3) + 0.1 * rng.normal(size=(3, 3)),
                                  M_se=np.eye(3) + 0.1 * rng.normal(size=(3, 3)), gain=0.013)


def _batch(rng, model):
    """Random and adversarial couplings: clean and noisy poses, far field, beyond the plausible
    range, near the hemisphere plane, rank-deficient, NaN/inf/zero, scales near the floating
    point limits; a length that is not a multiple of the kernel's block."""
    n = 150
    d = np.concatenate([rng.uniform(0.05, 0.8, n - 30), rng.uniform(2.0, 50.0, 30)])
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    u[:10, 0] = rng.uniform(-1e-6, 1e-6, 10)          # on the +x hemisphere plane
    u[:10] /= np.linalg.norm(u[:10], axis=1)[:, None]
    rv = rng.normal(size=(n, 3))
    rv *= (rng.uniform(0, np.pi, n) / np.linalg.norm(rv, axis=1))[:, None]
    C = model.coupling(pose_from_vector(np.hstack([d[:, None] * u, rv])))
    noise = rng.normal(size=C.shape) * np.linalg.norm(C, axis=(1, 2))[:, None, None]
    C += noise * np.repeat([0.0, 1e-5, 3e-3, 0.02, 0.5], n // 5)[:, None, None]
    bad = []
    for rank in (1, 2):                                  # rank deficient
        a = rng.normal(size=(4, 3, rank))
        bad.append(a @ rng.normal(size=(4, rank, 3)))
    nan = rng.normal(size=(3, 3, 3))
    nan[0, 1, 1] = np.nan
    nan[1, 0, 2] = np.inf
    nan[2, 2, 0] = -np.inf
    bad += [nan, np.zeros((1, 3, 3)), rng.normal(size=(4, 3, 3)),
            C[:3] * 1e-300, C[3:6] * 1e300, C[6:9] * 1e-320]
    return np.concatenate([C] + bad)


@pytest.mark.parametrize("name", sorted(SOLVERS))
@pytest.mark.parametrize("seed", [0, 1])
def test_fused_kernel_matches_the_per_sample_path(name, seed):
    rng = np.random.default_rng(seed)
    model = _model(rng)
    C = _batch(rng, model)
    hemis = ["+x", hemisphere_vectors("+y", C.shape[0]) + rng.normal(size=(C.shape[0], 3))]
    for hemi in hemis:
        for couplings in (C, C[:1], C[:33], C.astype(complex) * np.exp(0.01j)):
            new = SOLVERS[name](couplings, model, hemisphere=hemi if isinstance(hemi, str)
                                else hemi[:couplings.shape[0]])
            poses, vecs, status, residual, relres, _ = _reference(
                name, couplings, model, hemi if isinstance(hemi, str)
                else hemi[:couplings.shape[0]])
            np.testing.assert_array_equal(new.status, status)
            np.testing.assert_allclose(new.poses, poses, rtol=0, atol=1e-12)
            np.testing.assert_allclose(new.pose_vectors, vecs, rtol=0, atol=1e-12)
            np.testing.assert_allclose(new.residual, residual, rtol=1e-12, atol=0)
            np.testing.assert_allclose(new.relative_residual, relres, rtol=1e-12, atol=0)
    # every outcome is exercised
    st = set(SOLVERS[name](C, model).status.tolist())
    assert {Status.CONVERGED, Status.NOT_CONVERGED, Status.INVALID_INPUT,
            Status.OUT_OF_VOLUME, Status.AMBIGUOUS} <= st


@njit
def _both(M_so, M_se, gain, Rs, ts, A, B):
    m = np.empty((4, M_se.shape[1]))
    zso = np.zeros((3, M_so.shape[1]))
    zse = np.zeros((3, M_se.shape[1]))
    dummy = np.empty((A.shape[1], A.shape[2], 3))
    jac = (dummy, dummy, dummy, dummy)
    no = Rs.shape[0] < 0
    for k in range(Rs.shape[0]):
        concentric_eval(M_so, M_se, gain, Rs[k], ts[k], A[k], m)
        dipole_eval((zso, M_so, zse, M_se, gain), Rs[k], ts[k], B[k], jac, no)


@pytest.mark.parametrize("shape", [(3, 3), (3, 1), (4, 3)])
def test_concentric_eval_is_dipole_eval_with_zero_offsets(shape):
    rng = np.random.default_rng(7)
    n = 2000
    v = np.hstack([rng.normal(size=(n, 3)) * 10.0 ** rng.uniform(-3, 2, (n, 1)),
                   rng.normal(size=(n, 3))])
    v[0, :3] = 0.0                                   # coils at the same point: NaN
    P = pose_from_vector(v)
    M_so = rng.normal(size=(3, shape[0]))
    M_se = rng.normal(size=(3, shape[1]))
    A = np.empty((n,) + shape)
    B = np.empty((n,) + shape)
    _both(M_so, M_se, 0.004, np.ascontiguousarray(P[:, :3, :3]),
          np.ascontiguousarray(P[:, :3, 3]), A, B)
    assert np.isnan(A[0]).all() and np.isnan(B[0]).all()
    np.testing.assert_array_equal(A, B)              # bit for bit
