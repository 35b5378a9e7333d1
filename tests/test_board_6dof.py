"""A planar board read by a 6-DOF sensor of two coils, through the commands every tracker uses
(docs/planar.md#a-6-dof-sensor-on-a-board): simulate a robot collection, calibrate it in
reference mode, solve, report, inspect and track -- no code written for this combination."""

from __future__ import annotations

import json

import numpy as np
import pytest

from openemt.cli import main
from openemt.io import read_calibration, read_dataset
from openemt.live import example_tracker


def _run(argv, capsys):
    rc = main([str(a) for a in argv])
    out = capsys.readouterr()
    return rc, out.out, out.err


@pytest.fixture(scope="module")
def collection(tmp_path_factory):
    d = tmp_path_factory.mktemp("six")
    rc = main(["simulate", "--preset", "anser-6dof", "--reference", "robot", "--n-poses", "80",
               "--seed", "1", "-o", str(d / "b.h5"), "--truth-calibration", str(d / "t.json"),
               "--quiet"])
    assert rc == 0
    return d


def test_simulate_calibrate_solve_report(collection, capsys):
    d = collection
    ds = read_dataset(d / "b.h5")
    assert ds.couplings.shape == (80, 8, 2) and "reference_poses" in ds.extra
    truth = read_calibration(d / "t.json")
    assert truth.kind == "finite" and truth.model.dof == 6

    rc, out, err = _run(["calibrate", d / "b.h5", "--mode", "reference", "--holdout", "0.25",
                         "-o", d / "c.json", "--json"], capsys)
    assert rc == 0, err
    s = json.loads(out)
    h = s["holdout"]
    assert h["n"] == 20 and h["n_not_converged"] == 0
    # the robot's own noise (0.05 mm, 0.02 deg) is the floor: the fit is near it
    assert h["trans_rms_mm"] < 0.15 and h["rot_rms_deg"] < 0.08
    cal = read_calibration(d / "c.json")
    assert cal.mode == "reference" and cal.model.dof == 6 and not s["undetermined"]
    # fitted gains and the second sensor coil's relative gain against the simulation's truth
    np.testing.assert_allclose(cal.model.gains, truth.model.gains, rtol=5e-3)
    assert abs(cal.model.sensor_gains[1] - truth.model.sensor_gains[1]) < 2e-3

    rc, out, err = _run(["solve", d / "b.h5", "--calibration", d / "c.json", "-o", d / "p.h5",
                         "--json"], capsys)
    assert rc == 0, err
    s = json.loads(out)
    assert s["dof"] == 6 and s["status_counts"]["converged"] == 80
    assert s["accuracy"]["position_rms_mm"] < 0.5 and s["accuracy"]["rot_rms_deg"] < 0.2

    rc, out, err = _run(["report", d / "b.h5", "--calibration", d / "c.json", "--reference",
                         "poses", "-o", d / "r.html", "--json"], capsys)
    assert rc == 0, err
    acc = json.loads(out)["accuracy"]["calibration"]
    assert acc["n"] == 80 and acc["n_invalid"] == 0 and acc["trans_rms_mm"] < 0.5
    assert "gains[0]" in (d / "r.html").read_text()

    rc, out, err = _run(["info", d / "c.json", "--json"], capsys)
    assert rc == 0, err
    info = json.loads(out)
    assert info["model_kind"] == "finite" and info["dof"] == 6 and info["n_sensor"] == 2


def test_track_with_the_shipped_6dof_tracker(tmp_path, capsys):
    rc, out, err = _run(["track", "--tracker", example_tracker("anser-6dof"), "--source", "sim",
                         "--duration", "0.4", "--fast", "--no-igtl", "--log", tmp_path / "l.csv",
                         "--json"], capsys)
    assert rc == 0, err
    s = json.loads(out)
    assert s["status_counts"]["converged"] == sum(s["status_counts"].values()) > 500
    assert s["truth"]["position_error_mm_rms"] < 0.05


