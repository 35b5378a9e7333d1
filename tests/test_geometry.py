"""Batched SE(3) geometry: round trips, small and near-pi angles, batch vs loop, fixtures."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from openemt.geometry import (
    SENSOR_FIXTURES,
    SOURCE_FIXTURES,
    adjoint,
    compose,
    error_magnitudes,
    fixture_axes,
    ground_truth_poses,
    invert,
    left_jacobian_so3,
    pose_error,
    pose_from_vector,
    rotation_x,
    rotation_y,
    rotation_z,
    rotvec_between,
    sensor_fixture_rotation,
    skew,
    source_fixture_rotation,
    stage_joint,
    stage_transform,
    vector_from_pose,
)


def random_pose_vectors(rng, n, max_angle=np.pi):
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    ang = rng.uniform(0, max_angle, size=(n, 1))
    return np.hstack([rng.normal(scale=0.2, size=(n, 3)), axis * ang])


@pytest.mark.parametrize("shape", [(), (1,), (7,), (2, 3)])
def test_round_trip_keeps_rank(shape):
    rng = np.random.default_rng(1)
    n = int(np.prod(shape)) if shape else 1
    v = random_pose_vectors(rng, n, max_angle=np.pi * 0.999).reshape(shape + (6,))
    P = pose_from_vector(v)
    assert P.shape == shape + (4, 4)
    back = vector_from_pose(P)
    assert back.shape == shape + (6,)
    np.testing.assert_allclose(back, v, atol=1e-12)


@pytest.mark.parametrize("angle", [0.0, 1e-14, 1e-9, 1e-6, 1e-3])
def test_small_angles(angle):
    rng = np.random.default_rng(2)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    v = np.concatenate([[0.1, -0.2, 0.3], axis * angle])
    back = vector_from_pose(pose_from_vector(v))
    np.testing.assert_allclose(back, v, atol=1e-15, rtol=1e-10)


@pytest.mark.parametrize("eps", [0.0, 1e-12, 1e-8, 1e-5])
def test_angles_near_pi(eps):
    rng = np.random.default_rng(3)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    ang = np.pi - eps
    v = np.concatenate([[0.0, 0.1, 0.0], axis * ang])
    P = pose_from_vector(v)
    back = vector_from_pose(P)
    # at exactly pi the axis sign is ambiguous: compare rotations, and angles
    np.testing.assert_allclose(pose_from_vector(back), P, atol=1e-12)
    assert np.linalg.norm(back[3:]) == pytest.approx(ang, abs=1e-9)
    assert np.linalg.norm(back[3:]) <= np.pi + 1e-15


def test_matches_scipy_and_rodrigues():
    rng = np.random.default_rng(4)
    v = random_pose_vectors(rng, 50)
    P = pose_from_vector(v)
    np.testing.assert_allclose(P[:, :3, :3], Rotation.from_rotvec(v[:, 3:]).as_matrix(), atol=1e-14)
    # Rodrigues' formula, written independently
    for k in range(5):
        r = v[k, 3:]
        th = np.linalg.norm(r)
        K = skew(r / th)
        R = np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K
        np.testing.assert_allclose(P[k, :3, :3], R, atol=1e-13)
    np.testing.assert_array_equal(P[:, 3], np.tile([0, 0, 0, 1.0], (50, 1)))


def test_compose_invert_batch_vs_loop():
    rng = np.random.default_rng(5)
    A = pose_from_vector(random_pose_vectors(rng, 20))
    B = pose_from_vector(random_pose_vectors(rng, 20))
    AB = compose(A, B)
    Ai = invert(A)
    E = pose_error(A, B)
    for k in range(20):
        np.testing.assert_allclose(AB[k], A[k] @ B[k], atol=1e-14)
        np.testing.assert_allclose(Ai[k], np.linalg.inv(A[k]), atol=1e-12)
        np.testing.assert_allclose(E[k], np.linalg.inv(A[k]) @ B[k], atol=1e-12)
    np.testing.assert_allclose(compose(A, Ai), np.broadcast_to(np.eye(4), A.shape), atol=1e-13)
    # broadcasting a single pose over a batch
    np.testing.assert_allclose(compose(A[0], B), A[0] @ B, atol=1e-14)


def test_error_magnitudes_known_values():
    rng = np.random.default_rng(6)
    P = pose_from_vector(random_pose_vectors(rng, 10))
    d = np.array([0.001, -0.002, 0.0005, 0.0, 0.0, 0.0])
    rot = np.array([0, 0, 0, 0.01, 0.0, 0.0])
    # P_true = P_meas @ delta  ->  E = delta
    trans, ang = error_magnitudes(pose_error(P, P @ pose_from_vector(d)))
    np.testing.assert_allclose(trans, np.linalg.norm(d[:3]), rtol=1e-10)
    np.testing.assert_allclose(ang, 0.0, atol=1e-12)
    trans, ang = error_magnitudes(pose_error(P, P @ pose_from_vector(rot)))
    np.testing.assert_allclose(trans, 0.0, atol=1e-15)
    np.testing.assert_allclose(ang, 0.01, rtol=1e-10)
    # tiny angles are resolved (the trace formula would lose them)
    _, ang = error_magnitudes(pose_from_vector([0, 0, 0, 1e-9, 0, 0]))
    assert ang == pytest.approx(1e-9, rel=1e-6)


def test_elementary_rotations():
    th = 0.3
    np.testing.assert_allclose(rotation_z(th), [[np.cos(th), -np.sin(th), 0],
                                                [np.sin(th), np.cos(th), 0], [0, 0, 1]])
    for f, axis in ((rotation_x, [1, 0, 0]), (rotation_y, [0, 1, 0]), (rotation_z, [0, 0, 1])):
        np.testing.assert_allclose(f(th), Rotation.from_rotvec(np.array(axis) * th).as_matrix(),
                                   atol=1e-15)
    assert rotation_z(np.zeros(4)).shape == (4, 3, 3)


def test_fixture_rotations_match_the_documented_tables():
    # docs/ilemt-data.md#fixture-rotations, rows listed top to bottom
    so = {
        "YoutZup": np.eye(3),
        "XoutZup": [[0, 1, 0], [-1, 0, 0], [0, 0, 1]],
        "ZoutYup": [[-1, 0, 0], [0, 0, 1], [0, 1, 0]],
        "XinYup": [[0, -1, 0], [0, 0, 1], [-1, 0, 0]],
    }
    se = {
        "YoutZup": np.eye(3),
        "ZinYup": [[1, 0, 0], [0, 0, -1], [0, 1, 0]],
        "ZinXdown": [[0, 1, 0], [0, 0, -1], [-1, 0, 0]],
    }
    for code, R in so.items():
        np.testing.assert_array_equal(source_fixture_rotation(code), R)
    for code, R in se.items():
        np.testing.assert_array_equal(sensor_fixture_rotation(code), R)
    # the documented equivalents
    np.testing.assert_allclose(source_fixture_rotation("XoutZup"), rotation_z(-np.pi / 2), atol=1e-15)
    np.testing.assert_allclose(source_fixture_rotation("ZoutYup"),
                               rotation_z(np.pi) @ rotation_x(np.pi / 2), atol=1e-15)
    np.testing.assert_allclose(source_fixture_rotation("XinYup"),
                               rotation_y(np.pi / 2) @ rotation_x(-np.pi / 2), atol=1e-15)
    np.testing.assert_allclose(sensor_fixture_rotation("ZinYup"), rotation_x(np.pi / 2), atol=1e-15)
    np.testing.assert_allclose(sensor_fixture_rotation("ZinXdown"),
                               rotation_y(np.pi / 2) @ rotation_x(np.pi / 2), atol=1e-15)
    assert set(SOURCE_FIXTURES) == set(so) and set(SENSOR_FIXTURES) == set(se)


@pytest.mark.parametrize("code", ["", "YoutYup", "Yout", "WoutZup", "youtzup", None, 3])
def test_bad_fixture_codes(code):
    with pytest.raises(ValueError, match="expected a fixture code"):
        fixture_axes(code)


def test_all_fixture_codes_are_rotations():
    for a in "XYZ":
        for b in "XYZ":
            if a == b:
                continue
            for o in ("out", "in"):
                for u in ("up", "down"):
                    R = fixture_axes(f"{a}{o}{b}{u}")
                    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-15)
                    assert np.linalg.det(R) == pytest.approx(1.0)


def test_worked_example_ground_truth():
    # docs/ilemt-data.md#worked-example (fixtures rounded to 6 decimals as printed there)
    F_so = [-0.000999, -0.011916, -0.009595, 0.022462, 0.052125, -1.568037]
    F_st = [0.001510, 0.244445, 0.012462, -0.000160, 0.001946, 0.011071]
    F_se = [-0.000319, 0.000275, -0.000322, -2.207918, -2.226116, -0.003116]
    stage = np.array([[-0.05015, -0.049923933, -0.046116, 0, 0, -np.pi / 2]])
    st_J = stage_joint(stage, ["ZinXdown"])
    np.testing.assert_allclose(st_J[0], [[0, 0, -1, -0.05015], [0, -1, 0, -0.049923933],
                                         [-1, 0, 0, -0.046116], [0, 0, 0, 1]], atol=1e-15)
    P = ground_truth_poses(F_so, F_st, F_se, ["YoutZup"], stage, ["ZinXdown"])
    np.testing.assert_allclose(P[0, :3, 3], [0.191934, 0.038003, -0.044156], atol=2e-6)
    np.testing.assert_allclose(vector_from_pose(P)[0, 3:], [0.038683, -2.262403, 2.159695],
                               atol=3e-6)
    np.testing.assert_allclose(P[0, :3, :3], [[-0.999601, -0.027288, 0.00723],
                                              [-0.008489, 0.046311, -0.998891],
                                              [0.026923, -0.998554, -0.046525]], atol=2e-6)


def test_stage_transform_euler_order():
    s = np.array([[0.01, 0.02, 0.03, 0.1, 0.2, 0.3]])
    T = stage_transform(s)[0]
    np.testing.assert_allclose(T[:3, :3], rotation_z(0.3) @ rotation_y(0.2) @ rotation_x(0.1))
    np.testing.assert_allclose(T[:3, 3], [0.01, 0.02, 0.03])


def test_left_jacobian_and_adjoint_by_finite_differences():
    rng = np.random.default_rng(7)
    for r in list(random_pose_vectors(rng, 5)[:, 3:]) + [np.array([1e-8, 0, 0])]:
        J = left_jacobian_so3(r)
        R0 = Rotation.from_rotvec(r).as_matrix()
        h = 1e-7
        for a in range(3):
            dr = np.zeros(3)
            dr[a] = h
            Rp = Rotation.from_rotvec(r + dr).as_matrix()
            phi = Rotation.from_matrix(Rp @ R0.T).as_rotvec() / h
            np.testing.assert_allclose(phi, J[:, a], atol=1e-6)
    P = pose_from_vector(random_pose_vectors(rng, 1)[0])
    xi = np.array([1e-7, -2e-7, 3e-7, 2e-7, 1e-7, -1e-7])

    def exp_twist(x):
        T = np.eye(4)
        T[:3, :3] = Rotation.from_rotvec(x[3:]).as_matrix()
        T[:3, 3] = x[:3]  # first order is enough for this check
        return T

    lhs = P @ exp_twist(xi)
    rhs = exp_twist(adjoint(P) @ xi) @ P
    np.testing.assert_allclose(lhs, rhs, atol=1e-12)


@pytest.mark.parametrize("bad, match", [
    (np.zeros(5), r"shape \(\.\.\., 6\)"),
    (np.zeros((3, 7)), r"shape \(\.\.\., 6\)"),
    (np.array(["a"] * 6), "real numbers"),
])
def test_bad_pose_vectors(bad, match):
    with pytest.raises((ValueError, TypeError), match=match):
        pose_from_vector(bad)


def test_bad_poses():
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 4, 4\)"):
        vector_from_pose(np.zeros((3, 3)))
    with pytest.raises(ValueError, match="at least one pose"):
        compose()


def test_nonfinite_rows_give_nan_not_an_exception():
    P = pose_from_vector(np.array([[0.1, 0, 0, 0.1, 0, 0], [0.2, 0, 0, 0, 0.2, 0]]))
    P[1] = np.nan
    v = vector_from_pose(P)
    np.testing.assert_allclose(v[0], [0.1, 0, 0, 0.1, 0, 0], atol=1e-15)
    assert np.all(np.isnan(v[1]))
    trans, ang = error_magnitudes(pose_error(P, P))
    assert trans[0] == pytest.approx(0, abs=1e-15) and ang[0] == pytest.approx(0, abs=1e-7)
    assert np.isnan(trans[1]) and np.isnan(ang[1])


def test_pose_error_magnitudes_with_failed_rows():
    from openemt.evaluate import error_summary, pose_error_magnitudes

    D = pose_from_vector(np.array([[0.2, 0, 0, 0, 0, 0.1]] * 3))
    M = D.copy()
    M[0, 0, 3] += 1e-3
    M[2] = np.nan
    t, r = pose_error_magnitudes(M, D, sensor_fixture=[0.001, 0, 0, 0.1, 0.2, 0.3])
    assert t[0] == pytest.approx(1e-3, rel=1e-9) and t[1] == pytest.approx(0, abs=1e-15)
    assert np.isnan(t[2]) and np.isnan(r[2])
    s = error_summary(t, r)
    assert s["n"] == 3 and s["n_nonfinite"] == 1


@pytest.mark.parametrize("a", [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.6, 0.0, 0.8],
                               [0.0, -1.0, 0.0]])
def test_rotvec_between_takes_a_to_u_by_the_smallest_angle(a):
    a = np.asarray(a)
    rng = np.random.default_rng(7)
    u = rng.normal(size=(200, 3))
    u = np.vstack([u / np.linalg.norm(u, axis=1, keepdims=True), a, -a,
                   [[np.nan, 0.0, 1.0]]])
    rv = rotvec_between(a, u)
    R = Rotation.from_rotvec(rv[:-1]).as_matrix()
    np.testing.assert_allclose(R @ a, u[:-1], atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(rv[:-1], axis=1),
                               np.arccos(np.clip(u[:-1] @ a, -1, 1)), atol=1e-12)
    assert abs(rv[-3:-1] @ a).max() < 1e-12      # about an axis perpendicular to a
    assert np.isnan(rv[-1]).all()
