"""Rz error motions and gain non-linearity of the improved model; the held-out breakdown and
the repeat-pose noise floor (openemt.evaluate)."""

from __future__ import annotations

import numpy as np
import pytest
from _numdiff import central_differences
from test_calibrate import F_SE, F_SO, F_ST, synthetic_dataset, truth_model

from openemt._errors import InputError
from openemt.calibrate import (
    MODES,
    ImprovedProblem,
    ParameterLayout,
    RigOptions,
    fit_improved,
    repeat_pairs,
)
from openemt.calibrate._rig import error_motion_basis, gain_linearise
from openemt.evaluate import error_breakdown, repeat_scatter
from openemt.geometry import SOURCE_FIXTURES, pose_from_vector
from openemt.io import Calibration, Dataset
from openemt.paper import improved_lines as _improved_lines

TERMS_ON = RigOptions(octupole_sensor=True, stage_linear=("xy", "sx_sz"), rz_motion=1,
                      gain_nonlinear=True)



def _pair(fitted):
    """(problem, x) of a fit_improved() result."""
    return fitted.problem, fitted.x

def _cal(rng):
    return Calibration(model=truth_model(rng), source_fixture=F_SO, stage_fixture=F_ST,
                       sensor_fixture=F_SE)


def _with_couplings(ds, C):
    return Dataset(couplings=C, stage=ds.stage, source_fixture=ds.source_fixture,
                   sensor_fixture=ds.sensor_fixture, pattern=ds.pattern,
                   file_index=ds.file_index)


def test_error_motion_basis_vanishes_at_home_and_skips_the_first_harmonic():
    th = np.deg2rad([-90.0, -45.0, 0.0, 45.0, 90.0])
    f = error_motion_basis(th, 2)
    assert f.shape == (5, 4)
    np.testing.assert_allclose(f[2], 0.0, atol=1e-15)
    # second harmonic: sin 2 theta and 1 - cos 2 theta
    np.testing.assert_allclose(f[:, 0], np.sin(2 * th), atol=1e-15)
    np.testing.assert_allclose(f[:, 1], 1 - np.cos(2 * th), atol=1e-15)
    # on five angles the two orders span every function that is zero at theta = 0
    assert np.linalg.matrix_rank(f) == 4


def test_new_terms_jacobian_matches_finite_differences():
    rng = np.random.default_rng(5)
    cal = _cal(rng)
    ds = synthetic_dataset(rng, cal, n_per=3, source_fixtures=SOURCE_FIXTURES[:2])
    ds = _with_couplings(ds, ds.couplings * (1 + 0.1 * rng.normal(size=ds.couplings.shape)))
    lay = ParameterLayout(3, 3)
    pr = ImprovedProblem(ds, lay, cal.model.gain,
                         RigOptions(rz_poly=2, rz_motion=2, gain_nonlinear=True,
                                    coupling_offset=True, induced=True, octupole_sensor=True))
    x = np.zeros(pr.size)
    x[:lay.size] = lay.pack_calibration(cal)
    x[lay.size:] = rng.normal(0, 0.01, pr.size - lay.size)
    x[pr.extra["induced"]] = np.r_[0.5, 0.1, -0.1, rng.normal(0, 0.05, 9)]
    r, J = pr.residuals_and_jacobian(x)
    np.testing.assert_allclose(r, pr.residuals(x), atol=1e-15)
    # the pose and sensor-coil derivatives include the induced field
    P = pr.poses(x)
    h = 1e-7
    Pp, Pm = P.copy(), P.copy()
    Pp[:, 0, 3] += h
    Pm[:, 0, 3] -= h
    model = pr.model(x)
    fd = (model.coupling(Pp) - model.coupling(Pm)) / (2 * h)
    np.testing.assert_allclose(model.jacobians(P, params=False).d_translation[..., 0], fd,
                               rtol=0, atol=1e-6 * np.abs(fd).max())
    blocks = {**pr.extra, "model": lay.slices["model"]}
    for name in ("rz_poly", "rz_tilt", "rz_motion", "gain", "sensor_fix", "offset", "induced",
                 "k_se", "model"):
        cols = range(blocks[name].start, blocks[name].stop)
        Jn = central_differences(pr.residuals, x, columns=cols)
        for j, i in enumerate(cols):
            fd = Jn[:, j]
            np.testing.assert_allclose(J[:, i], fd, rtol=0,
                                       atol=1e-5 * max(np.abs(fd).max(), 1e-12),
                                       err_msg=f"{name} {i}")