def test_errors_in_variables_reaches_the_truth(collection):
    """The issue's criterion on the module's collection (80 poses, 20 held out): with the robot's
    noise stated, the default (errors-in-variables) fit's held-out error is within 3 standard
    errors of the truth calibration's on the same poses; the ordinary fit's rotation error is
    not (docs/reference-calibration.md#errors-in-variables; ``openemt bench reference`` at 300
    poses)."""
    from openemt.bench._reference import _held_out_errors, _rms_se
    from openemt.calibrate import fit_reference
    from openemt.simulate import nominal_calibration

    d = collection
    ds = read_dataset(d / "b.h5")
    truth = read_calibration(d / "t.json")
    B = ds.extra["reference_poses"]
    got = {}
    for w in ("auto", "ordinary"):
        f = fit_reference(ds, nominal_calibration("anser-6dof"), holdout=0.25, warn=False,
                          weighting=w)
        got[f.weighting["method"]] = f
    assert np.array_equal(got["ordinary"].test, f.test)
    # the truth calibration on the same held-out poses, scored the same way
    tt, tr = _held_out_errors(truth, ds.couplings[f.test], B[f.test])
    (rt, st), (rr, sr) = _rms_se(tt), _rms_se(tr)
    f = got["errors-in-variables"]
    h = f.holdout
    assert abs(h["trans_rms_mm"] - rt) < 3 * st and abs(h["rot_rms_deg"] - rr) < 3 * sr
    assert got["ordinary"].holdout["rot_rms_deg"] > rr + 3 * sr
    # the fit's own estimate of the reference noise is the stated one (0.05 mm, 0.02 deg)
    w = f.weighting
    assert 0.035e-3 < w["reference_residual_trans_m"] < 0.06e-3
    assert np.deg2rad(0.014) < w["reference_residual_rot_rad"] < np.deg2rad(0.024)


def test_whitening_makes_the_row_covariance_identity(collection):
    from openemt.calibrate import errors_in_variables_whitening, fit_reference
    from openemt.calibrate._reference import reference_noise_covariance
    from openemt.simulate import nominal_calibration

    ds = read_dataset(collection / "b.h5")
    f = fit_reference(ds, nominal_calibration("anser-6dof"), warn=False, weighting="ordinary")
    from openemt.calibrate import CalibrationProblem
    from openemt.solve import spectral_norms

    C = ds.signed_real()
    prob = CalibrationProblem(layout=f.layout, C_meas=C, weight=1 / spectral_norms(C),
                              so_J=np.broadcast_to(np.eye(4), (len(C), 4, 4)).copy(),
                              st_J=ds.extra["reference_poses"], gain=None)
    S = reference_noise_covariance(ds.meta["reference"])
    W, info = errors_in_variables_whitening(prob, f.x, S, n_free=f.free.size)
    _, G = prob.pose_gradient(f.x)
    Sigma = G @ S @ np.swapaxes(G, 1, 2) + info["coupling_noise"] ** 2 * np.eye(16)
    np.testing.assert_allclose(W @ Sigma @ np.swapaxes(W, 1, 2),
                               np.broadcast_to(np.eye(16), Sigma.shape), atol=1e-8)
    # the pose gradient agrees with central differences of the residual in B's tool frame
    from openemt.geometry import pose_from_vector

    h, k = 1e-7, 3
    for j in range(6):
        v = np.zeros(6)
        v[j] = h
        plus = prob.__class__(**{**prob.__dict__, "st_J": prob.st_J @ pose_from_vector(v)})
        minus = prob.__class__(**{**prob.__dict__, "st_J": prob.st_J @ pose_from_vector(-v)})
        num = (plus.residuals(f.x) - minus.residuals(f.x)).reshape(len(C), -1)[k] / (2 * h)
        np.testing.assert_allclose(G[k, :, j], num, rtol=1e-4, atol=1e-6 * np.abs(G[k]).max())


def test_bench_reference_reports_both_weightings(capsys):
    rc, out, err = _run(["bench", "reference", "--cases", "anser-6dof/robot", "--seeds", "2",
                         "--n-poses", "60", "--json"], capsys)
    assert rc == 0, err
    c = json.loads(out)["cases"]["anser-6dof/robot"]
    assert c["stated_noise_mm"] == pytest.approx(0.05) and c["truth_rot_se_deg"] > 0
    for w in ("ordinary", "errors-in-variables"):
        assert len(c[w]["z_rot"]) == 1 and c[w]["fit_s"] > 0
    assert abs(c["errors-in-variables"]["z_rot"][0]) < 3
    rc, out, err = _run(["bench", "reference", "--cases", "anser-6dof", "--json"], capsys)
    assert rc == 2 and "PRESET/REFERENCE" in err
