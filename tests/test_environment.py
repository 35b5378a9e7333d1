"""Environment terms (induced dipoles, gain non-linearity, coupling offset) carried by the
coupling model and the calibration file, and chosen by ``--environment``."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_calibrate import F_SE, F_SO, F_ST, perturbed, synthetic_dataset, truth_model

from openemt._errors import InputError
from openemt.board import BoardModel
from openemt.calibrate import RigOptions, improved_calibration
from openemt.calibrate._environment import parse_environment
from openemt.field import EnvironmentModel, EnvironmentTerms, numeric_jacobians
from openemt.geometry import pose_from_vector
from openemt.io import Calibration, read_calibration, write_calibration
from openemt.solve import hemisphere_from_positions, prepare


def _terms(rng, model, n_dip=1):
    P = pose_from_vector(np.array([[0.25, 0.0, 0.0, 0.0, 0.0, 0.0]]))
    sc = np.abs(model.coupling(P)).max()
    q = rng.uniform(-0.2, 0.2, (n_dip, 3)) + [0.45, 0.0, 0.0]
    mu = rng.normal(0, 0.05, (n_dip, model.n_source, 3))
    return EnvironmentTerms(q, mu, rng.normal(0, 0.02, model.n_sensor) / sc,
                            rng.normal(0, 1e-3, (model.n_source, model.n_sensor)) * sc)


def _poses(rng, n, centre=(0.25, 0.0, 0.0), spread=0.05):
    return pose_from_vector(np.c_[rng.uniform(-spread, spread, (n, 3)) + centre,
                                  rng.normal(0, 0.5, (n, 3))])


def test_environment_model_jacobians_are_analytic():
    rng = np.random.default_rng(0)
    base = truth_model(rng)
    m = EnvironmentModel(base, _terms(rng, base, n_dip=2))
    P = _poses(rng, 4)
    a, b = m.jacobians(P), numeric_jacobians(m, P)
    for k in ("d_translation", "d_rotation", "d_params"):
        x, y = getattr(a, k), getattr(b, k)
        assert np.abs(x - y).max() < 1e-6 * np.abs(y).max(), k
    # the reading undone by linearise() is the base plus the induced field
    lin = m.linearise(m.coupling(P))
    np.testing.assert_allclose(lin, m.linear_coupling(P) - m.terms.offset, rtol=0,
                               atol=1e-12 * np.abs(lin).max())
    assert m.solver_family == "dipole-refined"


def test_environment_model_on_a_board_reads_induced_dipoles_by_its_sensor():
    rng = np.random.default_rng(1)
    bm = BoardModel.from_board("anser")
    t = EnvironmentTerms([[0.0, 0.05, -0.1]], rng.normal(0, 1e-6, (1, bm.n_source, 3)))
    m = EnvironmentModel(bm, t)
    P = _poses(rng, 3, centre=(0.0, 0.0, 0.12), spread=0.04)
    a, b = m.jacobians(P), numeric_jacobians(m, P)
    for k in ("d_translation", "d_rotation"):
        x, y = getattr(a, k), getattr(b, k)
        assert np.abs(x - y).max() < 1e-6 * np.abs(y).max(), k
    assert m.solver_family == "planar-refined" and m.dof == bm.dof
    assert np.abs(m.coupling(P) - bm.coupling(P)).max() > 0
    # solved cold (the board's compiled solver from its seed grid, then refined under the
    # whole model): the known positions and axes, with the induced field 2 % of the board's
    ratio = np.abs(m.coupling(P) - bm.coupling(P)).max() / np.abs(bm.coupling(P)).max()
    m = EnvironmentModel(bm, EnvironmentTerms(t.positions, t.moments * 0.02 / ratio))
    C = m.coupling(P)[:, :, 0]
    res = prepare(m, initial="grid")(C)
    assert np.all(res.status == 0)
    np.testing.assert_allclose(res.poses[:, :3, 3], P[:, :3, 3], rtol=0, atol=1e-8)
    np.testing.assert_allclose(np.abs(np.einsum("na,na->n", res.poses[:, :3, 2],
                                                P[:, :3, 2])), 1.0, atol=1e-9)
    np.testing.assert_allclose(m.coupling_points(P[:, :3, 3], P[:, :3, 2]), C, rtol=0,
                               atol=1e-12 * np.abs(C).max())


def test_calibration_file_carries_the_environment_and_solve_uses_it(tmp_path):
    rng = np.random.default_rng(2)
    base = truth_model(rng)
    terms = _terms(rng, base)
    cal = Calibration(model=base, mode="XYZ", extra={"environment": terms.to_dict()})
    path = tmp_path / "cal.json"
    write_calibration(cal, path)
    back = read_calibration(path)
    assert isinstance(back.coupling_model, EnvironmentModel)
    assert back.environment.names() == ["dipoles:1", "gain", "offset"]
    P = _poses(rng, 20)
    C = back.coupling_model.coupling(P)
    np.testing.assert_array_equal(C, EnvironmentModel(base, terms).coupling(P))
    res = prepare(back)(C)
    assert np.all(res.status == 0)
    np.testing.assert_allclose(res.poses[:, :3, 3], P[:, :3, 3], rtol=0, atol=1e-9)
    # the dipole model alone is misled by the environment
    plain = prepare(Calibration(model=base))(C)
    assert np.abs(plain.poses[:, :3, 3] - P[:, :3, 3]).max() > 1e-5
    # a file without environment terms reads as before
    doc = json.loads(path.read_text())
    del doc["extra"]["environment"]
    path.write_text(json.dumps(doc))
    old = read_calibration(path)
    assert old.environment is None and old.coupling_model is old.model


def test_environment_terms_of_the_wrong_shape_are_refused():
    rng = np.random.default_rng(3)
    base = truth_model(rng)
    bad = EnvironmentTerms(np.zeros((1, 3)), np.zeros((1, 2, 3)))
    with pytest.raises(InputError, match="3 source"):
        Calibration(model=base, extra={"environment": bad.to_dict()})
    with pytest.raises(InputError, match="position"):
        EnvironmentTerms.from_dict({"induced_dipoles": [{"moments": [[0, 0, 0]]}]})


@pytest.mark.parametrize("text, names", [("auto", None), ("none", None),
                                         ("dipoles:2,gain,tilt", ["dipoles:2", "gain", "tilt"]),
                                         ("dipoles,offset", ["dipoles:1", "offset"])])
def test_parse_environment(text, names):
    c = parse_environment(text)
    assert c.mode == (text if names is None else "given")
    if names is not None:
        assert c.names() == names


@pytest.mark.parametrize("text", ["magic", "dipoles:0", "gain:2", "dipoles:x"])
def test_parse_environment_refuses(text):
    with pytest.raises(InputError, match="--environment|dipoles:K"):
        parse_environment(text)


def test_improved_calibration_file_solves_the_poses_of_its_own_scoring(tmp_path):
    """The path of ``calibrate --mode improved`` and ``reproduce table2 --improved``: a rig with
    metal (an induced dipole) and a gain non-linearity; the improved calibration with those
    terms, written to a file, solves test rows through ``prepare`` (as ``solve`` and ``track``
    do) to the poses its own held-out scoring solves, and far better than without them."""
    rng = np.random.default_rng(4)
    truth = Calibration(model=truth_model(rng), source_fixture=F_SO, stage_fixture=F_ST,
                        sensor_fixture=F_SE, mode="truth")
    terms = _terms(rng, truth.model)
    terms = EnvironmentTerms(terms.positions, terms.moments, terms.gain_beta, None)
    env_truth = truth.replace(extra={"environment": terms.to_dict()})
    md = synthetic_dataset(rng, env_truth.replace(model=env_truth.coupling_model), n_per=30,
                           noise=1e-5)
    test = synthetic_dataset(rng, env_truth.replace(model=env_truth.coupling_model), n_per=10,
                             noise=1e-5, pattern="ld")
    start = perturbed(truth, rng, 0.3)
    opts = RigOptions(sensor_code_fix=False, rz_poly=0, rz_tilt=False, octupole_source=False,
                      induced=True, gain_nonlinear=True, induced_start=tuple(terms.positions[0]))
    imp = improved_calibration(md, start, None, options=opts)
    cal = imp.to_calibration(start)
    assert cal.provenance["environment"]["chosen"] == ["dipoles:1", "gain"]
    path = tmp_path / "imp.json"
    write_calibration(cal, path)
    back = read_calibration(path)
    assert isinstance(back.coupling_model, EnvironmentModel)
    from openemt.calibrate._heldout import solve_and_score, transfer

    tp, xt = transfer(imp.problem, imp.x, test)
    own = solve_and_score(tp, xt, test, None)
    hemi = hemisphere_from_positions(own.truth[:, :3, 3])
    res = prepare(back, apply_correction=False, hemisphere=hemi)(test.couplings)
    assert np.all(res.status == 0)
    np.testing.assert_allclose(res.poses[:, :3, 3], own.poses[:, :3, 3], rtol=0, atol=1e-8)
    assert own.summary["trans_rms_mm"] < 0.05
    plain = improved_calibration(md, start, None, options=RigOptions(
        sensor_code_fix=False, rz_poly=0, rz_tilt=False, octupole_source=False))
    tp0, x0 = transfer(plain.problem, plain.x, test)
    assert solve_and_score(tp0, x0, test, None).summary["trans_rms_mm"] > \
        5 * own.summary["trans_rms_mm"]


def _board_truth(rng, tilt_sigma):
    """The simulated board of a grid: the Anser layout with random coil tilts (zero with
    ``tilt_sigma`` 0), gains and offsets drawn from ``rng``."""
    tilts = np.zeros((8, 3))
    tilts[:, :2] = rng.normal(0, tilt_sigma, (8, 2))
    return BoardModel.from_board("anser", gains=rng.uniform(0.9, 1.1, 8),
                                 offsets=rng.normal(0, 2e-3, (8, 3)), tilts=tilts)


def _board_couplings(truth, pts, metal, noise, rng, scale=None):
    """Couplings of sensors at ``pts`` pointing down (-z), with the metal's in-phase response
    at a 10 kHz carrier from the simulator's physics, plus noise of ``noise`` times ``scale``
    (default: the largest coupling)."""
    u = np.tile([0.0, 0.0, -1.0], (len(pts), 1))
    C = truth.coupling_points(pts, u)
    if metal is not None:
        rv = np.tile([np.pi, 0.0, 0.0], (len(pts), 1))          # sensor z axis along -z
        P = pose_from_vector(np.c_[pts, rv])
        C = C + metal.induced_couplings(truth, P, 10000.0)[:, :, 0].real
    scale = np.abs(C).max() if scale is None else scale
    return u, C + rng.normal(0, noise * scale, C.shape), scale


def _grid_points():
    from openemt.simulate import stage_pattern

    base = stage_pattern("grid")[:, :3]
    return np.vstack([base + [0.0, 0.0, h] for h in (0.06, 0.12)])


def _board_grid(tmp_path, name, tilt_sigma, seed, metal=None, noise=1e-4):
    from openemt.calibrate import GridData, write_grid_csv

    rng = np.random.default_rng(seed)
    truth = _board_truth(rng, tilt_sigma)
    pts = _grid_points()
    u, C, _ = _board_couplings(truth, pts, metal, noise, rng)
    path = tmp_path / f"{name}.csv"
    write_grid_csv(GridData(pts, u, C), path)
    return path


def _independent_points(tilt_sigma, seed, metal=None, noise=1e-4, n=2000):
    """``n`` further points of the board of ``_board_grid(..., tilt_sigma, seed, metal,
    noise)`` (the same truth, metal and noise level), spread uniformly over the grid's
    volume: points no fit has seen."""
    rng = np.random.default_rng(seed)
    truth = _board_truth(rng, tilt_sigma)
    grid = _grid_points()
    scale = _board_couplings(truth, grid, metal, noise, rng)[2]
    r2 = np.random.default_rng(1000 + seed)
    lo, hi = grid.min(axis=0), grid.max(axis=0)
    pts = r2.uniform(lo, hi, (n, 3))
    u, C, _ = _board_couplings(truth, pts, metal, noise, r2, scale)
    return pts, u, C


def _aluminium_plate():
    """A 300 x 300 x 2 mm aluminium plate standing 90 mm beside the grid (+x), facing it."""
    from openemt.simulate import MetalObject, MetalScene

    return MetalScene((MetalObject("plate", "aluminium", (0.22, 0.0, 0.09),
                                   (0.0, -np.pi / 2, 0.0), size=(0.3, 0.3),
                                   thickness=0.002),))


GRIDS = {"untilted": (0.0, 11, None, 1e-4), "tilted": (0.02, 11, None, 1e-4),
         "metal": (0.0, 11, "plate", 2e-5)}


def _held_out_options(path, grid):
    """Every hand-picked board option fitted on the checkerboard's fitted points as
    ``calibrate --mode planar --holdout checkerboard --environment NAME`` fits it, and its
    position RMS (mm) on 2,000 independent points of the same board (``_independent_points``),
    each solved from its known pose (the model's error; the command's cold solves converge to
    these poses). The 49 checkerboard points alone rank options that differ by 1-2 % by
    their own sampling noise (untilted grid: tilt 0.514 mm against none 0.521, while on the
    2,000 points none is the better one)."""
    from openemt.calibrate import (
        PLANAR_CANDIDATES,
        GridData,
        fit_board_environment,
        holdout_split,
        known_pose_errors,
    )
    from openemt.calibrate._planar import fit_planar, read_grid
    from openemt.io import load_board

    d = read_grid(path)
    held = holdout_split("checkerboard", len(d.points), points=d.points)
    train = GridData(d.points[~held], d.axes[~held], d.couplings[~held], d.coil_names)
    tilt_sigma, seed, metal, noise = GRIDS[grid]
    pts, u, C = _independent_points(tilt_sigma, seed, _aluminium_plate() if metal else None,
                                    noise)
    out = {}
    for name, terms in PLANAR_CANDIDATES.items():
        f = fit_board_environment(train, load_board(None),
                                  lambda g, m, tilt=False: fit_planar(g, m, fit_tilt=tilt),
                                  tilt=bool(terms.get("tilt")), dipoles=terms.get("dipoles", 0))
        e = known_pose_errors(f.model, pts, u, C)
        out[name] = float(np.sqrt(np.mean(e ** 2)) * 1e3)
    return train, out


@pytest.mark.parametrize("grid", list(GRIDS))
def test_planar_environment_auto_is_as_good_held_out_as_the_best_hand_picked(tmp_path, grid):
    """``--environment auto`` on a board: its choice (cross-validated on the fitted grid
    points only: none, tilt, one induced dipole, both) is held out at least as well as the
    best hand-picked option, on points none of them was fitted to."""
    from openemt.calibrate import PLANAR_CANDIDATES
    from openemt.calibrate._environment import planar_environment_cv
    from openemt.calibrate._planar import fit_planar
    from openemt.io import load_board

    tilt_sigma, seed, metal, noise = GRIDS[grid]
    path = _board_grid(tmp_path, "g", tilt_sigma, seed, _aluminium_plate() if metal else None,
                       noise)
    train, held = _held_out_options(path, grid)
    # what calibrate's auto runs on its fitted points
    chosen, scores = planar_environment_cv(
        train, load_board(None),
        lambda g, m, tilt=False: fit_planar(g, m, fit_tilt=tilt, uncertainty=False))
    assert list(scores) == list(PLANAR_CANDIDATES)
    assert held[chosen] <= min(held.values()), (chosen, held)
    if grid != "metal":
        assert "skipped" in scores["dipoles:1"], scores              # the gate
    if grid == "tilted":
        assert "tilt" in chosen and held[chosen] < 0.5 * held["none"], (chosen, held)
    if grid == "metal":
        # the plate: an induced dipole is chosen and takes most of the error away
        assert "dipoles:1" in chosen and held[chosen] < 0.2 * held["none"], (chosen, held)


def test_planar_calibration_with_an_induced_dipole_is_written_and_solved(tmp_path):
    """``calibrate --mode planar --environment dipoles:1``: the file carries the dipole,
    its provenance says so, and its held-out points are solved cold through the board's
    solver refined under the whole model."""
    from openemt.calibrate import CalibrateOptions, calibrate_dataset

    path = _board_grid(tmp_path, "g", 0.0, 11, _aluminium_plate(), 2e-5)
    out = tmp_path / "cal.json"
    r = calibrate_dataset(CalibrateOptions(dataset=path, mode="planar", output=out,
                                           holdout="checkerboard", environment="dipoles:1"))
    assert r.calibration.provenance["environment"] == {"chosen": ["dipoles:1"],
                                                       "method": "given", "candidates": {}}
    back = read_calibration(out)
    assert back.environment.names() == ["dipoles:1"]
    assert back.coupling_model.solver_family == "planar-refined"
    assert r.holdout["n"] == 49 and r.holdout["position_rms_mm"] < 0.2
    # the report solves the grid with the same model: the calibration's held-out block
    from openemt.calibrate._planar import read_grid
    from openemt.report import planar_report

    rep = planar_report(read_grid(path), back, holdout="checkerboard").summary
    assert rep["holdout"]["position_rms_mm"] == pytest.approx(r.holdout["position_rms_mm"],
                                                              rel=1e-9)


def test_fit_environment_recovers_an_induced_dipole_and_refits_from_witnesses():
    from openemt.calibrate import fit_environment

    rng = np.random.default_rng(5)
    base = truth_model(rng)
    truth = EnvironmentTerms([[0.1, 0.35, -0.1]], rng.normal(0, 0.05, (1, 3, 3)))
    env = EnvironmentModel(base, truth)
    P = _poses(rng, 60, centre=(0.0, 0.25, 0.0), spread=0.05)
    C = env.coupling(P)
    f = fit_environment(base, P, C, dipoles=1)
    np.testing.assert_allclose(f.terms.positions, truth.positions, atol=1e-6)
    np.testing.assert_allclose(f.terms.moments, truth.moments, atol=1e-6 * 0.05)
    assert f.rms < 1e-6 * f.rms_base
    # the object moves: a few known poses (witnesses) re-estimate the terms from the last ones
    moved = EnvironmentModel(base, EnvironmentTerms([[0.12, 0.33, -0.08]], truth.moments * 1.1))
    W = P[:6]
    g = fit_environment(base, W, moved.coupling(W), start=f.terms, max_nfev=30)
    Q = _poses(rng, 10, centre=(0.0, 0.25, 0.0), spread=0.05)
    np.testing.assert_allclose(g.model.coupling(Q), moved.coupling(Q), rtol=0,
                               atol=1e-6 * np.abs(moved.coupling(Q)).max())


def test_distortion_level_takes_the_band_and_witness_figures():
    from openemt.live import distortion_level

    q = np.array([0.0, 0.0, 0.0, 5e-4])
    r = np.array([0.0, 0.0, 0.0, np.nan])
    plain = distortion_level(q, r, 1e-3, 0.01)
    assert plain.tolist() == [0, 0, 0, 64]
    lv = distortion_level(q, r, 1e-3, 0.01, band=np.array([0.01, 0.0, np.nan, 0.0]),
                          witness_m=np.array([0.0, 2e-3, 0.0, 0.25e-3]))
    assert lv.tolist() == [128, 255, 0, 64]


def test_witness_estimator_follows_a_moving_object():
    from openemt.calibrate import WitnessEstimator

    rng = np.random.default_rng(6)
    base = truth_model(rng)
    W = _poses(rng, 4, centre=(0.0, 0.25, 0.0), spread=0.07)
    with pytest.raises(InputError, match="witness"):
        WitnessEstimator(base, W[:1])
    est = WitnessEstimator(base, W)
    mu = rng.normal(0, 0.05, (1, 3, 3))
    Q = _poses(rng, 8, centre=(0.0, 0.25, 0.0), spread=0.04)
    for k, y in enumerate((0.30, 0.32, 0.34)):            # the object moves along y
        moved = EnvironmentModel(base, EnvironmentTerms([[0.15, y, -0.05]], mu))
        m = est.update(moved.coupling(W))
        assert est.last.rms < 1e-6 * est.last.rms_base, k
        np.testing.assert_allclose(m.coupling(Q), moved.coupling(Q), rtol=0,
                                   atol=1e-5 * np.abs(moved.coupling(Q)).max())


@pytest.mark.parametrize("mode, env, what", [("planar", "gain", "tilt and dipoles:K in planar"),
                                             ("XYZ", "dipoles:1", "auto or none in mode XYZ"),
                                             ("improved", "dipoles:2", "at most dipoles:1"),
                                             ("planar", "lead", "auto, none or a list")])
def test_calibrate_refuses_environment_terms_a_mode_cannot_fit(tmp_path, capsys, mode, env,
                                                               what):
    from openemt.cli import main

    path = _board_grid(tmp_path, "g", 0.0, 1)
    assert main(["calibrate", str(path), "--mode", mode, "--environment", env]) == 2
    out = capsys.readouterr()
    assert what in out.out + out.err


def test_track_solves_with_the_environment_terms_of_its_calibration(tmp_path):
    """``track``'s sensors get the calibration's coupling model (its environment terms), so
    they solve the poses ``solve`` solves."""
    import shutil

    from openemt.live import example_tracker, read_tracker
    from openemt.live._session import tracker_sensors

    src = example_tracker("simulated-2")
    shutil.copy(src, tmp_path / "t.toml")
    base = read_calibration(src.parent / "concentric.json")
    rng = np.random.default_rng(7)
    terms = EnvironmentTerms([[0.45, 0.1, 0.0]], rng.normal(0, 0.05, (1, 3, 3)))
    cal = base.replace(extra={**base.extra, "environment": terms.to_dict()})
    write_calibration(cal, tmp_path / "concentric.json")
    spec = read_tracker(tmp_path / "t.toml")
    setups = tracker_sensors(spec)
    assert all(isinstance(s.model, EnvironmentModel) for s in setups)
    P = _poses(rng, 5, centre=(0.25, 0.0, 0.0), spread=0.04)
    C = setups[0].model.coupling(P)
    res = prepare(setups[0].model)(C)
    np.testing.assert_allclose(res.poses[:, :3, 3], P[:, :3, 3], atol=1e-9)
    np.testing.assert_allclose(prepare(read_calibration(tmp_path / "concentric.json"))(C).poses,
                               res.poses, atol=1e-12)


@pytest.mark.parametrize("env", [
    {"induced_dipoles": "x"}, {"induced_dipoles": [1, 2]},
    {"induced_dipoles": [{"position": "a", "moments": [[0, 0, 0]] * 3}]},
    {"induced_dipoles": [{"position": [0, 0, 0], "moments": [[0, 0]] * 3}]},
    {"induced_dipoles": [{"position": [1e6, 0, 0], "moments": [[0, 0, 0]] * 3}]},
    {"gain_nonlinearity": "abc"}, {"gain_nonlinearity": [1, 2]},
    {"gain_nonlinearity": [None, None, None]}, {"coupling_offset": [[1]]},
    {"coupling_offset": {"a": 1}}, "str", [1],
    {"induced_dipoles": [{"position": [0, 0, 0], "moments": [[0, 0, 0]] * 3,
                          "phases_rad": [0.1, 0.2]}]},
    {"induced_dipoles": [{"position": [0, 0, 0], "moments": [[0, 0, 0]] * 3,
                          "phases_rad": "abc"}]},
    {"induced_dipoles": [{"position": [0, 0, 0], "moments": [[0, 0, 0]] * 3,
                          "phases_rad": [0.1, None, 0.2]}]},
    {"induced_dipoles": [{"position": [0, 0, 0], "moments": [[0, 0, 0]] * 3,
                          "phases_rad": [0.1, 0.2, 0.3]},
                         {"position": [0, 0, 1], "moments": [[0, 0, 0]] * 3}]},
    {"induced_dipoles": [{"position": [0, 0, 0], "moments": [[0, 0, 0]] * 3,
                          "phases_rad": [0.1, 0.2, float("inf")]}]}])
def test_damaged_environment_terms_in_a_file_are_one_error_line(tmp_path, env):
    cal = Calibration(model=truth_model(np.random.default_rng(8)))
    path = tmp_path / "c.json"
    write_calibration(cal, path)
    doc = json.loads(path.read_text())
    doc["extra"]["environment"] = env
    path.write_text(json.dumps(doc))
    with pytest.raises(InputError, match="expected"):
        read_calibration(path)


def test_a_dipole_drifting_out_of_range_is_held_back_not_a_failed_fit():
    """A uniform background field (what a dipole far away looks like) pulls an induced dipole
    outwards without bound: the fit keeps it within MAX_DIPOLE_DISTANCE_M (a trial step
    beyond is rejected) and returns terms a calibration file accepts, instead of failing on
    its own trial step (seen on a short stainless tube beside the rig)."""
    from openemt.calibrate import fit_environment
    from openemt.field._environment import MAX_DIPOLE_DISTANCE_M

    rng = np.random.default_rng(3)
    base = truth_model(rng)
    P = _poses(rng, 60, spread=0.08)
    C = base.coupling(P)
    B = rng.normal(0, 1, (base.n_source, 3)) * 1e-2 * np.abs(C).max()
    m = np.einsum("nab,bk->nak", P[:, :3, :3], base.M_se) * base.gain     # sensor moments
    C = C + np.einsum("ja,nak->njk", B, m)
    f = fit_environment(base, P, C, dipoles=1)
    assert np.abs(f.terms.positions).max() <= MAX_DIPOLE_DISTANCE_M
    assert f.rms < 0.5 * f.rms_base
    EnvironmentTerms(f.terms.positions, f.terms.moments)            # a file would accept it
