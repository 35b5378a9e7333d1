"""Hand-eye / robot-world calibration A_i X = Y B_i on simulated pairs with known X, Y, noise
and outliers; pairing of recordings; ``openemt align``."""

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from openemt.align import axyb_closed_form, fit_axyb, pair_rows, reference_in_measured_frame
from openemt.cli import main
from openemt.geometry import invert, pose_from_rt
from openemt.io import pose_dataset, read_poses_csv, write_dataset


def _truth(seed):
    rng = np.random.default_rng(seed)
    X = pose_from_rt(Rotation.random(random_state=seed + 1).as_matrix(),
                     rng.uniform(-0.05, 0.05, 3))
    Y = pose_from_rt(Rotation.random(random_state=seed + 2).as_matrix(),
                     rng.uniform(-0.5, 0.5, 3))
    return X, Y


DEG = np.pi / 180


def _pairs(n, X, Y, rng, st_a=0.5e-3, sr_a=0.2 * DEG, st_b=0.25e-3, sr_b=0.1 * DEG):
    A = pose_from_rt(Rotation.random(n, random_state=int(rng.integers(1 << 30))).as_matrix(),
                     rng.uniform(-0.15, 0.15, (n, 3)) + [0.0, 0.0, 0.2])
    B = invert(Y) @ A @ X

    def noisy(P, st, sr):
        R = Rotation.from_rotvec(sr * rng.standard_normal((len(P), 3))).as_matrix()
        return pose_from_rt(R @ P[:, :3, :3], P[:, :3, 3] + st * rng.standard_normal((n, 3)))

    return noisy(A, st_a, sr_a), noisy(B, st_b, sr_b)


def _z(P, T, se):
    d = np.concatenate([P[:3, 3] - T[:3, 3],
                        Rotation.from_matrix(P[:3, :3] @ T[:3, :3].T).as_rotvec()])
    return d / se


def test_closed_form_is_exact_without_noise():
    X, Y = _truth(0)
    rng = np.random.default_rng(0)
    A, B = _pairs(5, X, Y, rng, 0, 0, 0, 0)
    Xh, Yh = axyb_closed_form(A, B)
    np.testing.assert_allclose(Xh, X, atol=1e-12)
    np.testing.assert_allclose(Yh, Y, atol=1e-12)
    np.testing.assert_allclose(reference_in_measured_frame(B, Xh, Yh), A, atol=1e-12)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_recovers_x_y_within_three_standard_errors_despite_outliers(seed):
    X, Y = _truth(seed)
    rng = np.random.default_rng(seed)
    A, B = _pairs(50, X, Y, rng)
    A[7, :3, 3] += 0.02                                   # a 20 mm EM glitch
    B[21, :3, :3] = Rotation.from_rotvec([0.0, 0.3, 0.0]).as_matrix() @ B[21, :3, :3]
    r = fit_axyb(A, B, seed=seed)
    assert {7, 21} <= set(r.outliers.tolist()) and len(r.outliers) <= 4
    assert np.all(np.abs(_z(r.X, X, r.X_se)) < 3)
    assert np.all(np.abs(_z(r.Y, Y, r.Y_se)) < 3)
    # standard errors of the right size: not inflated beyond the noise levels
    assert np.all(r.X_se[:3] < 0.3e-3) and np.all(r.X_se[3:] < np.deg2rad(0.1))
    # noise levels recovered; the held-out residual is close to the in-sample one
    assert 0.3e-3 < r.sigma_trans < 0.6e-3
    s = r.summary()
    assert s["held_out"]["n_folds"] == 5
    assert s["held_out"]["trans_rms_mm"] < 1.3 * s["residual_trans_rms_mm"]
    # without screening the outliers pull the solution away
    plain = fit_axyb(A, B, robust=False, folds=0)
    assert np.max(np.abs(_z(plain.X, X, r.X_se))) > np.max(np.abs(_z(r.X, X, r.X_se)))


def test_bad_inputs():
    X, Y = _truth(4)
    rng = np.random.default_rng(4)
    A, B = _pairs(10, X, Y, rng)
    with pytest.raises(ValueError, match="at least 3"):
        fit_axyb(A[:2], B[:2])
    with pytest.raises(ValueError, match="folds"):
        fit_axyb(A, B, folds=100000)
    with pytest.raises(ValueError, match="same shape"):
        fit_axyb(A, B[:5])


ONE_AXIS = "rotations about at least two non-parallel axes .* got rotations within"


