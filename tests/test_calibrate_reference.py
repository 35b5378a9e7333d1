"""Reference-pose calibration: coil model, X and Y against robot / optical reference poses
(docs/reference-calibration.md)."""

from __future__ import annotations

import argparse
import json
import warnings
from dataclasses import replace

import numpy as np
import pytest

from openemt.calibrate import (
    IdentifiabilityWarning,
    fit,
    fit_reference,
    score_reference,
    stage_reference,
)
from openemt.cli import _calibrate
from openemt.evaluate import error_summary, pose_error_magnitudes
from openemt.geometry import ground_truth_poses, invert
from openemt.io import import_ilemt_folder, read_calibration, read_ilemt_calibration, write_dataset
from openemt.simulate import (
    get_preset,
    nominal_calibration,
    reference_truth_calibration,
    simulate_reference,
)
from openemt.solve import hemisphere_from_positions, solve_lm


def _exact(preset="concentric"):
    p = get_preset(preset)
    return replace(p, model=p.dipole)  # exact dipoles: the model can be right


def _perturbation(P, P0):
    from scipy.spatial.transform import Rotation

    return np.r_[P[:3, 3] - P0[:3, 3], Rotation.from_matrix(P[:3, :3] @ P0[:3, :3].T).as_rotvec()]


def _z_scores(f, ds, preset):
    X, Y = (np.array(ds.meta["truth"][k]) for k in ("X", "Y"))
    truth = reference_truth_calibration(preset, X, Y)
    x_true = f.layout.pack_calibration(truth)
    se = np.zeros(f.layout.size)
    se_fields = f.calibration.standard_errors
    for name, key in (("L_so", "L_so"), ("M_so", "M_so"), ("L_se", "L_se"), ("M_se", "M_se")):
        se[f.layout.slices[name]] = np.asarray(se_fields[key]).T.ravel()
    for name, key in (("F_st", "stage_fixture"), ("F_se", "sensor_fixture")):
        se[f.layout.slices[name]] = se_fields[key]
    z_model = (f.x[f.free] - x_true[f.free]) / se[f.free]
    z_xy = np.r_[_perturbation(X, f.X) / f.X_se, _perturbation(Y, f.Y) / f.Y_se]
    return z_model, z_xy


@pytest.mark.parametrize("kind,seeds", [("robot", (1, 2)), ("optical", (3, 4))])
def test_recovers_model_x_and_y_within_standard_errors(kind, seeds):
    zs = []
    for seed in seeds:
        ds = simulate_reference(_exact(), kind, 250, snr_db=80, seed=seed)
        with warnings.catch_warnings():
            warnings.simplefilter("error", IdentifiabilityWarning)
            f = fit_reference(ds, nominal_calibration("concentric"))  # hand-eye start
        assert f.start["method"] == "hand-eye"
        assert f.identifiability["rank"] == f.identifiability["n_free"] == 35
        assert not f.identifiability["ill_conditioned"]
        z_model, z_xy = _z_scores(f, ds, "concentric")
        zs.append(np.r_[z_model, z_xy])
    z = np.concatenate(zs)
    assert np.mean(np.abs(z) < 3.0) >= 0.95
    assert np.max(np.abs(z)) < 4.0
    assert 0.4 < np.sqrt(np.mean(z ** 2)) < 1.6  # standard errors of the right size


@pytest.mark.parametrize("kind", ["robot", "optical"])
def test_held_out_error_near_noise_level(kind):
    ds = simulate_reference(_exact(), kind, 300, snr_db=80, seed=7)
    f = fit_reference(ds, nominal_calibration("concentric"), holdout=0.25, seed=1)
    h = f.holdout
    assert h["n"] == 75 and f.n_train == 225 and h["n_not_converged"] == 0
    # noise-implied level: the reference's stated noise and the couplings' noise (solving the
    # held-out couplings with the true model against the true poses)
    test = f.test
    P = ds.poses[test]
    res = solve_lm(ds.couplings[test], get_preset("concentric").dipole, initial="kim18",
                   hemisphere=hemisphere_from_positions(P[:, :3, 3]))
    t, r = pose_error_magnitudes(res.poses, P)
    s = error_summary(t, r)
    ref = ds.meta["reference"]
    implied_t = np.hypot(ref["noise_trans_m"] * 1e3, s["trans_rms_mm"])
    implied_r = np.hypot(np.rad2deg(ref["noise_rot_rad"]), s["rot_rms_deg"])
    assert 0.75 * implied_t < h["trans_rms_mm"] < 1.3 * implied_t
    assert 0.75 * implied_r < h["rot_rms_deg"] < 1.3 * implied_r
    assert h["trans_max_mm"] >= h["trans_rms_mm"]
    assert h["trans_uncert_mm"] == pytest.approx(np.hypot(h["trans_rms_mm"],
                                                          h["reference_noise_mm"]))
    # the written calibration carries X and Y
    block = f.calibration.extra["reference"]
    np.testing.assert_allclose(np.array(block["X"]), f.X)
    np.testing.assert_allclose(f.calibration.sensor_fixture[:3], invert(f.X)[:3, 3])


