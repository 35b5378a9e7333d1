"""Characterization: error vectors, u(cal), combined u(P) (MacLachlan et al. 2025, eq. 10), per-group stats."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from openemt.evaluate import (
    STAGE_UNCERTAINTY_M,
    STAGE_UNCERTAINTY_RAD,
    characterize,
    fixture_labels,
    pose_error_magnitudes,
    pose_error_vectors,
    uncertainty_summary,
)
from openemt.geometry import pose_from_rt, pose_from_vector

R_SIGMA = np.deg2rad(0.1)


def _pairs(rng, n, t_sigma=1e-4, r_sigma=R_SIGMA):
    D = pose_from_rt(Rotation.random(n, random_state=3).as_matrix(),
                     rng.uniform(-0.2, 0.2, (n, 3)))
    e = np.hstack([t_sigma * rng.standard_normal((n, 3)), r_sigma * rng.standard_normal((n, 3))])
    M = D @ np.linalg.inv(pose_from_vector(e))  # so that inv(M) @ D = pose(e)
    return M, D, e


def test_error_vectors_match_magnitudes_and_construction():
    rng = np.random.default_rng(30)
    M, D, e = _pairs(rng, 50)
    v = pose_error_vectors(M, D)
    np.testing.assert_allclose(v, e, atol=1e-12)
    t, r = pose_error_magnitudes(M, D)
    np.testing.assert_allclose(np.linalg.norm(v[:, :3], axis=1), t, atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(v[:, 3:], axis=1), r, atol=1e-12)
    F = np.array([-3e-4, 2e-4, -3e-4, -2.2, -2.2, 0.0])
    vf = pose_error_vectors(M, D, sensor_fixture=F)
    tf, rf = pose_error_magnitudes(M, D, sensor_fixture=F)
    np.testing.assert_allclose(np.linalg.norm(vf[:, :3], axis=1), tf, atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(vf[:, 3:], axis=1), rf, atol=1e-12)


def test_uncertainty_matches_paper_table2_concentric_row():
    """MacLachlan et al. 2025, Table II, concentric source, (default) row: u(cal) 0.41555 mm / 0.27262 deg
    gives u(P) 0.429 mm / 0.321 deg with the stage's 0.107 mm / 0.17 deg (eq. 10)."""
    t = np.full(10, 0.41555e-3)
    r = np.full(10, np.deg2rad(0.27262))
    s = uncertainty_summary(t, r)
    assert s["u_cal_trans_mm"] == pytest.approx(0.41555, abs=1e-9)
    assert s["u_P_trans_mm"] == pytest.approx(0.429, abs=5e-4)
    assert s["u_P_rot_deg"] == pytest.approx(0.321, abs=5e-4)
    # corrected row: 0.263 -> 0.284
    s2 = uncertainty_summary(np.full(10, 0.26306e-3), r)
    assert s2["u_P_trans_mm"] == pytest.approx(0.284, abs=5e-4)
    assert STAGE_UNCERTAINTY_M == 0.107e-3
    assert np.rad2deg(STAGE_UNCERTAINTY_RAD) == pytest.approx(0.17)


def test_characterize_overall_and_groups():
    rng = np.random.default_rng(31)
    M, D, _ = _pairs(rng, 400)
    groups = np.where(np.arange(400) < 100, "soYoutZup_seZinYup", "soYoutZup_seYoutZup")
    M[:100, :3, 3] += [1e-3, 0, 0]  # a 1 mm bias on the first group (in the source frame)
    M[5] = np.nan  # a failed solve
    c = characterize(M, D, groups=groups)
    o = c.overall
    assert o["n"] == 400 and o["n_nonfinite"] == 1
    g1, g2 = c.by_group["soYoutZup_seZinYup"], c.by_group["soYoutZup_seYoutZup"]
    assert list(c.by_group) == ["soYoutZup_seZinYup", "soYoutZup_seYoutZup"]
    assert g1["n"] == 100 and g2["n"] == 300
    assert g1["trans_rms_mm"] == pytest.approx(1.0, abs=0.05)
    # isotropic 0.1 mm per axis: RMS magnitude sqrt(3) * 0.1 mm
    assert g2["trans_rms_mm"] == pytest.approx(np.sqrt(3) * 0.1, rel=0.1)
    assert g2["u_P_trans_mm"] == pytest.approx(np.hypot(g2["trans_rms_mm"], 0.107), rel=1e-12)
    assert o["u_P_rot_deg"] > o["u_cal_rot_deg"]
    assert c.error_vectors.shape == (400, 6) and np.isnan(c.error_vectors[5]).all()
    np.testing.assert_allclose(c.positions, D[:, :3, 3])
    assert set(c.to_dict()) == {"overall", "by_group"}
    with pytest.raises(ValueError):
        characterize(M, D, groups=groups[:5])
    with pytest.raises(ValueError):
        characterize(M[:3], D)


def test_fixture_labels():
    class DS:
        source_fixture = np.array(["YoutZup", "XinYup"])
        sensor_fixture = np.array(["ZinXdown", "YoutZup"])
    assert fixture_labels(DS).tolist() == ["soYoutZup_seZinXdown", "soXinYup_seYoutZup"]
