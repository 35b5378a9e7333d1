"""Octupole (finite-coil) terms and the improved rig model: Jacobians, physics, recovery."""

from __future__ import annotations

import numpy as np
import pytest
from _numdiff import central_differences
from test_calibrate import F_SE, F_SO, F_ST, synthetic_dataset, truth_model

from openemt.calibrate import MODES, ImprovedProblem, ParameterLayout, RigOptions, fit_improved
from openemt.field import DipoleModel, FiniteCoilModel, OctupoleModel, circular_coil
from openemt.geometry import SOURCE_FIXTURES, pose_from_vector, vector_from_pose
from openemt.io import Calibration, Dataset
from openemt.solve import refine_poses

FULL = RigOptions(source_code_fix=True, rz_poly=2, octupole_sensor=True,
                  stage_linear=("xy", "rz", "sx_sz", "sy_sz"))



def _pair(fitted):
    """(problem, x) of a fit_improved() result."""
    return fitted.problem, fitted.x

def _random_octupole_model(rng):
    dm = DipoleModel(rng.normal(0, 0.003, (3, 3)), np.eye(3) + rng.normal(0, 0.05, (3, 3)),
                     rng.normal(0, 0.001, (3, 3)), 0.4 * np.eye(3) + rng.normal(0, 0.01, (3, 3)))
    return OctupoleModel(dm, rng.normal(0, 3e-4, 3), rng.normal(0, 3e-5, 3))


def test_octupole_jacobians_match_finite_differences():
    rng = np.random.default_rng(0)
    om = _random_octupole_model(rng)
    v = np.c_[rng.normal(0, 0.05, (6, 3)) + [0.2, 0, 0], rng.normal(size=(6, 3))]
    P = pose_from_vector(v)
    jac, dks, dke = om.split_jacobians(P)
    np.testing.assert_allclose(jac.C, om.coupling(P), rtol=1e-13)
    h = 1e-7
    for a in range(3):
        Pp, Pm = P.copy(), P.copy()
        Pp[:, a, 3] += h
        Pm[:, a, 3] -= h
        fd = (om.coupling(Pp) - om.coupling(Pm)) / (2 * h)
        np.testing.assert_allclose(jac.d_translation[..., a], fd, rtol=0,
                                   atol=1e-7 * np.abs(fd).max())
    for name in ("L_so", "M_so", "L_se", "M_se"):
        arr = getattr(om.dipole, name)
        got = getattr(jac, f"d_{name}")
        for i in range(3):
            for a in range(3):
                ap, am = arr.copy(), arr.copy()
                ap[a, i] += h
                am[a, i] -= h
                cp = OctupoleModel(om.dipole.replace(**{name: ap}), om.k_so, om.k_se).coupling(P)
                cm = OctupoleModel(om.dipole.replace(**{name: am}), om.k_so, om.k_se).coupling(P)
                fd = (cp - cm) / (2 * h)
                g = got[:, i, :, a] if name.endswith("so") else got[:, :, i, a]
                f = fd[:, i, :] if name.endswith("so") else fd[:, :, i]
                np.testing.assert_allclose(g, f, rtol=0, atol=1e-6 * np.abs(got).max(),
                                           err_msg=name)
    # strengths enter linearly; d_k is the unit-strength coupling of the coil concerned
    k = om.k_so.copy()
    k[1] += 1e-4
    diff = (OctupoleModel(om.dipole, k, om.k_se).coupling(P) - om.coupling(P)) / 1e-4
    np.testing.assert_allclose(diff[:, 1, :], dks[:, 1, :], rtol=1e-8)
    np.testing.assert_allclose(diff[:, [0, 2], :], 0.0, atol=1e-15)
    k = om.k_se.copy()
    k[2] += 1e-5
    diff = (OctupoleModel(om.dipole, om.k_so, k).coupling(P) - om.coupling(P)) / 1e-5
    np.testing.assert_allclose(diff[:, :, 2], dke[:, :, 2], rtol=1e-8)


def test_octupole_matches_a_finite_loop():
    """A thin circular loop of radius a: dipole + octupole (kappa = -3/4 a^2) leaves an
    error of order (a/r)^4, far below the dipole model's (a/r)^2."""
    a = 0.02
    src = [circular_coil(np.zeros(3), ax, radius=a) for ax in np.eye(3)]
    sen = [circular_coil(np.zeros(3), ax, radius=1e-4) for ax in np.eye(3)]
    fin = FiniteCoilModel(src, sen)
    dip = fin.dipole_equivalent()
    oct_ = OctupoleModel(dip, np.full(3, -0.75 * a * a), np.zeros(3))
    rng = np.random.default_rng(3)
    for r in (0.1, 0.15):  # r / a = 5 and 7.5
        u = rng.normal(size=(50, 3))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        P = pose_from_vector(np.c_[r * u, rng.normal(size=(50, 3))])
        C = fin.coupling(P)
        scale = np.abs(C).max()
        e_dip = np.abs(dip.coupling(P) - C).max() / scale
        e_oct = np.abs(oct_.coupling(P) - C).max() / scale
        assert e_dip > 1e-3 * (0.1 / r) ** 2
        assert e_oct < 0.2 * e_dip * (0.1 / r) ** 2


