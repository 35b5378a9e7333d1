"""The dipole coupling model: physics, analytic Jacobians vs finite differences, real data."""

import numpy as np
import pytest

from openemt.field import (
    ILEMT_GAIN,
    DipoleModel,
    coupling,
    coupling_jacobian_pose,
    coupling_jacobians,
)
from openemt.geometry import ground_truth_poses, pose_from_vector


def random_model(rng, n_so=3, n_se=3, offset=0.02):
    return DipoleModel(rng.normal(scale=offset, size=(3, n_so)),
                       np.eye(3, n_so) + 0.1 * rng.normal(size=(3, n_so)),
                       rng.normal(scale=offset / 4, size=(3, n_se)),
                       np.eye(3, n_se) + 0.1 * rng.normal(size=(3, n_se)))


def random_pose_vectors(rng, n):
    return np.hstack([rng.normal(scale=0.05, size=(n, 3)) + [0.2, 0.05, -0.03],
                      rng.uniform(-2, 2, size=(n, 3))])


def test_dipole_field_on_axis_and_equator():
    # a z source dipole; a z sensor on the z axis sees 2M/d^3, on the equator -M/d^3
    m = DipoleModel.concentric(np.array([[0.0], [0.0], [1.5]]), np.array([[0.0], [0.0], [0.7]]))
    d = 0.25
    on_axis = pose_from_vector([[0, 0, d, 0, 0, 0]])
    equator = pose_from_vector([[d, 0, 0, 0, 0, 0]])
    assert coupling(m, on_axis)[0, 0, 0] == pytest.approx(ILEMT_GAIN * 2 * 1.5 * 0.7 / d**3, rel=1e-14)
    assert coupling(m, equator)[0, 0, 0] == pytest.approx(-ILEMT_GAIN * 1.5 * 0.7 / d**3, rel=1e-14)


def test_inverse_cube_scaling_and_reciprocity():
    rng = np.random.default_rng(0)
    m = DipoleModel.concentric(np.eye(3) + 0.05 * rng.normal(size=(3, 3)), np.eye(3))
    v = random_pose_vectors(rng, 4)
    C1 = coupling(m, pose_from_vector(v))
    v2 = v.copy()
    v2[:, :3] *= 2
    C2 = coupling(m, pose_from_vector(v2))
    np.testing.assert_allclose(C2, C1 / 8, rtol=1e-13)
    # ideal concentric tri-axial coils: C = gain (3 u u^T - I) R / d^3 (source-major)
    ideal = DipoleModel.concentric()
    P = pose_from_vector(v)
    C = coupling(ideal, P)
    for k in range(4):
        t = P[k, :3, 3]
        d = np.linalg.norm(t)
        u = t / d
        expected = ILEMT_GAIN * (3 * np.outer(u, u) - np.eye(3)) @ P[k, :3, :3] / d**3
        np.testing.assert_allclose(C[k], expected, rtol=1e-12, atol=1e-15)


def test_rigid_motion_invariance():
    # moving source coils and sensor together by a rigid motion leaves couplings unchanged
    rng = np.random.default_rng(1)
    m = random_model(rng)
    P = pose_from_vector(random_pose_vectors(rng, 3))
    G = pose_from_vector([0.01, -0.02, 0.03, 0.3, -0.2, 0.5])
    Rg, tg = G[:3, :3], G[:3, 3:4]
    moved = m.replace(L_so=Rg @ m.L_so + tg, M_so=Rg @ m.M_so)
    np.testing.assert_allclose(coupling(moved, G @ P), coupling(m, P), rtol=1e-12, atol=1e-16)


@pytest.mark.parametrize("n_so, n_se", [(3, 3), (8, 1), (1, 1), (4, 2)])
def test_batch_vs_loop_and_shapes(n_so, n_se):
    rng = np.random.default_rng(2)
    m = random_model(rng, n_so, n_se)
    P = pose_from_vector(random_pose_vectors(rng, 6))
    C = coupling(m, P)
    assert C.shape == (6, n_so, n_se)
    for k in range(6):
        np.testing.assert_array_equal(coupling(m, P[k:k + 1])[0], C[k])
    # the formula written out directly, coil by coil
    for k in range(2):
        R, t = P[k, :3, :3], P[k, :3, 3]
        for i in range(n_so):
            for j in range(n_se):
                r = R @ m.L_se[:, j] + t - m.L_so[:, i]
                d = np.linalg.norm(r)
                u = r / d
                B = (3 * (m.M_so[:, i] @ u) * u - m.M_so[:, i]) / d**3
                assert C[k, i, j] == pytest.approx(ILEMT_GAIN * B @ (R @ m.M_se[:, j]), rel=1e-12)