def test_without_rotation_diversity_x_is_flagged():
    ds = simulate_reference(_exact(), "robot", 120, rotation_range=0.0, snr_db=80, seed=5)
    X, Y = (np.array(ds.meta["truth"][k]) for k in ("X", "Y"))
    start = reference_truth_calibration("concentric", X, Y)
    with pytest.warns(IdentifiabilityWarning, match="poorly determined|cannot determine"):
        f = fit_reference(ds, start)
    assert f.identifiability["ill_conditioned"]
    assert f.warnings
    # the same poses with rotations are fine
    ds2 = simulate_reference(_exact(), "robot", 120, snr_db=80, seed=5)
    with warnings.catch_warnings():
        warnings.simplefilter("error", IdentifiabilityWarning)
        f2 = fit_reference(ds2, start)
    assert not f2.identifiability["ill_conditioned"]
    assert f2.identifiability["xy_condition"] < f.identifiability["xy_condition"] / 10


def test_bad_input():
    ds = simulate_reference("concentric", "robot", 20, seed=0)
    start = nominal_calibration("concentric")
    with pytest.raises(ValueError, match="held-out fraction"):
        fit_reference(ds, start, holdout=1.0)
    with pytest.raises(ValueError, match="training poses"):
        fit_reference(ds, start, holdout=0.5)
    no_ref = replace(ds, extra={})
    with pytest.raises(ValueError, match="reference poses"):
        fit_reference(no_ref, start)
    B = ds.extra["reference_poses"].copy()
    B[4, :3, :3] *= 1.01  # scaled, not a rotation
    with pytest.raises(ValueError, match="orthonormal rotations.*row 4"):
        fit_reference(replace(ds, extra={**ds.extra, "reference_poses": B}), start)
    B = ds.extra["reference_poses"].copy()
    B[2, 0, 3] = np.nan
    with pytest.raises(ValueError, match="finite couplings and reference poses"):
        fit_reference(replace(ds, extra={**ds.extra, "reference_poses": B}), start)


def _main(argv):
    parser = argparse.ArgumentParser(prog="openemt")
    sub = parser.add_subparsers(dest="command")
    _calibrate.register(sub)
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except (ValueError, OSError) as exc:
        print(f"error: {exc}")
        return 2


def test_calibrate_reference_command(tmp_path, capsys, monkeypatch):
    import openemt._compile_notice as notice

    data = tmp_path / "robot.h5"
    write_dataset(simulate_reference(_exact(), "robot", 150, snr_db=80, seed=2), data)
    out = tmp_path / "cal.json"
    calls = []
    monkeypatch.setattr(notice, "announce_compile",
                        lambda out, what, *, kernels: calls.append((what, tuple(kernels))))
    rc = _main(["calibrate", str(data), "--mode", "reference", "--holdout", "0.2", "--seed",
                "3", "-o", str(out), "--json", "--quiet"])
    assert rc == 0
    # the kernels it runs are compiled under the notice (this mode had none before)
    assert calls == [("solver kernels", notice.SOLVER_KERNELS + notice.COLD_START_KERNELS)]
    monkeypatch.undo()
    s = json.loads(capsys.readouterr().out)
    assert s["mode"] == "reference" and s["num_points"] == 120
    assert s["start"].startswith("nominal model") and s["start_xy"]["method"] == "hand-eye"
    assert np.array(s["X"]).shape == (4, 4) and len(s["Y_se"]) == 6
    assert set(s["holdout"]) >= {"trans_rms_mm", "trans_max_mm", "rot_rms_deg", "n",
                                 "trans_uncert_mm"}
    assert s["holdout"]["n"] == 30 and s["ill_conditioned"] is False
    cal = read_calibration(out)
    assert cal.mode == "reference"
    np.testing.assert_allclose(np.array(cal.extra["reference"]["Y"]), np.array(s["Y"]))
    assert cal.stats["holdout"]["trans_rms_mm"] == pytest.approx(s["holdout"]["trans_rms_mm"])
    # a staged run from the written calibration starts from its X and Y
    rc = _main(["calibrate", str(data), "--mode", "reference", "--from", str(out), "--json",
                "--quiet"])
    assert rc == 0
    assert json.loads(capsys.readouterr().out)["start_xy"]["method"] == "calibration"
    rc = _main(["calibrate", str(data), "--mode", "reference", "--holdout", "2", "--json"])
    assert rc == 2