def test_new_terms_at_zero_are_the_previous_model():
    rng = np.random.default_rng(6)
    cal = _cal(rng)
    ds = synthetic_dataset(rng, cal, n_per=4)
    lay = ParameterLayout(3, 3)
    old = ImprovedProblem(ds, lay, cal.model.gain, RigOptions())
    new = ImprovedProblem(ds, lay, cal.model.gain, RigOptions(
        rz_motion=2, gain_nonlinear=True, coupling_offset=True, induced=True))
    x_old = np.zeros(old.size)
    x_old[:lay.size] = lay.pack_calibration(cal)
    x_new = np.zeros(new.size)
    x_new[:old.size] = x_old
    x_new[new.extra["induced"].start:new.extra["induced"].start + 3] = [0.5, 0.2, 0.1]
    np.testing.assert_array_equal(new.poses(x_new), old.poses(x_old))
    np.testing.assert_allclose(new.residuals(x_new), old.residuals(x_old), rtol=0, atol=1e-15)


def test_fit_recovers_error_motions_and_gain_nonlinearity():
    """Data from a rig whose Rz axis runs out and wobbles at twice per revolution, read through
    non-linear channels: the fit recovers both (they are identifiable)."""
    rng = np.random.default_rng(7)
    cal = _cal(rng)
    ds = synthetic_dataset(rng, cal, n_per=50)
    lay = ParameterLayout(3, 3)
    pr = ImprovedProblem(ds, lay, cal.model.gain, TERMS_ON)
    e = pr.extra
    x_true = np.zeros(pr.size)
    x_true[:lay.size] = lay.pack_calibration(cal)
    x_true[e["sensor_fix"]] = rng.normal(0, 1e-3, e["sensor_fix"].stop - e["sensor_fix"].start)
    x_true[e["rz_motion"]] = np.r_[2e-4, -1e-4, 5e-5, 1e-3, -5e-4, 2e-4,
                                   -1e-4, 2e-4, 0.0, -5e-4, 3e-4, -1e-3]
    beta = np.array([0.02, -0.03, 0.01]) / np.abs(ds.couplings).max()
    x_true[e["gain"]] = beta
    c = pr.model(x_true).coupling(pr.poses(x_true))
    # the channels read c_read with c_read (1 + beta |c_read|) = c
    read = np.sign(c) * (-1 + np.sqrt(1 + 4 * beta * np.abs(c))) / (2 * beta)
    np.testing.assert_allclose(gain_linearise(read, beta), c, rtol=0, atol=1e-13 * np.abs(c).max())
    data = _with_couplings(ds, read)
    freeze = MODES["XYZ"].freeze + ("z_se_fix",)
    prob, x = _pair(fit_improved(data, cal, TERMS_ON, optimize=MODES["XYZ"].optimize,
                                 freeze=freeze))
    r = prob.residuals(x)
    assert np.sqrt(r @ r / len(data)) < 1e-9
    np.testing.assert_allclose(x[e["rz_motion"]], x_true[e["rz_motion"]], rtol=1e-5,
                               atol=1e-9)
    np.testing.assert_allclose(x[e["gain"]], beta, rtol=1e-5)
    d = prob.rig(x).to_dict()
    assert np.asarray(d["rz_error_motion"]).shape == (2, 6)
    assert len(d["gain_nonlinearity"]) == 3


def test_error_breakdown_groups():
    trans = np.array([1.0, 3.0, 2.0, 4.0, np.nan]) * 1e-4
    rot = np.deg2rad([0.01, 0.03, 0.02, 0.04, 0.05])
    pos = np.array([[0.14, 0, 0], [0.0, 0.175, 0], [0, 0, 0.2], [0.3, 0, 0], [0.26, 0, 0]])
    b = error_breakdown(trans, rot, pos, stage_rz=np.deg2rad([0, 90, 90, -90, 0]),
                        sensor_fixture=["A", "B", "A", "A", "B"])
    assert list(b.by_range) == ["r < 150 mm", "150-200 mm", "200-250 mm", "r >= 250 mm"]
    assert [b.by_range[k]["n"] for k in b.by_range] == [1, 1, 1, 2]   # 200 mm is in 200-250
    assert b.by_range["r >= 250 mm"]["trans_rms_mm"] == pytest.approx(0.4)  # NaN row left out
    assert b.by_rz["90 deg"]["trans_rms_mm"] == pytest.approx(np.sqrt((0.09 + 0.04) / 2))
    assert b.by_rz["90 deg"]["rot_rms_deg"] == pytest.approx(np.sqrt((0.03**2 + 0.02**2) / 2))
    assert list(b.by_rz) == ["-90 deg", "0 deg", "90 deg"]
    assert b.by_sensor_fixture["A"]["n"] == 3
    assert b.overall["n"] == 5
    assert b.overall["trans_rms_mm"] == pytest.approx(np.sqrt(np.mean([0.01, 0.09, 0.04, 0.16])))
    empty = error_breakdown(trans[:1], rot[:1], pos[:1])
    assert empty.by_range["200-250 mm"] == {"n": 0, "trans_rms_mm": None, "rot_rms_deg": None}
    assert [r["group"] for r in b.rows()][:2] == ["all", "range r < 150 mm"]
    with pytest.raises(InputError, match="positions"):
        error_breakdown(trans, rot, pos[:, :2])
    with pytest.raises(InputError, match="stage_rz"):
        error_breakdown(trans, rot, pos, stage_rz=[0.0])


