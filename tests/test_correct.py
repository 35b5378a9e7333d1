"""Output corrections on pose pairs: recovery of known distortions, held-out errors, JSON."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from openemt.correct import (
    Correction,
    evaluate_correction,
    fit_correction,
    fit_grid,
    fit_polynomial,
    fit_rbf,
    kfold_splits,
    monomial_exponents,
    read_correction,
    write_correction,
)
from openemt.geometry import pose_from_rt


def _workspace(rng, n):
    p = rng.uniform([0.05, -0.15, -0.15], [0.35, 0.15, 0.15], (n, 3))
    R = Rotation.random(n, random_state=int(rng.integers(1 << 31))).as_matrix()
    return pose_from_rt(R, p)


def _poly_distortion(P):
    """A cubic position distortion (mm scale) and a quadratic rotation distortion (~0.5 deg)."""
    p, R = P[:, :3, 3], P[:, :3, :3]
    q = (p - [0.2, 0.0, 0.0]) / 0.15
    dp = 1e-3 * np.stack([1.5 * q[:, 0] ** 2 - 0.8 * q[:, 1] * q[:, 2] + 0.5 * q[:, 0] ** 3,
                          0.7 * q[:, 0] * q[:, 1] + 0.4 * q[:, 2],
                          -0.9 * q[:, 2] * q[:, 0] + 0.6 * q[:, 1] ** 2], axis=1)
    rho = np.deg2rad(0.5) * np.stack([q[:, 1] * q[:, 0], 0.6 * q[:, 2] ** 2 - 0.3,
                                      0.8 * q[:, 0] * q[:, 2] + 0.2 * q[:, 1]], axis=1)
    return pose_from_rt(Rotation.from_rotvec(rho).as_matrix() @ R, p + dp)


def _pos_rot_err(A, B):
    t = np.linalg.norm(A[:, :3, 3] - B[:, :3, 3], axis=1)
    E = np.swapaxes(A[:, :3, :3], 1, 2) @ B[:, :3, :3]
    r = np.linalg.norm(Rotation.from_matrix(E).as_rotvec(), axis=1)
    return t, r


def test_monomial_counts():
    assert [len(monomial_exponents(r)) for r in range(1, 6)] == [4, 10, 20, 35, 56]
    e = monomial_exponents(3)
    assert len({tuple(x) for x in e}) == len(e)
    assert e.sum(axis=1).max() == 3


def test_kfold_partitions_and_groups():
    splits = kfold_splits(23, 5, seed=3)
    test = np.sort(np.concatenate([t for _, t in splits]))
    np.testing.assert_array_equal(test, np.arange(23))
    for tr, te in splits:
        assert not set(tr) & set(te)
    g = np.repeat(["a", "b", "c"], [4, 5, 6])
    gs = kfold_splits(15, groups=g)
    assert [len(te) for _, te in gs] == [4, 5, 6]
    with pytest.raises(ValueError):
        kfold_splits(3, 5)


def test_polynomial_recovers_polynomial_distortion_exactly():
    rng = np.random.default_rng(10)
    ref = _workspace(rng, 150)
    meas = _poly_distortion(ref)
    # the inverse of a polynomial distortion is not a polynomial, but the distortion is small:
    # order 5 leaves only a tiny remainder; the CV must pick a high order, not 1
    c = fit_correction(meas, ref, "poly", k=5, seed=0)
    t, r = _pos_rot_err(c.apply(meas), ref)
    assert c.params["pos_order"] >= 3
    assert c.params["rot_order"] >= 2
    assert np.sqrt(np.mean(t ** 2)) < 2e-6          # from ~1 mm
    assert np.sqrt(np.mean(r ** 2)) < np.deg2rad(2e-4)  # from ~0.3 deg
    s = c.stats
    assert s["in_sample"]["uncorrected"]["trans_rms_mm"] > 0.5
    assert s["held_out"]["corrected"]["trans_rms_mm"] < 0.01
    assert s["held_out"]["scheme"] == "5-fold by location"
    # held-out never better than in-sample by more than rounding (same model family)
    assert s["held_out"]["corrected"]["trans_rms_mm"] >= s["in_sample"]["corrected"]["trans_rms_mm"] * 0.999


def test_polynomial_order_selection_prefers_true_order_with_noise():
    rng = np.random.default_rng(11)
    ref = _workspace(rng, 300)
    p = ref[:, :3, 3]
    q = (p - [0.2, 0, 0]) / 0.15
    off = 1e-3 * np.stack([q[:, 0] ** 2, q[:, 1] * q[:, 2], -q[:, 2] ** 2], axis=1)
    m = p - off + 2e-5 * rng.standard_normal(p.shape)
    fit = fit_polynomial(m, p, k=5, seed=1)
    sel = fit.selection["position"]
    assert fit.pos_order == 2 or sel[fit.pos_order]["held_out_rms"] <= sel[2]["held_out_rms"]
    assert sel[1]["held_out_rms"] > 10 * sel[2]["held_out_rms"]
    # overfitting is visible: in-sample error falls with order while held-out does not
    assert sel[5]["in_sample_rms"] < sel[2]["in_sample_rms"]
    assert sel[5]["held_out_rms"] > sel[5]["in_sample_rms"]


@pytest.mark.parametrize("method", ["grid", "rbf"])
def test_lookup_tables_reproduce_affine_offsets(method):
    """Trilinear tables and TPS (with linear term) reproduce affine offset fields exactly."""
    rng = np.random.default_rng(12)
    ref = _workspace(rng, 120)
    A = np.eye(3) + 0.01 * rng.standard_normal((3, 3))
    b = np.array([1e-3, -2e-3, 0.5e-3])
    m = ref[:, :3, 3] @ A.T + b
    rho = (ref[:, :3, 3] - 0.2) @ (0.02 * rng.standard_normal((3, 3))).T  # small linear field
    Rm = Rotation.from_rotvec(-rho).as_matrix() @ ref[:, :3, :3]
    meas = pose_from_rt(Rm, m)
    fit = fit_grid if method == "grid" else fit_rbf
    model = fit(m, ref[:, :3, 3], Rm, ref[:, :3, :3], smoothing=1e-6 if method == "grid" else 0)
    xyz, _ = model.predict(m, Rm)
    # grid: the offset is affine in the *measured* position, exactly representable
    np.testing.assert_allclose(xyz, ref[:, :3, 3], atol=1e-9)
    c = fit_correction(meas, ref, method, cross_validate=False)
    t, r = _pos_rot_err(c.apply(meas), ref)
    assert np.max(t) < 1e-5
    assert np.max(r) < 1e-4  # rotation offsets are only approximately linear in m


@pytest.mark.parametrize("method", ["dlt", "poly", "grid", "rbf"])
def test_every_method_beats_uncorrected_held_out_and_round_trips(method, tmp_path):
    rng = np.random.default_rng(13)
    ref = _workspace(rng, 160)
    meas = _poly_distortion(ref)
    P = meas.copy()
    P[:, :3, 3] += 5e-5 * rng.standard_normal((len(P), 3))
    c = fit_correction(P, ref, method, k=4, seed=2)
    ho, ins = c.stats["held_out"]["corrected"], c.stats["in_sample"]["corrected"]
    unc = c.stats["in_sample"]["uncorrected"]
    assert ho["trans_rms_mm"] < unc["trans_rms_mm"]
    if method != "dlt":
        assert ho["rot_rms_deg"] < 0.5 * unc["rot_rms_deg"]
        assert c.corrects_orientation
    else:
        assert ho["rot_rms_deg"] == pytest.approx(unc["rot_rms_deg"], rel=1e-12)
    assert ho["trans_rms_mm"] >= 0.95 * ins["trans_rms_mm"]
    path = tmp_path / "corr.json"
    write_correction(c, path)
    c2 = read_correction(path)
    assert isinstance(c2, Correction) and c2.method == method
    np.testing.assert_allclose(c2.apply(P), c.apply(P), atol=1e-12)
    # positions-only apply keeps the rank
    assert c2.apply(P[0, :3, 3]).shape == (3,)
    np.testing.assert_allclose(c2.apply(P[:, :3, 3]), c.apply(P)[:, :3, 3], atol=1e-12)
    # batch == loop
    loop = np.stack([c.apply(P[i:i + 1])[0] for i in range(5)])
    np.testing.assert_allclose(c.apply(P[:5]), loop, atol=1e-12)
    ev = evaluate_correction(c, P, ref)
    assert ev["corrected"]["trans_rms_mm"] == pytest.approx(ins["trans_rms_mm"], rel=1e-9)


def test_positions_only_and_group_holdout():
    rng = np.random.default_rng(14)
    ref = _workspace(rng, 90)
    meas = _poly_distortion(ref)
    groups = np.repeat([0, 1, 2], 30)
    c = fit_correction(meas[:, :3, 3], ref[:, :3, 3], "poly", groups=groups)
    assert c.stats["held_out"]["scheme"] == "leave-one-group-out"
    assert "rot_rms_deg" not in c.stats["held_out"]["corrected"]
    assert not c.corrects_orientation


def test_bad_inputs(tmp_path):
    with pytest.raises(ValueError, match="method"):
        fit_correction(np.zeros((10, 3)), np.zeros((10, 3)), "spline")
    with pytest.raises(ValueError):
        fit_correction(np.zeros((10, 3)), np.zeros((9, 3)), "poly")
    with pytest.raises(TypeError):
        fit_correction(np.zeros((10, 3), complex), np.zeros((10, 3)), "poly")
    p = tmp_path / "x.json"
    p.write_text("{not json")
    with pytest.raises(ValueError, match="JSON"):
        read_correction(p)
    p.write_text('{"format": "other"}')
    with pytest.raises(ValueError, match="openemt.correction"):
        read_correction(p)


def _grid_data(rng, levels, repeats, noise):
    g = np.linspace(-0.05, 0.05, levels)
    p = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3) + [0.2, 0.0, 0.0]
    p = np.repeat(p, repeats, axis=0)
    ref = pose_from_rt(Rotation.random(len(p), random_state=int(rng.integers(1000))).as_matrix(),
                       p)
    meas = _poly_distortion(ref)
    meas[:, :3, 3] += noise * rng.standard_normal((len(p), 3))
    return meas, ref


def test_grid_sampled_calibration_levels_and_location_folds():
    """On a 3-level calibration grid, powers >= 3 per axis are not identified: the fit must
    leave them out (axis_levels) and the folds must hold out whole locations."""
    from openemt.correct import axis_levels, location_groups, location_kfold

    rng = np.random.default_rng(15)
    meas, ref = _grid_data(rng, 3, 5, 2e-5)
    m = meas[:, :3, 3]
    assert axis_levels((m - m.mean(0)) / 0.05) == (3, 3, 3)
    assert axis_levels(rng.uniform(-1, 1, (300, 3))) == (None, None, None)
    g = location_groups(m)
    assert len(np.unique(g)) == 27 and all(np.bincount(g) == 5)
    for _, test in location_kfold(m, 5, seed=0):
        assert set(g[test]).isdisjoint(set(np.delete(g, test)))  # no location in both parts
    c = fit_correction(meas, ref, "poly")
    assert c.params["max_power"] == [2, 2, 2]
    assert c.stats["held_out"]["scheme"] == "5-fold by location"
    # between the calibration levels (a 5-level test grid) the correction still helps
    tmeas, tref = _grid_data(rng, 5, 1, 2e-5)
    ev = evaluate_correction(c, tmeas, tref)
    assert ev["corrected"]["trans_rms_mm"] < 0.6 * ev["uncorrected"]["trans_rms_mm"]
    assert ev["corrected"]["rot_rms_deg"] < 0.6 * ev["uncorrected"]["rot_rms_deg"]


def test_real_data_md_calibration_corrects_ld_test(ilemt_dir):
    """cal_9_15, XYZ_hr_cal without its stored correction: fit each method on the 3 md files
    (426 rows, a 3-level grid) and test on the 3 ld files (1896 rows, 5 levels). The test
    points lie between the calibration levels, so this checks interpolation, not repeatability.
    Paper Table II (concentric source): 0.41555 mm uncorrected, 0.26306 mm with the DLT."""
    from openemt.geometry import ground_truth_poses
    from openemt.io import import_ilemt_folder, read_ilemt_calibration
    from openemt.solve import solve

    cal = read_ilemt_calibration(ilemt_dir / "output" / "XYZ_hr_cal.mat")
    conc = read_ilemt_calibration(ilemt_dir / "output" / "XYZ_concentric_hr_cal.mat")

    def load(pattern):
        ds = import_ilemt_folder(ilemt_dir, patterns=[pattern])
        ds = ds.select(np.flatnonzero(ds.source_fixture == "YoutZup"))
        P = ground_truth_poses(cal.source_fixture, cal.stage_fixture, cal.sensor_fixture,
                               ds.source_fixture, ds.stage, ds.sensor_fixture)
        i = np.argmax(np.abs(P[:, :3, 3]), axis=1)
        s = np.sign(P[np.arange(len(P)), i, 3])
        hem = np.array([("+" if si > 0 else "-") + "xyz"[ii] for ii, si in zip(i, s)])
        r = solve(ds.couplings, cal, hemisphere=hem, concentric_calibration=conc,
                  apply_correction=False)
        return r.poses, P

    Mc, Dc = load("md")
    Mt, Dt = load("ld")
    assert len(Mc) == 426 and len(Mt) == 1896
    for method, ratio in [("dlt", 0.66), ("poly", 0.55), ("grid", 0.55), ("rbf", 0.55)]:
        c = fit_correction(Mc, Dc, method, cross_validate=False)
        ev = evaluate_correction(c, Mt, Dt)
        unc, cor = ev["uncorrected"], ev["corrected"]
        assert unc["trans_rms_mm"] == pytest.approx(0.41555, rel=1e-3)
        assert cor["trans_rms_mm"] < ratio * unc["trans_rms_mm"], method
        if method == "dlt":
            assert cor["trans_rms_mm"] == pytest.approx(0.26306, rel=0.01)
        else:
            assert cor["rot_rms_deg"] < 0.75 * unc["rot_rms_deg"], method