def test_ilemt_stage_as_reference_matches_rig_chain(ilemt_dir):
    """One fixture combination of the real recording with the stage transform as the
    reference pose: the same accuracy as the rig-chain calibration of the same rows."""
    data = import_ilemt_folder(ilemt_dir)
    start = read_ilemt_calibration(ilemt_dir / "base_calibration.mat")
    # rig chain, home source and home sensor fixture, md rows (shifting F_se along the Rz
    # axis is a gauge with a single fixture combination: Z_only holds z_se_fix)
    rig = fit(data, start, "Z_only").calibration
    ref_rows = stage_reference(data)  # soYoutZup_seYoutZup_md, B = stage transform
    assert len(ref_rows) == rig.stats["num_points"] == 142
    with pytest.warns(IdentifiabilityWarning, match="X translation"):
        free = fit_reference(ref_rows, start)  # the same gauge, detected
    assert free.start["method"] == "translations"
    # the paper's objective (ordinary weighting) is the rig chain's: the same fit
    f = fit_reference(ref_rows, start, freeze=("z_se_fix",), weighting="ordinary")
    assert f.weighting["method"] == "ordinary"
    assert not f.identifiability["undetermined"]
    assert f.rms_residue == pytest.approx(rig.stats["rms_residue"], rel=0.05)
    # held out: the ld rows of the same combination (632), scored against each one's truth
    ld = data.select(data.mask(pattern="ld", source_fixture="YoutZup",
                               sensor_fixture="YoutZup"))
    D = ground_truth_poses(rig.source_fixture, rig.stage_fixture, rig.sensor_fixture,
                           ld.source_fixture, ld.stage, ld.sensor_fixture)
    res = solve_lm(ld.couplings, rig.model, initial="kim18",
                   hemisphere=hemisphere_from_positions(D[:, :3, 3]))
    rig_ld = error_summary(*pose_error_magnitudes(res.poses, D))
    ld_ref = stage_reference(data, pattern="ld")
    ref_ld = score_reference(f.calibration, ld_ref.couplings, ld_ref.extra["reference_poses"])
    assert ref_ld["n"] == rig_ld["n"] == 632
    assert ref_ld["trans_rms_mm"] == pytest.approx(rig_ld["trans_rms_mm"], rel=0.05)
    assert ref_ld["rot_rms_deg"] == pytest.approx(rig_ld["rot_rms_deg"], rel=0.05)
    assert ref_ld["trans_rms_mm"] < 0.35  # 0.304 mm on cal_9_15


def test_ilemt_stage_reference_errors_in_variables(ilemt_dir):
    """The stage states its uncertainty (0.107 mm, 0.17 deg), so the default weighting of the
    stage-as-reference fit is errors-in-variables; on the real recording its ld rows (held
    out, 632) come out better than with the paper's ordinary weighting (0.2794 against
    0.3044 mm on cal_9_15)."""
    data = import_ilemt_folder(ilemt_dir)
    start = read_ilemt_calibration(ilemt_dir / "base_calibration.mat")
    ref_rows = stage_reference(data)
    ld = stage_reference(data, pattern="ld")
    out = {}
    for w in ("ordinary", "auto"):
        f = fit_reference(ref_rows, start, freeze=("z_se_fix",), weighting=w)
        out[f.weighting["method"]] = score_reference(
            f.calibration, ld.couplings, ld.extra["reference_poses"])
    assert set(out) == {"ordinary", "errors-in-variables"}
    assert out["errors-in-variables"]["trans_rms_mm"] < 0.95 * out["ordinary"]["trans_rms_mm"]


def test_weighting_choices_and_refusals():
    """``auto`` picks errors-in-variables only with a stated reference noise; asking for it
    without one, or for an unknown weighting, is one clear error before any fit."""
    from openemt._errors import InputError

    ds = simulate_reference(_exact(), "robot", 40, snr_db=80, seed=5)
    start = nominal_calibration("concentric")
    quiet = replace(ds, meta={**ds.meta, "reference": {**ds.meta["reference"],
                                                       "noise_trans_m": None,
                                                       "noise_rot_rad": None}})
    assert fit_reference(quiet, start, warn=False).weighting["method"] == "ordinary"
    with pytest.raises(InputError, match="states its reference noise"):
        fit_reference(quiet, start, weighting="errors-in-variables")
    with pytest.raises(InputError, match="expected weighting in auto"):
        fit_reference(ds, start, weighting="heavy")
    f = fit_reference(ds, start, warn=False)
    assert f.weighting["method"] == "errors-in-variables"
    assert f.calibration.stats["weighting"]["method"] == "errors-in-variables"
    # the paper's rms_residue is reported whatever the weighting: not the whitened one
    assert f.rms_residue == pytest.approx(f.calibration.stats["rms_residue"])
    assert f.rms_residue < 0.01


def test_weighting_outside_reference_mode_is_refused(tmp_path, capsys):
    from openemt.cli import main

    ds = simulate_reference(_exact(), "robot", 20, snr_db=80, seed=6)
    write_dataset(ds, tmp_path / "r.h5")
    assert main(["calibrate", str(tmp_path / "r.h5"), "--mode", "planar", "--weighting",
                 "ordinary", "-o", str(tmp_path / "c.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["error: expected --weighting with --mode reference only, got --mode planar"]
    assert not (tmp_path / "c.json").exists()