def test_improved_problem_jacobian_matches_finite_differences():
    rng = np.random.default_rng(0)
    cal = Calibration(model=truth_model(rng), source_fixture=F_SO, stage_fixture=F_ST,
                      sensor_fixture=F_SE)
    ds = synthetic_dataset(rng, cal, n_per=3, source_fixtures=SOURCE_FIXTURES)
    ds = Dataset(couplings=ds.couplings * (1 + 0.1 * rng.normal(size=ds.couplings.shape)),
                 stage=ds.stage, source_fixture=ds.source_fixture,
                 sensor_fixture=ds.sensor_fixture, pattern=ds.pattern, file_index=ds.file_index)
    lay = ParameterLayout(3, 3)
    pr = ImprovedProblem(ds, lay, cal.model.gain, FULL)
    x = np.zeros(pr.size)
    x[:lay.size] = lay.pack_calibration(cal)
    x[lay.size:] = rng.normal(0, 0.01, pr.size - lay.size)
    x[pr.extra["k_so"]] = rng.normal(0, 3e-4, 3)
    x[pr.extra["k_se"]] = rng.normal(0, 3e-5, 3)
    r, J = pr.residuals_and_jacobian(x)
    np.testing.assert_allclose(r, pr.residuals(x), atol=1e-15)
    Jn = central_differences(pr.residuals, x)
    for i in range(pr.size):
        fd = Jn[:, i]
        np.testing.assert_allclose(J[:, i], fd, rtol=0, atol=1e-5 * max(np.abs(fd).max(), 1e-12),
                                   err_msg=str(i))


def test_improved_rig_model_zero_is_the_paper_model():
    rng = np.random.default_rng(1)
    cal = Calibration(model=truth_model(rng), source_fixture=F_SO, stage_fixture=F_ST,
                      sensor_fixture=F_SE)
    ds = synthetic_dataset(rng, cal, n_per=4, source_fixtures=SOURCE_FIXTURES)
    lay = ParameterLayout(3, 3)
    pr = ImprovedProblem(ds, lay, cal.model.gain, FULL)
    x = np.zeros(pr.size)
    x[:lay.size] = lay.pack_calibration(cal)
    np.testing.assert_allclose(pr.poses(x), ds.poses, atol=1e-14)
    np.testing.assert_allclose(pr.residuals(x), 0.0, atol=1e-12)


def test_improved_fit_recovers_rig_errors_and_octupoles():
    """Data made by a rig with fixture-code, Rz and stage errors and finite coils: the improved
    fit recovers them, the paper's model cannot."""
    rng = np.random.default_rng(2)
    cal = Calibration(model=truth_model(rng), source_fixture=F_SO, stage_fixture=F_ST,
                      sensor_fixture=F_SE)
    opts = RigOptions(octupole_sensor=True, stage_linear=("xy", "sx_sz"))
    ds = synthetic_dataset(rng, cal, n_per=50)
    lay = ParameterLayout(3, 3)
    pr = ImprovedProblem(ds, lay, cal.model.gain, opts)
    x_true = np.zeros(pr.size)
    x_true[:lay.size] = lay.pack_calibration(cal)
    e = pr.extra
    x_true[e["sensor_fix"]] = np.r_[1e-4, -2e-4, 1e-4, 0.01, -0.012, 0.004,
                                    -1e-4, 5e-5, 2e-4, -0.008, 0.006, 0.003]
    x_true[e["rz_poly"]] = [2e-3]
    x_true[e["rz_tilt"]] = [1e-3, -2e-3]
    x_true[e["k_so"]] = [-4e-4, -5e-4, -3e-4]
    x_true[e["k_se"]] = [-2e-5, -1e-5, -3e-5]
    x_true[e["stage_linear"]] = [5e-4, 2e-3]
    C = pr.model(x_true).coupling(pr.poses(x_true))
    data = Dataset(couplings=C, stage=ds.stage, source_fixture=ds.source_fixture,
                   sensor_fixture=ds.sensor_fixture, pattern=ds.pattern,
                   file_index=ds.file_index)
    freeze = MODES["XYZ"].freeze + ("z_se_fix",)
    prob, x = _pair(fit_improved(data, cal, opts, optimize=MODES["XYZ"].optimize,
                                      freeze=freeze))
    r = prob.residuals(x)
    assert np.sqrt(r @ r / len(data)) < 1e-9
    for name in ("sensor_fix", "rz_poly", "rz_tilt", "k_so", "k_se", "stage_linear"):
        np.testing.assert_allclose(x[e[name]], x_true[e[name]], rtol=1e-5, atol=1e-9,
                                   err_msg=name)
    # the paper's model on the same data leaves a large residue
    paper = RigOptions(sensor_code_fix=False, rz_poly=0, rz_tilt=False, octupole_source=False)
    p0, x0 = _pair(fit_improved(data, cal, paper, optimize=MODES["XYZ"].optimize,
                                freeze=MODES["XYZ"].freeze))
    r0 = p0.residuals(x0)
    assert np.sqrt(r0 @ r0 / len(data)) > 1e-4


def test_refine_poses_with_octupoles():
    rng = np.random.default_rng(4)
    om = _random_octupole_model(rng)
    v = np.c_[rng.normal(0, 0.04, (30, 3)) + [0.2, 0.02, 0.0], rng.normal(0, 1.0, (30, 3))]
    v = vector_from_pose(pose_from_vector(v))
    C = om.coupling(pose_from_vector(v))
    start = v + np.c_[rng.normal(0, 1e-3, (30, 3)), rng.normal(0, 5e-3, (30, 3))]
    got, res = refine_poses(om, C, start)
    np.testing.assert_allclose(got[:, :3], v[:, :3], atol=1e-10)
    E = np.linalg.inv(pose_from_vector(got)) @ pose_from_vector(v)
    assert np.abs(vector_from_pose(E)[:, 3:]).max() < 1e-9
    assert res.max() < 1e-20
    with pytest.raises(ValueError, match="k_so"):
        OctupoleModel(om.dipole, np.zeros(2), np.zeros(3))