@pytest.mark.parametrize("noise_deg", [0.0, 0.05, 0.5])
@pytest.mark.parametrize("scale", [1e-3, 1.0, 1e3])
def test_one_axis_motion_is_named_before_any_fit(noise_deg, scale):
    """Rotations about one axis leave X and Y undetermined: the error names the cause, whatever
    the noise (which decides what a fit would do) and the unit of the translations."""
    X, Y = _truth(4)
    rng = np.random.default_rng(4)
    axis = Rotation.random(random_state=5).apply([0.0, 0.0, 1.0])
    Rz = Rotation.from_rotvec(np.outer(np.linspace(0, 2, 6), axis)).as_matrix()
    A1 = pose_from_rt(Rz, rng.normal(size=(6, 3)))
    B1 = invert(Y) @ A1 @ X
    noise = Rotation.from_rotvec(np.deg2rad(noise_deg) * rng.standard_normal((6, 3)))
    A1[:, :3, :3] = noise.as_matrix() @ A1[:, :3, :3]
    A1[:, :3, 3] *= scale
    B1[:, :3, 3] *= scale
    with pytest.raises(ValueError, match=ONE_AXIS):
        fit_axyb(A1, B1)


def test_no_rotation_and_two_axes():
    X, Y = _truth(6)
    rng = np.random.default_rng(6)
    A0 = pose_from_rt(np.repeat(np.eye(3)[None], 8, 0), rng.normal(size=(8, 3)))
    with pytest.raises(ValueError, match="got no rotation"):
        fit_axyb(A0, invert(Y) @ A0 @ X)
    # rotations of 10 deg about x and about y: enough (the check passes, the fit recovers X)
    rv = np.zeros((8, 3))
    rv[:4, 0] = np.deg2rad(np.linspace(-10, 10, 4))
    rv[4:, 1] = np.deg2rad(np.linspace(-10, 10, 4))
    A2 = pose_from_rt(Rotation.from_rotvec(rv).as_matrix(), rng.normal(size=(8, 3)))
    r = fit_axyb(A2, invert(Y) @ A2 @ X, folds=0)
    np.testing.assert_allclose(r.X, X, atol=1e-9)


def test_pair_rows_by_order_and_frame():
    i, j, info = pair_rows(3, 3)
    assert i.tolist() == j.tolist() == [0, 1, 2]
    with pytest.raises(ValueError, match="--match frame"):
        pair_rows(3, 4)
    i, j, info = pair_rows(4, 5, match="frame", measured_frame=[10, 11, 12, -1],
                           reference_frame=[9, 10, 12, 13, 11])
    assert i.tolist() == [0, 1, 2] and j.tolist() == [1, 4, 2]
    assert info["n_unmatched_measured"] == 1 and info["n_unmatched_reference"] == 2
    with pytest.raises(ValueError, match="unique"):
        pair_rows(2, 2, match="frame", measured_frame=[1, 1], reference_frame=[1, 2])


def test_align_command_writes_pairs_in_the_measured_frame(tmp_path, capsys):
    X, Y = _truth(5)
    rng = np.random.default_rng(5)
    A, B = _pairs(30, X, Y, rng, 0.2e-3, np.deg2rad(0.05), 0.1e-3, np.deg2rad(0.05))
    A[3, :3, 3] += 0.01
    frames = np.arange(100, 130)
    order = rng.permutation(30)  # the reference recording lists its frames shuffled
    write_dataset(pose_dataset(A, file_index=np.zeros(30, int), files=["em.tsv"],
                               extra={"frame": frames}), tmp_path / "em.h5")
    write_dataset(pose_dataset(B[order], file_index=np.zeros(30, int), files=["opt.tsv"],
                               extra={"frame": frames[order]}), tmp_path / "opt.h5")
    out = tmp_path / "pairs.csv"
    assert main(["align", str(tmp_path / "em.h5"), str(tmp_path / "opt.h5"), "-o", str(out),
                 "--match", "frame", "--json"]) == 0
    cap = capsys.readouterr()
    s = json.loads(cap.out)
    assert s["n"] == 30 and s["outliers"] == [3] and s["n_written"] == 29
    assert {"residual_trans_rms_mm", "residual_rot_rms_deg", "X", "Y", "X_se",
            "Y_se"} <= set(s)
    assert s["residual_trans_rms_mm"] < 0.6 and "X (reference tool" in cap.err
    assert np.all(np.abs(_z(np.array(s["X"]), X, np.array(s["X_se"]))) < 3)
    t = read_poses_csv(out)
    assert len(t) == 29 and t.frame.tolist() == [f for f in frames if f != 103]
    np.testing.assert_allclose(t.reference[:, :3, 3], t.poses[:, :3, 3], atol=2e-3)
    # pairing by order fails on the shuffled recording: large residuals, not silence
    assert main(["align", str(tmp_path / "em.h5"), str(tmp_path / "opt.h5"), "-o",
                 str(tmp_path / "p2.csv"), "--json", "--folds", "100000"]) == 2
    assert "folds" in capsys.readouterr().err
