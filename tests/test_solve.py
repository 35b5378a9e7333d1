"""Pose solvers: closed forms, LM, statuses, bad inputs, Cramer-Rao bound."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from openemt.evaluate import pose_error_magnitudes
from openemt.field import DipoleModel
from openemt.geometry import pose_from_vector
from openemt.solve import (
    SolveResult,
    Status,
    cramer_rao,
    hemisphere_from_positions,
    hemisphere_vectors,
    solve_kim18,
    solve_kuipers,
    solve_lm,
    solve_svd,
)


def random_poses(rng, n, *, center=(0.0, 0.25, 0.0), spread=0.08):
    v = np.empty((n, 6))
    v[:, :3] = np.asarray(center) + rng.uniform(-spread, spread, (n, 3))
    rv = rng.normal(size=(n, 3))
    rv *= (rng.uniform(0, np.pi, n) / np.linalg.norm(rv, axis=1))[:, None]
    v[:, 3:] = rv
    return pose_from_vector(v)


def dipole_approx_model():
    """3 air coils with 45 mm offsets (docs/ilemt-data.md#calibration-mat, cal_9_24 values, rounded)."""
    L_so = np.array([[0.045269, -0.000789, 0.0], [0.001401, 0.045415, 0.0],
                     [-0.043735, -0.042953, 0.0]])
    M_so = np.array([[0.951017, -0.000652, 0.0], [0.0, 0.949091, 0.0], [-0.025910, 0.000539, 1.0]])
    L_se = np.array([[0.000136, 0.000060, 0.0], [0.000117, 0.000116, 0.0],
                     [-0.000221, -0.000186, 0.0]])
    M_se = np.array([[0.157389, 0.000390, 0.0], [0.0, 0.156712, 0.0],
                     [0.002441, 0.001925, 0.160667]])
    return DipoleModel(L_so, M_so, L_se, M_se)


def skewed_concentric(rng):
    M_so = np.eye(3) * 0.9 + 0.03 * rng.normal(size=(3, 3))
    M_se = np.diag([0.40, 0.39, 0.41]) + 0.005 * rng.normal(size=(3, 3))
    return DipoleModel.concentric(M_so, M_se)


CLOSED = {
    "svd": lambda C, m, **kw: solve_svd(C, m, **kw),
    "kuipers": lambda C, m, **kw: solve_kuipers(C, m, **kw),
    "kim18": lambda C, m, **kw: solve_kim18(C, m, **kw),
}


# --- closed forms ---------------------------------------------------------------------------
@pytest.mark.parametrize("name", list(CLOSED))
@pytest.mark.parametrize("skewed", [False, True])
def test_closed_form_round_trip_machine_precision(name, skewed):
    rng = np.random.default_rng(1)
    model = skewed_concentric(rng) if skewed else DipoleModel.concentric()
    P = random_poses(rng, 500, center=(0.3, 0.0, 0.0), spread=0.25)
    P[:, 0, 3] = np.abs(P[:, 0, 3]) + 0.03
    C = model.coupling(P)
    res = CLOSED[name](C, model, hemisphere="+x")
    assert np.all(res.status == Status.CONVERGED)
    np.testing.assert_allclose(res.poses, P, rtol=0, atol=1e-12)
    np.testing.assert_allclose(res.poses[:, :3, :3] @ np.swapaxes(res.poses[:, :3, :3], 1, 2),
                               np.broadcast_to(np.eye(3), (500, 3, 3)), atol=1e-13)
    assert np.all(res.residual < 1e-25)
    assert np.all(res.iterations == 0)


@pytest.mark.parametrize("name", list(CLOSED))
def test_closed_form_hemisphere_resolves_sign(name):
    rng = np.random.default_rng(2)
    model = DipoleModel.concentric()
    P = random_poses(rng, 50, center=(0.0, 0.0, -0.3), spread=0.1)
    C = model.coupling(P)
    neg = CLOSED[name](C, model, hemisphere="-z")
    pos = CLOSED[name](C, model, hemisphere="+z")
    np.testing.assert_allclose(neg.poses[:, :3, 3], P[:, :3, 3], atol=1e-12)
    np.testing.assert_allclose(pos.poses[:, :3, 3], -P[:, :3, 3], atol=1e-12)
    np.testing.assert_allclose(pos.poses[:, :3, :3], P[:, :3, :3], atol=1e-12)
    vec = CLOSED[name](C, model, hemisphere=[0.1, 0.0, -1.0])
    np.testing.assert_allclose(vec.poses, P, atol=1e-12)
    per_row = CLOSED[name](C, model, hemisphere=np.array(["-z"] * 50))
    np.testing.assert_allclose(per_row.poses, P, atol=1e-12)


@pytest.mark.parametrize("name", list(CLOSED))
def test_closed_form_batch_equals_loop(name):
    rng = np.random.default_rng(3)
    model = skewed_concentric(rng)
    P = random_poses(rng, 20, center=(0.25, 0.05, 0.0))
    C = model.coupling(P) * (1 + 1e-3 * rng.normal(size=(20, 3, 3)))
    batch = CLOSED[name](C, model, hemisphere="+x")
    for k in range(20):
        one = CLOSED[name](C[k:k + 1], model, hemisphere="+x")
        np.testing.assert_array_equal(one.poses[0], batch.poses[k])
        np.testing.assert_array_equal(one.residual[0], batch.residual[k])


def test_closed_forms_agree_under_noise_and_kuipers_differs_slightly():
    rng = np.random.default_rng(4)
    model = DipoleModel.concentric()
    P = random_poses(rng, 200, center=(0.3, 0.0, 0.0), spread=0.1)
    C = model.coupling(P)
    C = C + 1e-3 * np.sqrt(np.mean(C ** 2, axis=(1, 2)))[:, None, None] * rng.normal(size=C.shape)
    out = {n: f(C, model, hemisphere="+x") for n, f in CLOSED.items()}
    for n, r in out.items():
        t, a = pose_error_magnitudes(r.poses, P)
        assert np.sqrt(np.mean(t ** 2)) < 2e-3, n
        assert np.sqrt(np.mean(a ** 2)) < 5e-3, n
    # svd and kim18 share the rotation (Wahba = Kim18 rotation), distances differ
    np.testing.assert_allclose(out["svd"].poses[:, :3, :3], out["kim18"].poses[:, :3, :3],
                               atol=1e-12)
    assert not np.allclose(out["svd"].poses[:, :3, 3], out["kim18"].poses[:, :3, 3], atol=1e-12)


@pytest.mark.parametrize("name", list(CLOSED))
def test_closed_form_bad_inputs_flagged(name):
    rng = np.random.default_rng(5)
    model = DipoleModel.concentric()
    P = random_poses(rng, 6, center=(0.3, 0.0, 0.0))
    C = model.coupling(P)
    C[1, 0, 0] = np.nan
    C[2, 1, 2] = np.inf
    C[3] = 0.0
    C[4] = np.outer([1.0, 2.0, 3.0], [0.5, -1.0, 0.2])  # rank 1
    res = CLOSED[name](C, model, hemisphere="+x")
    assert list(res.status[1:5]) == [Status.INVALID_INPUT] * 4
    assert np.all(np.isnan(res.poses[1:5])) and np.all(np.isnan(res.pose_vectors[1:5]))
    assert res.status[0] == Status.CONVERGED and res.status[5] == Status.CONVERGED
    np.testing.assert_allclose(res.poses[[0, 5]], P[[0, 5]], atol=1e-12)
    assert res.status_counts()["invalid_input"] == 4


def test_closed_form_ambiguous_on_hemisphere_plane():
    model = DipoleModel.concentric()
    P = pose_from_vector(np.array([[0.0, 0.3, 0.0, 0.1, 0.2, 0.3]]))
    res = solve_svd(model.coupling(P), hemisphere="+x")
    assert res.status[0] == Status.AMBIGUOUS
    assert np.all(np.isfinite(res.poses))


def test_closed_form_input_validation():
    model = DipoleModel.concentric()
    with pytest.raises(ValueError, match="expected"):
        solve_svd(np.zeros((4, 3, 2)))
    with pytest.raises(TypeError, match="expected"):
        solve_svd(np.array([[["a"] * 3] * 3]))
    with pytest.raises(ValueError, match="hemisphere"):
        solve_svd(np.ones((1, 3, 3)), hemisphere="+w")
    with pytest.raises(ValueError, match="concentric"):
        solve_kim18(np.ones((1, 3, 3)), dipole_approx_model())
    with pytest.raises(ValueError, match="hemisphere"):
        solve_kuipers(np.ones((2, 3, 3)), model, hemisphere=None)


def test_complex_input_uses_signed_real_and_complex_norm():
    rng = np.random.default_rng(6)
    model = DipoleModel.concentric()
    P = random_poses(rng, 10, center=(0.3, 0.0, 0.0))
    C = model.coupling(P)
    Cz = C * np.exp(1j * 0.01 * rng.normal(size=C.shape))
    res = solve_kim18(Cz, model, hemisphere="+x")
    real = np.where(Cz.real < 0, -1.0, 1.0) * np.abs(Cz)
    ref = solve_kim18(real, model, hemisphere="+x")
    np.testing.assert_array_equal(res.poses, ref.poses)
    pred = model.coupling(res.poses)
    expect = np.sum((pred - real) ** 2, axis=(1, 2)) / np.linalg.norm(Cz, ord=2, axis=(1, 2))
    np.testing.assert_allclose(res.residual, expect, rtol=1e-10)


# --- hemisphere helpers -----------------------------------------------------------------------
def test_hemisphere_helpers():
    h = hemisphere_from_positions([[0.1, -0.3, 0.0], [0.0, 0.1, 0.2], [-0.5, 0.1, 0.1]])
    assert list(h) == ["-y", "+z", "-x"]
    v = hemisphere_vectors(h, 3)
    np.testing.assert_array_equal(v, [[0, -1, 0], [0, 0, 1], [-1, 0, 0]])
    np.testing.assert_array_equal(hemisphere_vectors(None, 2), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="expected"):
        hemisphere_vectors(["+x"], 2)


# --- LM -----------------------------------------------------------------------------------------
def test_lm_nonconcentric_round_trip_and_batch_vs_loop():
    rng = np.random.default_rng(7)
    model = dipole_approx_model()
    P = random_poses(rng, 300, center=(0.0, 0.25, 0.0), spread=0.05)
    C = model.coupling(P)
    res = solve_lm(C, model, hemisphere="+y")
    assert np.all(res.status == Status.CONVERGED)
    np.testing.assert_allclose(res.poses, P, atol=1e-11)
    assert np.all(res.iterations > 0)
    for k in (0, 17, 299):
        one = solve_lm(C[k:k + 1], model, hemisphere="+y")
        np.testing.assert_array_equal(one.poses[0], res.poses[k])
        assert one.iterations[0] == res.iterations[k]


def test_lm_tracking_smooth_trajectory():
    model = dipole_approx_model()
    n = 400
    s = np.linspace(0, 1, n)[:, None]
    v = np.hstack([0.04 * np.sin(2 * np.pi * s * [1, 2, 3]) + [0.0, 0.25, 0.0],
                   0.5 * np.sin(2 * np.pi * s * [1.5, 1, 0.5]) + [0.1, 0.2, 0.3]])
    P = pose_from_vector(v)
    C = model.coupling(P)
    res = solve_lm(C, model, hemisphere="+y", initial="track")
    assert np.all(res.status == Status.CONVERGED)
    # xtol = 1e-8 on the (predicted) step: the answer is exact to well below 1e-9
    np.testing.assert_allclose(res.poses, P, atol=1e-9)
    tight = solve_lm(C, model, hemisphere="+y", initial="track", xtol=1e-12)
    np.testing.assert_allclose(tight.poses, P, atol=1e-12)
    cold = solve_lm(C, model, hemisphere="+y")
    assert res.iterations.mean() < cold.iterations.mean()


def test_lm_matches_scipy_least_squares_with_noise():
    rng = np.random.default_rng(9)
    model = dipole_approx_model()
    P = random_poses(rng, 15, center=(0.0, 0.25, 0.0), spread=0.05)
    C = model.coupling(P)
    C = C + 1e-4 * np.abs(C).mean() * rng.normal(size=C.shape)
    res = solve_lm(C, model, hemisphere="+y", max_relative_residual=None)
    for k in range(15):
        def fun(x, k=k):
            return (model.coupling(pose_from_vector(x[None]))[0] - C[k]).ravel()
        ref = least_squares(fun, res.pose_vectors[k] + 1e-3, xtol=1e-14, ftol=1e-14,
                            gtol=1e-14)
        np.testing.assert_allclose(res.pose_vectors[k, :3], ref.x[:3], atol=1e-9)
        ssr = np.sum(fun(res.pose_vectors[k]) ** 2)
        assert ssr <= 2 * ref.cost * (1 + 1e-9)


def test_lm_hemisphere_constraint_and_retries():
    rng = np.random.default_rng(10)
    model = DipoleModel.concentric(np.eye(3) * 0.9, np.eye(3) * 0.4)
    P = random_poses(rng, 30, center=(0.3, 0.0, 0.0), spread=0.1)
    C = model.coupling(P)
    # start from the mirror image with a wrong orientation: hemisphere +x must bring it back
    init = np.zeros((30, 6))
    init[:, :3] = -P[:, :3, 3]
    res = solve_lm(C, model, hemisphere="+x", initial=init)
    assert np.all(res.status == Status.CONVERGED)
    np.testing.assert_allclose(res.poses, P, atol=1e-10)
    # unconstrained and started in the mirror: the mirror solution is equally exact
    mirror = solve_lm(C, model, hemisphere=None, initial=init, retries=False)
    np.testing.assert_allclose(mirror.poses[:, :3, 3], -P[:, :3, 3], atol=1e-10)


def test_lm_out_of_volume_and_bad_inputs():
    rng = np.random.default_rng(11)
    model = dipole_approx_model()
    P = random_poses(rng, 5, center=(0.0, 0.25, 0.0), spread=0.03)
    P[2, 1, 3] = 0.5  # outside a 0.4 m box
    C = model.coupling(P)
    C[3] = np.nan
    C[4] = 0.0
    res = solve_lm(C, model, hemisphere="+y", bounds=0.4)
    assert res.status[2] == Status.OUT_OF_VOLUME
    assert list(res.status[3:]) == [Status.INVALID_INPUT] * 2
    assert np.all(np.isnan(res.poses[3:]))
    assert list(res.status[:2]) == [Status.CONVERGED] * 2
    with pytest.raises(ValueError, match="expected"):
        solve_lm(C[:, :2], model)
    with pytest.raises(ValueError, match="expected"):
        solve_lm(C, model, initial="nonsense")
    with pytest.raises(ValueError, match="expected"):
        solve_lm(C, model, initial=np.zeros((2, 6)))


def test_lm_invalid_residual_and_max_iterations():
    rng = np.random.default_rng(12)
    model = dipole_approx_model()
    P = random_poses(rng, 4, center=(0.0, 0.25, 0.0), spread=0.03)
    C = model.coupling(P)
    C[1] = C[1] + 0.05 * rng.normal(size=(3, 3))  # not a dipole coupling any more
    res = solve_lm(C, model, hemisphere="+y")
    assert res.status[1] == Status.NOT_CONVERGED and res.residual[1] > 1e-5
    assert res.status[0] == Status.CONVERGED
    one = solve_lm(C[:1], model, hemisphere="+y", max_iter=1, retries=False)
    assert one.status[0] == Status.MAX_ITERATIONS


def test_lm_five_dof_single_coil_sensor():
    rng = np.random.default_rng(13)
    # 8 source coils on a board (Anser-like layout), a single-coil sensor
    ang = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    L_so = np.vstack([0.06 * np.cos(ang), 0.06 * np.sin(ang), np.zeros(8)])
    M_so = np.vstack([0.3 * np.cos(2 * ang), 0.3 * np.sin(2 * ang), np.ones(8)])
    model = DipoleModel(L_so, M_so, np.zeros((3, 1)), np.array([[0.0], [0.0], [0.2]]))
    P = random_poses(rng, 40, center=(0.0, 0.0, 0.15), spread=0.05)
    C = model.coupling(P)
    res = solve_lm(C, model, hemisphere="+z", initial="multistart")
    assert np.all(res.status == Status.CONVERGED)
    np.testing.assert_allclose(res.poses[:, :3, 3], P[:, :3, 3], atol=1e-10)
    np.testing.assert_allclose(res.poses[:, :3, 2], P[:, :3, 2], atol=1e-10)  # sensor axis
    # reported rotation: zero roll = shortest arc from z to the axis (R e_z = axis, rv . z = 0)
    np.testing.assert_allclose(res.pose_vectors[:, 5], 0.0, atol=1e-12)
    np.testing.assert_allclose(model.coupling(res.poses), C, atol=1e-12)


def test_lm_covariance_and_cramer_rao_monte_carlo():
    rng = np.random.default_rng(14)
    model = dipole_approx_model()
    P = random_poses(rng, 1, center=(0.02, 0.25, -0.01), spread=0.0)
    C0 = model.coupling(P)[0]
    sigma = 1e-4 * np.abs(C0).max()
    n = 3000
    C = C0 + sigma * rng.normal(size=(n, 3, 3))
    res = solve_lm(C, model, hemisphere="+y", initial=np.tile(
        np.concatenate([P[0, :3, 3], np.zeros(3)]), (n, 1)), max_relative_residual=None,
        covariance=True)
    crb = cramer_rao(model, P, sigma)[0]
    emp = np.cov((res.pose_vectors - res.pose_vectors.mean(0)).T)
    # empirical covariance of an efficient estimator matches the bound (to MC accuracy)
    np.testing.assert_allclose(np.diag(emp), np.diag(crb), rtol=0.1)
    np.testing.assert_allclose(np.mean(res.covariance[:, range(6), range(6)], axis=0),
                               np.diag(crb), rtol=0.1)
    loc = cramer_rao(model, P, sigma, parametrization="local")[0]
    assert np.trace(loc[:3, :3]) == pytest.approx(np.trace(crb[:3, :3]), rel=1e-12)
    with pytest.raises(ValueError, match="expected"):
        cramer_rao(model, P, np.ones(4))


def test_cramer_rao_scales_with_noise_and_matches_hand_formula():
    rng = np.random.default_rng(15)
    model = DipoleModel.concentric()
    P = random_poses(rng, 3, center=(0.3, 0.0, 0.0))
    a = cramer_rao(model, P, 1e-5)
    b = cramer_rao(model, P, 2e-5)
    np.testing.assert_allclose(b, 4 * a, rtol=1e-12)
    S = np.eye(9) * 1e-10
    np.testing.assert_allclose(cramer_rao(model, P, S), a, rtol=1e-10)


def test_solve_result_helpers():
    r = SolveResult(np.zeros((3, 4, 4)), np.zeros((3, 6)), np.array([0, 2, 5], np.int8),
                    np.zeros(3), np.zeros(3, np.int32))
    assert r.status_counts() == {"converged": 1, "max_iterations": 0, "invalid_input": 1,
                                 "ambiguous": 0, "out_of_volume": 0, "not_converged": 1}
    np.testing.assert_array_equal(r.valid, [True, False, False])
    both = SolveResult.concatenate([r, r.select([0])])
    assert len(both) == 4


def test_kim18_matches_numpy_transcription_of_ilemt_formula():
    """Kim18 exactly as written in docs/paper-procedure.md#kim18, with numpy's SVD, on noisy data."""
    rng = np.random.default_rng(16)
    model = skewed_concentric(rng)
    P = random_poses(rng, 200, center=(0.3, 0.0, 0.0), spread=0.1)
    C = model.coupling(P)
    C = C * (1 + 0.05 * rng.normal(size=C.shape))  # heavy noise: exercises every code path
    res = solve_kim18(C, model, hemisphere="+x")
    g = np.linalg.norm(model.M_se, axis=0)
    Nm = model.M_se / g
    for k in range(200):
        S = (C[k] / g[None, :]).T
        Y = np.linalg.inv(Nm.T) @ S @ np.linalg.inv(model.M_so)
        U, s, Vt = np.linalg.svd(Y)
        V = Vt.T
        R = V @ np.diag([1.0, -1.0, -1.0]) @ U.T
        mu = 4 * np.pi / 250
        gamma = (3 * mu / (2 * np.pi * (2 * s[0] + s[1] + s[2]))) ** (1 / 3)
        p = gamma * V[:, 0]
        p = p if p[0] >= 0 else -p
        if np.linalg.det(R) < 0:  # numpy's plain formula gives a reflection: ours corrects it
            assert np.linalg.det(res.poses[k, :3, :3]) > 0
            continue
        np.testing.assert_allclose(res.poses[k, :3, :3], R, atol=1e-12)
        np.testing.assert_allclose(res.poses[k, :3, 3], p, atol=1e-13)


def _markley_reference(B):
    """Rotation maximising tr(R^T B) by numpy's SVD with the determinant correction."""
    U, s, Vt = np.linalg.svd(B)
    d = np.sign(np.linalg.det(U @ Vt))
    return U @ np.diag([1.0, 1.0, d]) @ Vt, s


def test_wahba_quat_matches_numpy_svd():
    """q-method with the known top eigenvalue vs numpy's SVD (both signs of det B)."""
    from openemt.solve._linalg import quat_matrix, rotvec_from_matrix, rotvec_from_quat, wahba_quat

    rng = np.random.default_rng(21)
    q = np.empty(4)
    M = np.empty((4, 4))
    R = np.empty((3, 3))
    rv = np.empty(3)
    rv_ref = np.empty(3)
    n_neg = 0
    for k in range(400):
        if k % 2:
            B = rng.normal(size=(3, 3))
        else:  # near-orthogonal, as in the solvers
            Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
            B = Q @ np.diag(rng.uniform(0.5, 2.0, 3)) + 1e-3 * rng.normal(size=(3, 3))
        R_ref, s = _markley_reference(B)
        det = np.linalg.det(B)
        n_neg += det < 0
        lam = s[0] + s[1] + np.sign(det) * s[2]
        assert wahba_quat(B, lam, q, M)
        assert q[0] >= 0.0
        np.testing.assert_allclose(np.linalg.norm(q), 1.0, atol=1e-15)
        quat_matrix(q, R)
        gap = s[1] + np.sign(det) * s[2]  # conditioning of the Wahba problem
        np.testing.assert_allclose(R, R_ref, atol=1e-13 / gap)
        rotvec_from_quat(q, rv)
        rotvec_from_matrix(R, rv_ref)
        if np.linalg.norm(rv) < np.pi - 1e-6:  # away from the +/- pi branch cut
            np.testing.assert_allclose(rv, rv_ref, atol=1e-13)
    assert n_neg > 50
    # a wrong eigenvalue leaves a regular K - lam I: no null vector direction to trust
    assert wahba_quat(np.eye(3), 3.0, q, M) is True
    np.testing.assert_allclose(q, [1.0, 0.0, 0.0, 0.0], atol=1e-15)


@pytest.mark.parametrize("name", ["svd", "kim18"])
def test_closed_form_far_from_dipole_matches_numpy_svd(name):
    """Couplings far from the concentric model (coil offsets, close range): nearly double top
    singular values and det(C0) < 0 both occur; the rotation is still U diag(1,-1,-1) V^T with
    Markley's correction and the direction the first singular vector (numpy reference)."""
    rng = np.random.default_rng(22)
    model = skewed_concentric(rng)
    offset = model.replace(L_so=0.05 * rng.normal(size=(3, 3)),
                           L_se=0.05 * rng.normal(size=(3, 3)))
    P = random_poses(rng, 400, center=(0.2, 0.0, 0.0), spread=0.08)
    C = offset.coupling(P)
    C = C * (1 + 0.02 * rng.normal(size=C.shape))
    res = solve_svd(C, model) if name == "svd" else solve_kim18(C, model)
    C0 = np.linalg.inv(model.M_so.T) @ C @ np.linalg.inv(model.M_se)
    n_close = n_neg = 0
    for k in range(len(C)):
        U, s, _ = np.linalg.svd(C0[k])
        if s[0] < 1.05 * s[1] or s[2] < 1e-6 * s[0]:
            continue  # ill-conditioned direction: not a rounding-level comparison
        n_close += s[0] < np.sqrt(1.5) * s[1]
        n_neg += np.linalg.det(C0[k]) < 0
        H_inv = 1.5 * np.outer(U[:, 0], U[:, 0]) - np.eye(3)
        R_ref, sb = _markley_reference(H_inv @ C0[k])
        gap = (sb[1] + np.sign(np.linalg.det(C0[k])) * sb[2]) / sb[0]
        np.testing.assert_allclose(res.poses[k, :3, :3], R_ref, atol=1e-12 / gap)
        u = U[:, 0] if U[0, 0] >= 0 else -U[:, 0]
        t = res.poses[k, :3, 3]
        np.testing.assert_allclose(t / np.linalg.norm(t), u, atol=1e-11)
    assert n_close > 5 and n_neg > 5, (n_close, n_neg)


def test_sym3_eigvals_matches_numpy_eigvalsh():
    """Trigonometric eigenvalues (incl. nearly double ones, as for H = 3 u u^T - I) vs LAPACK."""
    from openemt.solve._linalg import sym3_eigvals

    rng = np.random.default_rng(23)
    lam = np.empty(3)
    for k in range(600):
        Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        if k % 3 == 0:
            ev = rng.normal(size=3)
        elif k % 3 == 1:  # two nearly equal small eigenvalues
            ev = np.array([4.0, 1.0, 1.0 + 10.0 ** rng.uniform(-12, -2)])
        else:  # two nearly equal large eigenvalues
            ev = np.array([1.0, 1.0 + 10.0 ** rng.uniform(-12, -2), 0.2])
        A = Q @ np.diag(ev) @ Q.T
        A = 0.5 * (A + A.T)
        sym3_eigvals(A, lam)
        ref = np.linalg.eigvalsh(A)[::-1]
        scale = np.abs(ref).max()
        np.testing.assert_allclose(lam.sum(), ref.sum(), rtol=0, atol=1e-13 * scale)
        # exact to rounding for separated eigenvalues; a nearly double pair (gap g) is resolved
        # to about eps * scale^2 / g, at worst sqrt(eps) * scale (the arccos near +/-1)
        gap = np.abs(np.diff(ref)).min()
        tol = 1e-13 * scale + min(5e-8 * scale, 1e-14 * scale ** 2 / gap)
        np.testing.assert_allclose(lam, ref, rtol=0, atol=tol)