def test_repeat_scatter_is_the_per_measurement_scatter():
    rng = np.random.default_rng(8)
    v = np.c_[rng.uniform(0.15, 0.3, (400, 3)), rng.normal(size=(400, 3))]
    a = pose_from_vector(v)
    assert repeat_scatter(a, a).trans_rms_mm == pytest.approx(0.0, abs=1e-9)
    # two independent measurements with 0.1 mm per-axis noise: 3-D scatter sqrt(3) * 0.1 mm
    noise = 1e-4
    b1, b2 = a.copy(), a.copy()
    b1[:, :3, 3] += rng.normal(0, noise, (400, 3))
    b2[:, :3, 3] += rng.normal(0, noise, (400, 3))
    s = repeat_scatter(b1, b2)
    assert s.n_pairs == 400
    assert s.trans_rms_mm == pytest.approx(np.sqrt(3) * 0.1, rel=0.1)
    with pytest.raises(InputError, match="one shape"):
        repeat_scatter(b1, b2[:3])


def test_repeat_pairs_of_the_bundled_md_and_ld_rows(ilemt_dir):
    from openemt.io import import_ilemt_folder

    ds = import_ilemt_folder(ilemt_dir)
    md = ds.select(ds.mask(pattern="md", source_fixture="YoutZup"))
    ld = ds.select(ds.mask(pattern="ld", source_fixture="YoutZup"))
    i, j = repeat_pairs(md, ld)
    # the 3 x 3 x 3 md grid is part of the 5 x 5 x 5 ld grid, at all 5 angles, per sensor fixture
    assert i.size >= 3 * 5 * 27
    np.testing.assert_array_equal(md.stage_logged[i], ld.stage_logged[j])
    np.testing.assert_array_equal(md.sensor_fixture[i], ld.sensor_fixture[j])
    assert np.all(np.any(md.stage_logged[i] != 0, axis=1))   # no null rows
    assert repeat_pairs(md.select(np.zeros(len(md), bool)), ld)[0].size == 0


def test_improved_human_lines_name_every_term_and_the_floor():
    b = error_breakdown([1e-4], [1e-4], [[0.2, 0, 0]], stage_rz=[0.0],
                        sensor_fixture=["A"]).to_dict()
    out = {"improved_model": {"terms": [{"term": "t1", "reason": "not kept: because"}]},
           "breakdown": {"default": b, "improved_steps": {
               "improved": {"kept": True, "breakdown": b},
               "improved+t1": {"kept": False, "breakdown": b}}},
           "noise_floor": {"n_pairs": 3, "trans_rms_mm": 0.0145, "rot_rms_deg": 0.0038}}
    text = "\n".join(_improved_lines(out))
    assert "t1: not kept: because" in text
    assert "improved+t1 (not kept)" in text
    assert "range 200-250 mm" in text and "Rz 0 deg" in text and "sensor fixture A" in text
    assert "0.015 mm" in text


def test_fit_recovers_an_induced_dipole():
    """Data of a rig with a magnetic object 0.6 m from the source (a moment per carrier): the
    fit finds it from a start 6 cm away (the position search is local), and the paper's model
    cannot fit the data."""
    rng = np.random.default_rng(9)
    cal = _cal(rng)
    ds = synthetic_dataset(rng, cal, n_per=50)
    lay = ParameterLayout(3, 3)
    opts = RigOptions(induced=True, induced_start=(0.65, 0.13, -0.02))
    pr = ImprovedProblem(ds, lay, cal.model.gain, opts)
    e = pr.extra
    x_true = np.zeros(pr.size)
    x_true[:lay.size] = lay.pack_calibration(cal)
    x_true[e["induced"]] = np.r_[0.6, 0.1, -0.05, rng.normal(0, 0.05, 9)]
    data = _with_couplings(ds, pr.model(x_true).coupling(pr.poses(x_true)))
    freeze = MODES["XYZ"].freeze + ("z_se_fix",)
    prob, x = _pair(fit_improved(data, cal, opts, optimize=MODES["XYZ"].optimize, freeze=freeze))
    r = prob.residuals(x)
    assert np.sqrt(r @ r / len(data)) < 1e-9
    np.testing.assert_allclose(x[e["induced"]], x_true[e["induced"]], rtol=1e-5, atol=1e-8)
    d = prob.rig(x).to_dict()["induced_dipole"]
    np.testing.assert_allclose(d["position"], [0.6, 0.1, -0.05], atol=1e-8)
    paper = RigOptions(sensor_code_fix=False, rz_poly=0, rz_tilt=False, octupole_source=False)
    p0, x0 = _pair(fit_improved(data, cal, paper, optimize=MODES["XYZ"].optimize,
                                freeze=MODES["XYZ"].freeze))
    r0 = p0.residuals(x0)
    assert np.sqrt(r0 @ r0 / len(data)) > 1e-4
