"""openemt.navigate: pivot and spin calibration, paired-point registration and the grid
assessment recover simulated truth within their standard errors; refusals name their cause."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from openemt._errors import InputError
from openemt.navigate import (
    assess_grid,
    pivot_calibration,
    register_points,
    register_points_batch,
    regular_grid,
    simulate_grid_points,
    simulate_pivot_poses,
    simulate_spin_poses,
    spin_calibration,
)

TIP = np.array([0.012, -0.004, 0.155])
PIVOT = np.array([0.11, 0.03, 0.21])


def _within(est, truth, se, k=3.0):
    z = (np.asarray(est) - truth) / np.asarray(se)
    assert np.all(np.abs(z) < k), z


# --------------------------------------------------------------------------- pivot


def test_pivot_standard_errors_are_calibrated():
    """Over many simulated recordings the error falls within 1 SE about 68 % of the time and
    within 3 SE nearly always: the standard errors mean what they say."""
    rng = np.random.default_rng(0)
    z = []
    for _ in range(300):
        P = simulate_pivot_poses(40, TIP, PIVOT, rng, noise=3e-4)
        r = pivot_calibration(P)
        z.append(np.concatenate([(r.tip - TIP) / r.tip_se, (r.pivot - PIVOT) / r.pivot_se]))
    a = np.abs(np.array(z))
    assert 0.62 < np.mean(a < 1) < 0.74
    assert np.mean(a < 3) > 0.99


@pytest.mark.parametrize("method", ["algebraic", "sphere", "ransac"])
def test_pivot_recovers_truth_without_outliers(method):
    P = simulate_pivot_poses(60, TIP, PIVOT, np.random.default_rng(1))
    r = pivot_calibration(P, method)
    _within(r.tip, TIP, r.tip_se)
    _within(r.pivot, PIVOT, r.pivot_se)
    assert r.n == r.n_inliers == 60
    d = r.to_dict()
    assert d["rms_mm"] == pytest.approx(np.sqrt(3) * d["rms_component_mm"])
    # the per-pose residuals are R_i t + p_i - q
    res = np.einsum("nij,j->ni", P[:, :3, :3], r.tip) + P[:, :3, 3] - r.pivot
    np.testing.assert_allclose(r.residuals, res, atol=1e-15)
    assert d["rms_mm"] == pytest.approx(1e3 * np.sqrt(np.mean(np.sum(res ** 2, axis=1))))
    # 0.2 mm noise per axis: RMS 3-D residual close to 0.35 mm
    assert 0.25 < d["rms_mm"] < 0.45


def test_pivot_ransac_rejects_slipped_poses():
    P = simulate_pivot_poses(60, TIP, PIVOT, np.random.default_rng(2), n_outliers=8,
                             outlier_offset=0.006)
    r = pivot_calibration(P, "ransac")
    assert r.to_dict()["outlier_rows"] == list(range(8))
    assert r.n_inliers == 52
    _within(r.tip, TIP, r.tip_se)
    _within(r.pivot, PIVOT, r.pivot_se)
    assert r.warnings == ()
    # the plain fit is pulled off: answered, and flagged with its residual figure
    plain = pivot_calibration(P, "algebraic")
    (w,) = plain.warnings
    assert f"{1e3 * plain.rms:.3g} mm is above the expected 2 mm" in w and "slipped" in w
    assert plain.to_dict()["warnings"] == [w]
    loose = pivot_calibration(P, "algebraic", max_rms_mm=None)
    assert loose.rms > 3 * r.rms and loose.n_inliers == 60 and loose.warnings == ()


def test_pivot_refusals_and_nonfinite_rows():
    rng = np.random.default_rng(3)
    with pytest.raises(InputError, match="at least 10 poses"):
        pivot_calibration(simulate_pivot_poses(9, TIP, PIVOT, rng))
    # rotations about one axis leave the tip along it undetermined: refused before any fit
    R = Rotation.from_rotvec(np.outer(np.linspace(-0.5, 0.5, 30), [0, 0, 1])).as_matrix()
    P = np.tile(np.eye(4), (30, 1, 1))
    P[:, :3, :3] = R
    P[:, :3, 3] = PIVOT - R @ TIP
    with pytest.raises(InputError, match="two non-parallel axes.*pivot calibration.*another axis"):
        pivot_calibration(P)
    with pytest.raises(InputError, match="method"):
        pivot_calibration(simulate_pivot_poses(20, TIP, PIVOT, rng), "lsq")
    P = simulate_pivot_poses(30, TIP, PIVOT, rng)
    P[[3, 7]] = np.nan
    r = pivot_calibration(P)
    d = r.to_dict()
    assert (d["n"], d["n_nonfinite"], d["n_inliers"]) == (28, 2, 28)
    assert r.per_pose()["distance_mm"][3] is None


# --------------------------------------------------------------------------- spin

AXIS = np.array([0.1, -0.2, 1.0]) / np.linalg.norm([0.1, -0.2, 1.0])
POINT = np.array([0.002, 0.003, -0.0004]) - np.dot([0.002, 0.003, -0.0004], AXIS) * AXIS


def _angle_deg(a, b):
    return np.rad2deg(np.arccos(np.clip(abs(np.dot(a, b)), -1, 1)))


@pytest.mark.parametrize("method", ["algebraic", "ransac"])
def test_spin_recovers_axis_and_point(method):
    P = simulate_spin_poses(60, AXIS, POINT, np.random.default_rng(4))
    s = spin_calibration(P, method, tip=AXIS)
    assert np.dot(s.axis, AXIS) > 0
    # the angle of a 2-D Gaussian error of total SE axis_se stays below 3 SE
    assert _angle_deg(s.axis, AXIS) < 3 * s.axis_se_deg
    _within(s.point, POINT, s.point_se)
    assert s.n_inliers == 60
    assert s.to_dict()["spin_deg"] > 30


def test_spin_ransac_and_refusals():
    rng = np.random.default_rng(5)
    P = simulate_spin_poses(60, AXIS, POINT, rng)
    P[:5, :3, :3] = P[:5, :3, :3] @ Rotation.from_rotvec([0.2, 0.1, 0]).as_matrix()
    s = spin_calibration(P, "ransac")
    assert s.to_dict()["outlier_rows"] == [0, 1, 2, 3, 4]
    assert _angle_deg(s.axis, AXIS) < 3 * s.axis_se_deg
    with pytest.raises(InputError, match="at least 10 deg RMS.*turn the tool further"):
        spin_calibration(simulate_spin_poses(40, AXIS, POINT, rng, spin_deg=5))
    # pivot poses are no spin: the axis residual is far above the limit
    wobbled = spin_calibration(simulate_pivot_poses(40, TIP, PIVOT, rng))
    assert len(wobbled.warnings) == 1 and "spin-axis residual RMS" in wobbled.warnings[0]
    assert "wobbled" in wobbled.warnings[0]


# --------------------------------------------------------------------------- registration


def _true_transform():
    return Rotation.from_rotvec([0.3, -0.2, 0.5]), np.array([0.05, -0.1, 0.3])


def test_register_recovers_truth_within_standard_errors():
    rng = np.random.default_rng(6)
    rot, t = _true_transform()
    moving = rng.uniform(-0.08, 0.08, (8, 3))
    fixed = rot.apply(moving) + t + rng.normal(0, 3e-4, (8, 3))
    reg = register_points(fixed, moving)
    R = reg.transform[:3, :3]
    _within((Rotation.from_matrix(R) * rot.inv()).as_rotvec(), 0.0, reg.rotation_se)
    _within(reg.transform[:3, 3], t, reg.translation_se)
    assert reg.scale == 1.0
    np.testing.assert_allclose(reg.residuals, reg.apply(moving) - fixed, atol=1e-15)
    d = reg.to_dict()
    assert d["fre_rms_mm"] == pytest.approx(
        1e3 * np.sqrt(np.mean(np.sum(reg.residuals ** 2, axis=1))))
    assert len(d["residual_mm"]) == 8


def test_register_similarity_and_weights():
    rng = np.random.default_rng(7)
    rot, t = _true_transform()
    moving = rng.uniform(-0.08, 0.08, (10, 3))
    fixed = 1.02 * rot.apply(moving) + t + rng.normal(0, 2e-4, (10, 3))
    reg = register_points(fixed, moving, scale=True)
    _within(reg.scale, 1.02, reg.scale_se)
    # a zero weight removes a point: same as leaving it out
    w = np.ones(10)
    w[4] = 0
    a = register_points(fixed, moving, w)
    b = register_points(np.delete(fixed, 4, 0), np.delete(moving, 4, 0))
    np.testing.assert_allclose(a.transform, b.transform, atol=1e-12)
    with pytest.raises(InputError, match="collinear"):
        register_points(fixed[:4], np.outer(np.arange(4.0), [1, 1, 0]))
    with pytest.raises(InputError, match="at least 3"):
        register_points(fixed[:2], moving[:2])


def test_predicted_tre_matches_monte_carlo():
    """Fitzpatrick-West: the mean squared TRE over many registrations equals the prediction."""
    rng = np.random.default_rng(8)
    rot, t = _true_transform()
    moving = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.08, 0], [0, 0, 0.06], [0.05, 0.05, 0.02]])
    targets = np.array([[0.02, 0.02, 0.02], [0.2, -0.1, 0.15]])
    fle = 5e-4
    err2 = np.zeros(len(targets))
    fre2 = 0.0
    n = 800
    for _ in range(n):
        fixed = rot.apply(moving) + t + rng.normal(0, fle / np.sqrt(3), moving.shape)
        reg = register_points(fixed, moving, targets=targets, fle_rms=fle)
        err2 += np.sum((reg.apply(targets) - (rot.apply(targets) + t)) ** 2, axis=1)
        fre2 += reg.fre_rms ** 2
    np.testing.assert_allclose(np.sqrt(err2 / n), reg.tre_rms, rtol=0.06)
    # <FRE^2> = (1 - 2/K) FLE^2
    assert np.sqrt(fre2 / n) == pytest.approx(fle * np.sqrt(1 - 2 / 5), rel=0.05)
    # the far target is predicted worse than the central one
    assert reg.tre_rms[1] > 2 * reg.tre_rms[0]


def test_register_batch_equals_single_and_flags_bad_frames():
    rng = np.random.default_rng(9)
    geometry = rng.uniform(-0.05, 0.05, (5, 3))
    rots = Rotation.random(6, random_state=rng)
    obs = np.stack([r.apply(geometry) + [0.1 * i, 0, 0.2] for i, r in enumerate(rots)])
    obs += rng.normal(0, 1e-4, obs.shape)
    obs[2, 1] = np.nan  # an occluded marker
    obs[4, :3] = np.nan  # only 2 markers left
    b = register_points_batch(obs, geometry)
    for i in (0, 1, 3, 5):
        np.testing.assert_allclose(b.poses[i], register_points(obs[i], geometry).transform,
                                   atol=1e-12)
    keep = [0, 2, 3, 4]
    np.testing.assert_allclose(b.poses[2],
                               register_points(obs[2, keep], geometry[keep]).transform,
                               atol=1e-12)
    assert np.all(np.isnan(b.poses[4])) and np.isnan(b.fre_rms[4])
    assert b.n_used.tolist() == [5, 5, 4, 5, 2, 5]
    assert b.to_dict()["n_failed"] == 1


# --------------------------------------------------------------------------- assess


def test_assess_scaled_square_by_hand():
    """A 50 mm square measured 1 % too large: the best rigid fit leaves every corner
    eps * 25 sqrt(2) mm off, sides are 0.5 mm and diagonals 0.5 sqrt(2) mm too long."""
    eps = 0.01
    nominal = 1e-3 * np.array([[0, 0, 0], [50, 0, 0], [50, 50, 0], [0, 50, 0]], float)
    rot = Rotation.from_rotvec([0.2, -0.1, 0.4])
    measured = rot.apply((1 + eps) * nominal) + [0.1, 0.2, 0.3]
    d = assess_grid(measured, nominal).to_dict()
    corner = eps * 25 * np.sqrt(2)
    assert d["rigid_rms_mm"] == pytest.approx(corner, rel=1e-9)
    assert d["rigid_mean_mm"] == pytest.approx(corner, rel=1e-9)
    assert d["rigid_max_mm"] == pytest.approx(corner, rel=1e-9)
    errors = eps * np.array([50, 50, 50, 50, 50 * np.sqrt(2), 50 * np.sqrt(2)])
    assert d["n_distances"] == 6 and d["n"] == 4
    assert d["distance_error_mean_mm"] == pytest.approx(errors.mean(), rel=1e-9)
    assert d["distance_error_rms_mm"] == pytest.approx(np.sqrt(np.mean(errors ** 2)), rel=1e-9)
    assert d["distance_classes"]["50"]["n"] == 4
    assert d["distance_classes"]["50"]["mean_mm"] == pytest.approx(0.5, rel=1e-9)
    assert d["distance_classes"]["150"]["n"] == 0
    assert d["jitter"] is None and "rotation_error_rms_deg" not in d


def test_assess_grid_against_independent_statistics():
    rng = np.random.default_rng(10)
    nominal = regular_grid(0.05, (3, 3, 2))
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([0.1, 0.3, -0.2]).as_matrix()
    T[:3, 3] = [0.1, -0.05, 0.25]
    samples, labels = simulate_grid_points(nominal, rng, transform=T, noise=3e-4, repeats=3)
    res = assess_grid(samples, nominal, groups=labels)
    d = res.to_dict()
    mean = samples.reshape(18, 3, 3).mean(axis=1)
    # rigid fit computed independently (scipy's Kabsch on the centred points)
    c_m, c_n = mean.mean(0), nominal.mean(0)
    R, _ = Rotation.align_vectors(nominal - c_n, mean - c_m)
    r = np.linalg.norm(R.apply(mean - c_m) + c_n - nominal, axis=1)
    assert d["rigid_rms_mm"] == pytest.approx(1e3 * np.sqrt(np.mean(r ** 2)), rel=1e-9)
    assert d["rigid_max_mm"] == pytest.approx(1e3 * r.max(), rel=1e-9)
    errs, cls = [], []
    for i in range(18):
        for j in range(i + 1, 18):
            dn = np.linalg.norm(nominal[i] - nominal[j])
            errs.append(np.linalg.norm(mean[i] - mean[j]) - dn)
            if abs(dn - 0.15) < 1e-6:
                cls.append(errs[-1])
    errs = 1e3 * np.array(errs)
    assert d["n_distances"] == 153
    assert d["distance_error_mean_mm"] == pytest.approx(np.mean(np.abs(errs)), rel=1e-9)
    assert d["distance_error_rms_mm"] == pytest.approx(np.sqrt(np.mean(errs ** 2)), rel=1e-9)
    assert d["distance_classes"]["150"]["n"] == len(cls) > 0
    # jitter: RMS distance of the samples from their point's mean
    jit = np.linalg.norm(samples.reshape(18, 3, 3) - mean[:, None], axis=2)
    assert d["jitter"]["jitter_trans_rms_mm"] == pytest.approx(
        1e3 * np.sqrt(np.mean(jit ** 2)), rel=1e-9)
    # nearest-neighbour matching of shuffled points finds the same pairs and statistics
    perm = rng.permutation(len(samples))
    near = assess_grid(samples[perm], nominal, groups=labels[perm], match="nearest").to_dict()
    assert near["rigid_rms_mm"] == pytest.approx(d["rigid_rms_mm"], rel=1e-9)
    assert near["distance_error_rms_mm"] == pytest.approx(d["distance_error_rms_mm"], rel=1e-9)
    with pytest.raises(InputError, match="match 'nearest'"):
        assess_grid(samples[:10], nominal)


def test_assess_rotation_errors_and_nonfinite_rows():
    nominal = regular_grid(0.05, (2, 2, 2))
    angles = np.deg2rad([0.5, -0.5, 0.5, -0.5, 0.5, -0.5, 0.5, -0.5])
    P = np.tile(np.eye(4), (9, 1, 1))
    P[:8, :3, :3] = Rotation.from_rotvec(np.outer(angles, [0, 0, 1])).as_matrix()
    P[:8, :3, 3] = nominal
    P[8] = np.nan
    d = assess_grid(P, np.vstack([nominal, [[1, 1, 1]]])[:8], match="nearest").to_dict()
    assert d["rotation_error_rms_deg"] == pytest.approx(0.5, rel=1e-9)
    assert d["rotation_error_max_deg"] == pytest.approx(0.5, rel=1e-9)
    assert (d["n"], d["n_rows"], d["n_nonfinite"]) == (8, 9, 1)
    assert d["rigid_max_mm"] < 1e-9
