"""Calibration on synthetic data: layout, analytic Jacobian, fit, modes, identifiability."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from _numdiff import central_differences

from openemt.calibrate import (
    MODES,
    IdentifiabilityWarning,
    ParameterLayout,
    build_problem,
    fit,
    get_mode,
    residue_stats,
)
from openemt.field import DipoleModel
from openemt.geometry import SENSOR_FIXTURES, SOURCE_FIXTURES, ground_truth_poses
from openemt.io import Calibration, Dataset

F_SO = np.array([0.001, -0.0003, -0.009, 0.035, 0.041, -1.570])
F_ST = np.array([0.0126, 0.2424, 0.0086, -0.015, 0.0011, 0.0128])
F_SE = np.array([-0.0003, 0.00026, -0.0003, -2.2078, -2.2263, -0.0032])


def truth_model(rng, n_so=3, n_se=3):
    L_so = rng.normal(0, 0.002, (3, n_so))
    M_so = np.eye(3, n_so) * 0.9 + rng.normal(0, 0.02, (3, n_so))
    L_se = rng.normal(0, 0.0003, (3, n_se))
    M_se = np.eye(3, n_se) * 0.4 + rng.normal(0, 0.005, (3, n_se))
    if n_so == 3:
        L_so[:, 2] = 0
        M_so[:, 2] = [0, 0, 1.0]
        M_so[1, 0] = 0.0
    if n_se == 3:
        L_se[:, 2] = 0
        M_se[:2, 2] = 0
        M_se[1, 0] = 0.0
    return DipoleModel(L_so, M_so, L_se, M_se)


def synthetic_dataset(rng, cal, n_per=40, source_fixtures=SOURCE_FIXTURES[:1],
                      sensor_fixtures=SENSOR_FIXTURES, noise=0.0, pattern="md"):
    so, se, stage = [], [], []
    for a in source_fixtures:
        for b in sensor_fixtures:
            s = np.zeros((n_per, 6))
            s[:, :3] = rng.uniform(-0.05, 0.05, (n_per, 3))
            s[:, 5] = rng.choice(np.deg2rad([-90, -45, 0, 45, 90]), n_per)
            stage.append(s)
            so += [a] * n_per
            se += [b] * n_per
    stage = np.concatenate(stage)
    P = ground_truth_poses(cal.source_fixture, cal.stage_fixture, cal.sensor_fixture, so, stage,
                           se)
    C = cal.model.coupling(P)
    C = C + noise * np.linalg.norm(C, ord=2, axis=(1, 2))[:, None, None] * rng.normal(
        size=C.shape)
    return Dataset(couplings=C, stage=stage, source_fixture=so, sensor_fixture=se,
                   pattern=pattern, file_index=np.full(len(so), -1), poses=P)


def perturbed(cal, rng, scale=1.0):
    m = cal.model
    model = m.replace(L_so=m.L_so + scale * rng.normal(0, 5e-4, m.L_so.shape),
                      M_so=m.M_so * (1 + scale * rng.normal(0, 0.01, m.M_so.shape)),
                      L_se=m.L_se + scale * rng.normal(0, 2e-4, m.L_se.shape),
                      M_se=m.M_se * (1 + scale * rng.normal(0, 0.01, m.M_se.shape)))
    def d(v):
        return v + scale * np.r_[rng.normal(0, 1e-3, 3), rng.normal(0, 0.01, 3)]

    return cal.replace(model=model, source_fixture=d(cal.source_fixture),
                       stage_fixture=d(cal.stage_fixture), sensor_fixture=d(cal.sensor_fixture))


@pytest.fixture
def truth():
    rng = np.random.default_rng(1)
    return Calibration(model=truth_model(rng), source_fixture=F_SO, stage_fixture=F_ST,
                       sensor_fixture=F_SE, mode="truth")


# -- layout ----------------------------------------------------------------------------------

@pytest.mark.parametrize("mode, n_free", [("XYZ", 35), ("concentric", 23), ("XYZ_all", 41),
                                          ("XYZ_all_concentric", 29), ("so_fixture_all", 12),
                                          ("trans_only", 29)])
def test_free_parameter_counts_match_ilemt(mode, n_free):
    lay = ParameterLayout(3, 3)
    m = get_mode(mode)
    opt = [g for g in m.optimize if not (m.concentric and g in ("d_so_pos", "d_se_pos"))]
    assert lay.free_indices(opt, m.freeze).size == n_free


def test_layout_pack_roundtrip_and_gauge(truth):
    lay = ParameterLayout(3, 3)
    x = lay.pack_calibration(truth)
    assert x.shape == (lay.size,) == (54,)
    arrs = lay.coil_arrays(x)
    for k in ("L_so", "M_so", "L_se", "M_se"):
        np.testing.assert_array_equal(arrs[k], getattr(truth.model, k))
    for got, want in zip(lay.fixtures(x), (F_SO, F_ST, F_SE)):
        np.testing.assert_array_equal(got, want)
    labels = {lay.label(i) for i in lay.gauge}
    assert labels == {"L_so[0, 2]", "L_so[1, 2]", "L_so[2, 2]", "M_so[0, 2]", "M_so[1, 2]",
                      "L_se[0, 2]", "L_se[1, 2]", "L_se[2, 2]", "M_se[0, 2]", "M_se[1, 2]"}
    assert [lay.label(i) for i in lay.groups["d_so_y_co"]] == ["M_so[1, 0]"]
    assert [lay.label(i) for i in lay.groups["d_se_z_gain"]] == ["M_se[2, 2]"]
    assert [lay.label(i) for i in lay.groups["x_st_fix"]] == ["F_st[0]"]


@pytest.mark.parametrize("n_so, n_se", [(1, 1), (8, 1), (3, 2), (5, 3)])
def test_layout_other_coil_counts(n_so, n_se):
    lay = ParameterLayout(n_so, n_se)
    assert lay.size == 6 * (n_so + n_se) + 18
    free = lay.free_indices(MODES["XYZ"].optimize, MODES["XYZ"].freeze)
    # reference coils: position and transverse moment held; source gain held; y_co held
    expect = (3 * (n_so - 1) + 3 * (n_so - 1) - (n_so > 1)
              + 3 * (n_se - 1) + 3 * (n_se - 1) + 1 - (n_se > 1) + 12)
    assert free.size == expect
    assert not np.intersect1d(free, lay.gauge).size


def test_layout_rejects_bad_input():
    with pytest.raises(ValueError, match="positive integer"):
        ParameterLayout(0, 3)
    with pytest.raises(ValueError, match="group names"):
        ParameterLayout(3, 3).free_indices(["d_so_pos", "nonsense"])
    with pytest.raises(ValueError, match="calibration mode"):
        get_mode("XYZZY")


# -- objective and Jacobian ------------------------------------------------------------------

@pytest.mark.parametrize("n_so, n_se", [(3, 3), (4, 1)])
def test_analytic_jacobian_matches_finite_differences(n_so, n_se):
    rng = np.random.default_rng(7)
    cal = Calibration(model=truth_model(rng, n_so, n_se), source_fixture=F_SO,
                      stage_fixture=F_ST, sensor_fixture=F_SE)
    ds = synthetic_dataset(rng, cal, n_per=4, source_fixtures=SOURCE_FIXTURES)
    # measured values away from the prediction, so residuals are not zero
    ds = Dataset(couplings=ds.couplings * (1 + 0.1 * rng.normal(size=ds.couplings.shape)),
                 stage=ds.stage, source_fixture=ds.source_fixture,
                 sensor_fixture=ds.sensor_fixture, pattern=ds.pattern, file_index=ds.file_index)
    lay = ParameterLayout(n_so, n_se)
    prob = build_problem(ds, lay, cal.model.gain)
    x = lay.pack_calibration(cal)
    r, J = prob.residuals_and_jacobian(x)
    np.testing.assert_allclose(r, prob.residuals(x), rtol=0, atol=1e-15)
    Jn = central_differences(prob.residuals, x)
    for name, s in lay.slices.items():
        scale = np.abs(Jn[:, s]).max()
        np.testing.assert_allclose(J[:, s], Jn[:, s], rtol=0, atol=1e-6 * scale, err_msg=name)


def test_residual_uses_spectral_norm(truth):
    rng = np.random.default_rng(3)
    ds = synthetic_dataset(rng, truth, n_per=5)
    lay = ParameterLayout(3, 3)
    prob = build_problem(ds, lay, truth.model.gain)
    x = lay.pack_calibration(truth)
    x[lay.groups["x_st_fix"]] += 1e-3
    r = prob.residuals(x).reshape(-1, 3, 3)
    raw = ds.couplings - prob.predict(x)
    s = np.linalg.svd(ds.couplings, compute_uv=False)[:, 0]
    np.testing.assert_allclose(r, raw / s[:, None, None], rtol=1e-12)


# -- fitting ---------------------------------------------------------------------------------

def test_fit_recovers_noise_free_truth(truth):
    rng = np.random.default_rng(11)
    ds = synthetic_dataset(rng, truth, n_per=40)
    start = perturbed(truth, rng)
    # the truth's held groups (gauge, source gain, y components) are the start's
    x_true = ParameterLayout(3, 3).pack_calibration(truth)
    lay = ParameterLayout(3, 3)
    xs = lay.pack_calibration(start)
    held = np.setdiff1d(np.arange(lay.size), lay.free_indices(MODES["XYZ"].optimize,
                                                               MODES["XYZ"].freeze))
    xs[held] = x_true[held]
    F = lay.fixtures(xs)
    start = Calibration(model=lay.model(xs, truth.model.gain), source_fixture=F[0],
                        stage_fixture=F[1], sensor_fixture=F[2])
    # F_so and F_st only enter as a product with one source fixture: hold F_so at truth
    res = fit(ds, start, "XYZ")
    assert res.calibration.stats["rms_residue"] < 1e-10
    np.testing.assert_allclose(res.x, x_true, rtol=0, atol=1e-9)
    assert res.identifiability.rank == 35 and not res.identifiability.undetermined
    assert res.calibration.mode == "XYZ"
    assert "d_so_z_gain" in res.calibration.frozen
    assert res.calibration.stats["num_points"] == len(ds)


def test_fit_with_noise_within_three_standard_errors(truth):
    rng = np.random.default_rng(5)
    ds = synthetic_dataset(rng, truth, n_per=60, source_fixtures=SOURCE_FIXTURES, noise=2e-4)
    start = perturbed(truth, rng, 0.5)
    lay = ParameterLayout(3, 3)
    x_true = lay.pack_calibration(truth)
    free = lay.free_indices(MODES["XYZ_all"].optimize, MODES["XYZ_all"].freeze)
    xs = lay.pack_calibration(start)
    held = np.setdiff1d(np.arange(lay.size), free)
    xs[held] = x_true[held]
    F = lay.fixtures(xs)
    start = Calibration(model=lay.model(xs, truth.model.gain), source_fixture=F[0],
                        stage_fixture=F[1], sensor_fixture=F[2])
    res = fit(ds, start, "XYZ_all")
    se = res.identifiability.standard_errors
    z = (res.x[free] - x_true[free]) / se
    assert np.all(np.isfinite(se)) and np.all(se > 0)
    assert np.max(np.abs(z)) < 4.0  # 41 parameters: allow the largest of them a little slack
    assert np.mean(np.abs(z) < 3.0) > 0.95
    # the rms residue estimates the noise level: 9 entries per row
    assert res.calibration.stats["rms_residue"] == pytest.approx(2e-4 * 3, rel=0.1)
    # standard errors land in the calibration in the shapes of the values
    assert res.calibration.standard_errors["L_so"].shape == (3, 3)
    assert res.calibration.standard_errors["L_so"][0, 2] == 0.0  # gauge: held


def test_undetermined_groups_warn():
    rng = np.random.default_rng(2)
    truth = Calibration(model=truth_model(rng), source_fixture=F_SO, stage_fixture=F_ST,
                        sensor_fixture=F_SE)
    ds = synthetic_dataset(rng, truth, n_per=20)  # home source fixture only
    with pytest.warns(IdentifiabilityWarning, match="so_fix.*st_fix"):
        res = fit(ds, perturbed(truth, rng, 0.2), "XYZ", optimize=("so_fix",)
                  + MODES["XYZ"].optimize)
    ident = res.identifiability
    assert ident.rank == ident.n_free - 6
    assert set(ident.undetermined) == {"so_fix", "st_fix"}
    assert np.isinf(res.calibration.standard_errors["source_fixture"]).all()
    # the coil groups stay determined
    assert np.isfinite(res.calibration.standard_errors["M_se"]).all()


def test_concentric_mode_zeroes_positions(truth):
    rng = np.random.default_rng(4)
    ds = synthetic_dataset(rng, truth, n_per=20)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        cal = fit(ds, truth, "concentric").calibration
    assert cal.model.is_concentric
    assert cal.stats["rms_residue"] > 0


def test_mode_row_selection_and_errors(truth):
    rng = np.random.default_rng(6)
    ds = synthetic_dataset(rng, truth, n_per=6, source_fixtures=SOURCE_FIXTURES)
    full = residue_stats(ds, truth, "XYZ_all")
    home = residue_stats(ds, truth, "XYZ")
    assert full.num_points == 4 * 3 * 6 and home.num_points == 3 * 6
    assert full.rms_residue < 1e-12
    with pytest.raises(ValueError, match="expected rows for mode 'trans_only'"):
        fit(ds, truth, "trans_only")
    with pytest.raises(TypeError, match="Dataset"):
        fit(ds.couplings, truth)
    with pytest.raises(ValueError, match="free parameter"):
        fit(ds, truth, "XYZ", optimize=("d_so_y_co",))


def test_problem_kinematics_match_ground_truth(truth):
    rng = np.random.default_rng(8)
    ds = synthetic_dataset(rng, truth, n_per=3, source_fixtures=SOURCE_FIXTURES)
    lay = ParameterLayout(3, 3)
    prob = build_problem(ds, lay, truth.model.gain)
    P = prob.poses(lay.pack_calibration(truth))[0]
    np.testing.assert_allclose(P, ds.poses, rtol=0, atol=1e-14)
