"""Simulated reference-pose collections (robot arm, optical tracker) and ``openemt simulate
--reference``."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from openemt import cli
from openemt.align import reference_in_measured_frame
from openemt.calibrate import ParameterLayout
from openemt.evaluate import pose_error_magnitudes
from openemt.io import read_calibration, read_dataset
from openemt.simulate import (
    REFERENCE_KINDS,
    get_preset,
    nominal_calibration,
    simulate_reference,
)


@pytest.mark.parametrize("kind", ["robot", "optical"])
def test_reference_poses_match_truth_within_stated_noise(kind):
    ds = simulate_reference("concentric", kind, 400, seed=3)
    k = REFERENCE_KINDS[kind]
    X = np.array(ds.meta["truth"]["X"])
    Y = np.array(ds.meta["truth"]["Y"])
    B, B_true = ds.extra["reference_poses"], ds.extra["reference_poses_true"]
    # the convention of openemt.align: sensor pose = Y B X^-1
    np.testing.assert_allclose(reference_in_measured_frame(B_true, X, Y), ds.poses, atol=1e-12)
    t, r = pose_error_magnitudes(B, B_true)
    # stated noise: 3-D RMS translation and RMS angle
    assert np.sqrt(np.mean(t ** 2)) == pytest.approx(k.noise_trans, rel=0.15)
    assert np.sqrt(np.mean(r ** 2)) == pytest.approx(k.noise_rot, rel=0.15)
    assert ds.meta["reference"]["noise_trans_m"] == k.noise_trans
    # poses in the tracker's volume: one hemisphere, 150-350 mm from the source
    h = np.array(ds.meta["reference"]["hemisphere"])
    assert np.all(ds.poses[:, :3, 3] @ h > 0.1)
    d = np.linalg.norm(ds.poses[:, :3, 3], axis=1)
    assert d.min() > 0.15 and d.max() < 0.35
    # rotation diversity about every axis
    R = ds.poses[:, :3, :3]
    rv = Rotation.from_matrix(R @ R[0].T).as_rotvec()
    spread = np.sqrt(np.linalg.eigvalsh(np.cov(rv.T)))
    assert np.all(spread > np.deg2rad(10.0))
    assert ds.couplings.shape == (400, 3, 3)


def test_noise_settable_and_seeded():
    a = simulate_reference("concentric", "robot", 50, noise_trans=0.0, noise_rot=0.0, seed=1)
    np.testing.assert_array_equal(a.extra["reference_poses"], a.extra["reference_poses_true"])
    b = simulate_reference("concentric", "robot", 50, noise_trans=0.0, noise_rot=0.0, seed=1)
    np.testing.assert_array_equal(a.couplings, b.couplings)
    c = simulate_reference("concentric", "robot", 50, seed=2)
    assert not np.allclose(a.poses, c.poses)
    d = simulate_reference("concentric", "robot", 50, snr_db=60, seed=1)
    assert np.any(d.extra["noise_sigma"] > 0) and not np.allclose(d.couplings, a.couplings)


def test_bad_arguments():
    with pytest.raises(ValueError, match="6-DOF sensor .two or more coils.*got .anser. with 1"):
        simulate_reference("anser", "robot", 10)
    with pytest.raises(ValueError, match="reference kind"):
        simulate_reference("concentric", "laser", 10)
    with pytest.raises(ValueError, match="n_poses >= 3"):
        simulate_reference("concentric", "robot", 2)
    with pytest.raises(ValueError, match="noise_trans"):
        simulate_reference("concentric", "robot", 10, noise_trans=-1.0)


def test_nominal_calibration_follows_the_gauge():
    cal = nominal_calibration("dipole-approx")
    lay = ParameterLayout.for_model(cal.model)
    x = lay.pack_calibration(cal)
    truth = get_preset("dipole-approx").dipole
    assert not np.any(x[lay.gauge[:3]])  # reference coil at the origin
    assert cal.model.M_so[2, 2] == pytest.approx(np.linalg.norm(truth.M_so[:, 2]))
    assert cal.model.M_so[1, 0] == 0.0 and cal.model.M_se[1, 0] == 0.0
    assert cal.model.is_concentric


@pytest.fixture
def main():
    return cli.main


def test_simulate_reference_command(main, tmp_path, capsys):
    out, truth = tmp_path / "opt.h5", tmp_path / "truth.json"
    code = main(["simulate", "--preset", "concentric", "--reference", "optical", "--n-poses",
                 "40", "--reference-noise-mm", "0.3", "--reference-noise-deg", "0.05",
                 "--snr-db", "80", "--seed", "4", "-o", str(out), "--truth-calibration",
                 str(truth), "--json", "--quiet"])
    assert code == 0
    s = json.loads(capsys.readouterr().out)
    assert s["n_samples"] == 40 and s["reference"]["kind"] == "optical"
    assert s["reference"]["noise_trans_m"] == pytest.approx(3e-4)
    assert s["reference"]["noise_rot_rad"] == pytest.approx(np.deg2rad(0.05))
    ds = read_dataset(out)
    want = simulate_reference("concentric", "optical", 40, noise_trans=3e-4,
                              noise_rot=np.deg2rad(0.05), snr_db=80, seed=4)
    np.testing.assert_array_equal(ds.couplings, want.couplings)
    np.testing.assert_array_equal(ds.extra["reference_poses"], want.extra["reference_poses"])
    cal = read_calibration(truth)
    X, Y = (np.array(cal.extra["reference"][k]) for k in ("X", "Y"))
    np.testing.assert_allclose(X, s["truth"]["X"])
    # the truth calibration predicts the noise-free couplings through Y B X^-1
    P = reference_in_measured_frame(ds.extra["reference_poses_true"], X, Y)
    np.testing.assert_allclose(P, ds.poses, atol=1e-12)
    np.testing.assert_allclose(cal.stage_fixture[:3], Y[:3, 3])


def test_simulate_reference_refuses_rig_options(main, tmp_path, capsys):
    out = tmp_path / "x.h5"
    code = main(["simulate", "--reference", "robot", "--pattern", "md", "-o", str(out)])
    assert code == 2 and not out.exists()
    assert "--reference" in capsys.readouterr().err