@pytest.mark.parametrize("n_so, n_se", [(3, 3), (8, 1)])
def test_pose_jacobian_matches_finite_differences(n_so, n_se):
    rng = np.random.default_rng(3)
    m = random_model(rng, n_so, n_se)
    v = random_pose_vectors(rng, 5)
    C, J = coupling_jacobian_pose(m, v)
    assert J.shape == (5, n_so, n_se, 6)
    h = 1e-6
    Jn = np.stack([(coupling(m, pose_from_vector(v + h * e)) - coupling(m, pose_from_vector(v - h * e)))
                   / (2 * h) for e in np.eye(6)], axis=-1)
    np.testing.assert_allclose(J, Jn, atol=1e-8 * np.abs(C).max())


def test_parameter_jacobians_match_finite_differences():
    rng = np.random.default_rng(4)
    m = random_model(rng, 3, 2)
    P = pose_from_vector(random_pose_vectors(rng, 4))
    jac = coupling_jacobians(m, P)
    h = 1e-6
    scale = np.abs(jac.C).max()
    for name in ("L_so", "M_so", "L_se", "M_se"):
        A = getattr(m, name)
        for a in range(3):
            for c in range(A.shape[1]):
                Ap, Am = A.copy(), A.copy()
                Ap[a, c] += h
                Am[a, c] -= h
                num = (coupling(m.replace(**{name: Ap}), P) - coupling(m.replace(**{name: Am}), P)) / (2 * h)
                ana = np.zeros_like(num)
                if name.endswith("so"):
                    ana[:, c, :] = getattr(jac, "d_" + name)[:, c, :, a]
                else:
                    ana[:, :, c] = getattr(jac, "d_" + name)[:, :, c, a]
                np.testing.assert_allclose(ana, num, atol=1e-7 * scale, err_msg=f"{name}[{a},{c}]")
    # the rotation block: R -> exp([phi]x) R
    from scipy.spatial.transform import Rotation
    for a in range(3):
        phi = np.zeros(3)
        phi[a] = h
        Pp, Pm = P.copy(), P.copy()
        Pp[:, :3, :3] = Rotation.from_rotvec(phi).as_matrix() @ P[:, :3, :3]
        Pm[:, :3, :3] = Rotation.from_rotvec(-phi).as_matrix() @ P[:, :3, :3]
        num = (coupling(m, Pp) - coupling(m, Pm)) / (2 * h)
        np.testing.assert_allclose(jac.d_rotation[..., a], num, atol=1e-8 * scale)


def test_bad_inputs():
    with pytest.raises(ValueError, match=r"expected `L_so` to have shape \(3, n_coils\)"):
        DipoleModel(np.zeros((2, 3)), np.eye(3), np.zeros((3, 3)), np.eye(3))
    with pytest.raises(ValueError, match="equal shape"):
        DipoleModel(np.zeros((3, 2)), np.eye(3), np.zeros((3, 3)), np.eye(3))
    with pytest.raises(ValueError, match="finite"):
        DipoleModel(np.full((3, 3), np.nan), np.eye(3), np.zeros((3, 3)), np.eye(3))
    m = DipoleModel.concentric()
    with pytest.raises(ValueError, match=r"shape \(N, 4, 4\)"):
        coupling(m, np.eye(4))
    bad = pose_from_vector([[0.2, 0, 0, 0, 0, 0]])
    bad[0, 0, 3] = np.nan
    with pytest.raises(ValueError, match="finite"):
        coupling(m, bad)


def test_worked_example_real_calibration(ilemt_dir):
    """docs/ilemt-data.md#worked-example: predicted coupling of one real row with the committed XYZ_hr_cal."""
    from openemt.io import read_ilemt_calibration

    cal = read_ilemt_calibration(ilemt_dir / "output" / "XYZ_hr_cal.mat")
    stage = np.array([[-0.05015, -0.049923933, -0.046116, 0, 0, -np.pi / 2]])
    P = ground_truth_poses(cal.source_fixture, cal.stage_fixture, cal.sensor_fixture, ["YoutZup"],
                           stage, ["ZinXdown"])
    C = coupling(cal.model, P)[0]
    expected = np.array([[-0.277596, 0.094483, -0.075848],
                         [-0.088092, 0.012846, 0.163578],
                         [0.121062, 0.169763, 0.032187]])
    # printed to 6 decimals: agree to the last printed digit (5 significant digits or better)
    np.testing.assert_allclose(C, expected, atol=6e-7)
