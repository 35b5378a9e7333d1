"""openemt.design: the Cramer-Rao map of a tracker (the bound from any model's analytic pose
Jacobian), Monte Carlo solves against it, and the command line."""

import json

import numpy as np
import pytest

from openemt.board import builtin_board
from openemt.cli import main
from openemt.design import (
    bound_map,
    design_map,
    orientation_set,
    pose_bound,
    resolve_target,
)
from openemt.field import numeric_jacobians
from openemt.geometry import pose_from_vector
from openemt.io import read_board, write_board
from openemt.live import example_tracker
from openemt.solve import cramer_rao


def test_bound_matches_solve_cramer_rao_for_the_dipole_model():
    """One bound: the design map's (any model, local rotation) equals openemt.solve's for
    the dipole model of the rig."""
    model = resolve_target("concentric").model
    P = pose_from_vector(np.array([[0.25, 0.02, -0.03, 0.3, -0.2, 1.1],
                                   [0.21, -0.05, 0.04, 2.0, 0.5, -0.4]]))
    ref = cramer_rao(model, P, 1e-4, parametrization="local")
    b = pose_bound(model, P, 1e-4)
    np.testing.assert_allclose(b.position_std, np.sqrt(np.trace(ref[:, :3, :3], axis1=1,
                                                                axis2=2)), rtol=1e-9)
    np.testing.assert_allclose(b.rotation_std, np.sqrt(np.trace(ref[:, 3:, 3:], axis1=1,
                                                                axis2=2)), rtol=1e-9)


@pytest.mark.parametrize("name", ["anser", "anser-6dof"])
def test_board_bound_from_the_analytic_jacobian_matches_finite_differences(name):
    """The board's bound (5-DOF: rotation normal to the sensor axis only) from the model's
    analytic pose Jacobian equals the bound from central differences of its couplings."""
    model = resolve_target(name).model
    P = pose_from_vector(np.array([[0.03, -0.05, 0.09, 2.8, 0.3, 0.2],
                                   [-0.1, 0.08, 0.15, 1.5, 1.0, -0.5]]))
    a = pose_bound(model, P, 1e-9)
    n = pose_bound(model, P, 1e-9, jacobians=numeric_jacobians(model, P, step=1e-6))
    np.testing.assert_allclose(a.position_std, n.position_std, rtol=1e-4)
    np.testing.assert_allclose(a.rotation_std, n.rotation_std, rtol=1e-4)
    assert np.all(a.ok) and np.all(a.position_std > 0)


def test_bound_scales_with_the_noise_and_is_worse_far_from_the_board():
    model = resolve_target("anser").model
    pts = np.array([[0.0, 0.0, 0.06], [0.0, 0.0, 0.16]])
    b1 = bound_map(model, pts, orientation_set("down"), 1e-9)
    b2 = bound_map(model, pts, orientation_set("down"), 3e-9)
    np.testing.assert_allclose(b2.position_std, 3 * b1.position_std, rtol=1e-9)
    assert b1.position_std[1, 0] > 2 * b1.position_std[0, 0]


@pytest.mark.parametrize("name", ["concentric", "anser", "anser-6dof"])
def test_montecarlo_error_agrees_with_the_bound(name):
    """The solver's Monte Carlo RMS position error (coupling-level noise, started at the
    truth) is within 10 % of the bound, median over sampled points (the rig source, the board
    with a 5-DOF and with a 6-DOF sensor)."""
    m = design_map(target=name, grid=(3, 3, 2), montecarlo=8, trials=150, seed=3)
    mc = m.montecarlo
    assert mc["n_points"] == 8 and mc["n_failed"] == 0
    assert abs(m.montecarlo_ratio_median - 1) < 0.1, mc
    assert abs(mc["ratio_rotation_median"] - 1) < 0.1, mc


def test_map_summary_and_volume_fraction():
    m = design_map(target="anser", grid=(3, 3, 3), orientations="axes", montecarlo=0,
                   target_mm=0.1, snr_db=80)
    std = m.bounds.position_std
    assert std.shape == (27, 6) and m.n_points == 27 and m.dof == 5
    assert m.position_mm["median"] == pytest.approx(np.median(std) * 1e3)
    assert m.position_mm["p95"] <= m.position_mm["max"]
    assert m.position_mm["fraction_below_target"] == pytest.approx(np.mean(std <= 1e-4))
    assert m.volume["z_mm"] == [60.0, 160.0]


def test_cli_map_json_html_and_bad_input(tmp_path, capsys):
    out = tmp_path / "map.html"
    rc = main(["design", "map", "anser", "--grid", "3", "3", "2", "--orientations", "down",
               "--montecarlo", "3", "--trials", "20", "--noise-sigma", "1e-9", "-o", str(out),
               "--json"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    d = json.loads(cap.out)
    assert d["noise_sigma"] == 1e-9 and d["n_points"] == 18 and d["n_orientations"] == 1
    assert d["montecarlo"]["n_points"] == 3 and d["montecarlo_ratio_median"] > 0
    text = out.read_text()
    assert text.count("data:image/png;base64,") == 3 and "Design map: anser" in text
    bad = tmp_path / "bad.html"
    rc = main(["design", "map", "anser", "--x-mm", "1", "--json", "-o", str(bad)])
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith("error: expected two values") and not bad.exists()
    rc = main(["design", "map", "nonesuch", "--json"])
    assert rc == 2 and "expected a built-in board" in capsys.readouterr().err
    rc = main(["design", "map", "anser", "--noise-sigma", "1e-9", "--snr-db", "60"])
    assert rc == 2 and "got both" in capsys.readouterr().err


def test_targets_files_and_rig(tmp_path):
    """A board file and a tracker file map as the board does; the rig has its volume."""
    write_board(builtin_board("anser"), tmp_path / "b.toml")
    kw = dict(grid=(2, 2, 2), orientations="down", montecarlo=0, noise_sigma=1e-9)
    ref = design_map(target="anser", **kw).position_mm["median"]
    assert design_map(target=str(tmp_path / "b.toml"), **kw).position_mm["median"] == \
        pytest.approx(ref)
    t = resolve_target(str(example_tracker("anser")))
    assert t.kind == "tracker" and t.model.n_source == 8
    r = resolve_target("dipole-approx")
    assert r.kind == "rig" and r.model.dof == 6 and r.volume.x[0] < r.volume.x[1]


def test_tracker_noise_from_its_adc_figures_matches_the_demodulated_noise():
    """A tracker file's coupling noise comes from its ADC figures; the raw-signal Monte Carlo
    (simulated samples through the demodulator) agrees with the bound for that noise."""
    m = design_map(target=str(example_tracker("anser")), grid=(3, 3, 2), montecarlo=6,
                   trials=150, seed=5)
    assert "ADC figures" in m.noise and "raw ADC samples" in m.montecarlo["noise"]
    # 1.5e-5 V rms, gain 5e4 V per coupling x A, Hann frame of 128 samples:
    # sigma sqrt(2 sum w^2) / sum w / gain = 1.5e-5 * sqrt(2 * 48) / 64 / 5e4
    assert m.noise_sigma == pytest.approx(1.5e-5 * np.sqrt(96.0) / 64 / 5e4, rel=1e-12)
    assert abs(m.montecarlo_ratio_median - 1) < 0.1, m.montecarlo


def test_optimize_lowers_the_bound_within_the_constraints(tmp_path, capsys):
    out = tmp_path / "opt.toml"
    page = tmp_path / "opt.html"
    rc = main(["design", "optimize", "anser", "--grid", "3", "3", "2", "--orientations",
               "down", "--max-evaluations", "80", "--montecarlo", "4", "--trials", "40",
               "-o", str(out), "--html", str(page), "--json"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    d = json.loads(cap.out)
    assert d["optimized"]["position_mm"]["p95"] <= d["start"]["position_mm"]["p95"]
    assert d["improvement_p95"] == pytest.approx(
        1 - d["optimized"]["position_mm"]["p95"] / d["start"]["position_mm"]["p95"])
    assert d["evaluations"] <= 81 and page.read_text().count("data:image/png") == 5
    b = read_board(out)
    start = builtin_board("anser")
    assert b.n_coils == start.n_coils and b.sensor.to_dict() == start.sensor.to_dict()
    assert all(c.outer_size == s.outer_size and c.turns_per_layer == s.turns_per_layer
               for c, s in zip(b.coils, start.coils))
    _assert_inside_and_apart(b, start, 2e-3)
    # every command that takes a board reads it
    m = design_map(target=str(out), grid=(3, 3, 2), orientations="down", montecarlo=0,
                   noise_sigma=d["noise_sigma"])
    assert m.position_mm["p95"] == pytest.approx(d["optimized"]["position_mm"]["p95"])


def _outline(c):
    """Dense samples of a square coil outline (board plane)."""
    h = c.outer_size[0] / 2
    R = c.rotation[:2, :2]
    t = np.linspace(-h, h, 200)
    sides = [np.column_stack([t, np.full_like(t, s)]) for s in (-h, h)] + \
        [np.column_stack([np.full_like(t, s), t]) for s in (-h, h)]
    return np.concatenate(sides) @ R.T + c.center[:2]


def _assert_inside_and_apart(board, start, spacing):
    """Outlines inside the start footprint and at least ``spacing`` apart (dense samples of
    each outline: their distances are at least the outlines' distance)."""
    lines = [_outline(c) for c in board.coils]
    box = np.concatenate([_outline(c) for c in start.coils])
    for k, p in enumerate(lines):
        assert np.all(p >= box.min(0) - 1e-9) and np.all(p <= box.max(0) + 1e-9)
        for q in lines[k + 1:]:
            dist = np.linalg.norm(p[:, None] - q[None], axis=-1).min()
            assert dist >= spacing - 1e-9


def _trace_lengths(board):
    return np.array([np.linalg.norm(np.diff(c.segments(), axis=1)[:, 0], axis=1).sum()
                     for c in board.coils])


def test_optimize_sizes_and_turns_within_the_drive_power(tmp_path):
    from openemt.design import optimize_layout

    out = tmp_path / "all.toml"
    r = optimize_layout(target="anser", vary="all", grid=(3, 3, 2), orientations="down",
                        max_evaluations=300, montecarlo=0, output=str(out))
    b, start = read_board(out), builtin_board("anser")
    _assert_inside_and_apart(b, start, 2e-3)
    # the drive power at a common current (sum of trace resistances, one trace width) is at
    # most the start's, and the JSON says what the file holds
    L, L0 = _trace_lengths(b), _trace_lengths(start)
    assert L.sum() <= L0.sum() * (1 + 1e-9)
    assert r.power["ratio"] == pytest.approx(L.sum() / L0.sum(), rel=1e-9)
    assert [c["turns_per_layer"] for c in r.coils] == [c.turns_per_layer for c in b.coils]
    sizes = np.array([c.outer_size[0] for c in b.coils])
    turns = np.array([c.turns_per_layer for c in b.coils])
    assert np.all(sizes >= 0.020 - 1e-12) and np.all(4 * turns == np.round(4 * turns))
    # sizes and turns moved (the search changed them), and the bound did not get worse
    assert np.any(np.abs(sizes - 0.070) > 1e-6) or np.any(turns != 12.5)
    assert r.optimized["position_mm"]["p95"] <= r.start["position_mm"]["p95"]
    m = design_map(target=str(out), grid=(3, 3, 2), orientations="down", montecarlo=0,
                   noise_sigma=r.noise_sigma)
    assert m.position_mm["p95"] == pytest.approx(r.optimized["position_mm"]["p95"])


def test_optimize_rig_source_positions_axes_and_moments(tmp_path):
    from openemt.design import optimize_layout
    from openemt.io import read_calibration
    from openemt.simulate import truth_calibration

    out = tmp_path / "rig.json"
    r = optimize_layout(target="concentric", grid=(3, 3, 3), max_evaluations=200,
                        montecarlo=3, trials=30, montecarlo_noise="coupling", output=str(out))
    m0, m = truth_calibration("concentric").model, read_calibration(out).model
    # total drive power (sum of squared moments) the start's, positions within the box, the
    # sensor unchanged
    assert np.sum(m.M_so ** 2) == pytest.approx(np.sum(m0.M_so ** 2), rel=1e-12)
    assert np.all(np.abs(m.L_so - m0.L_so) <= 0.020 + 1e-12)
    assert np.array_equal(m.L_se, m0.L_se) and np.array_equal(m.M_se, m0.M_se)
    assert not np.allclose(m.M_so, m0.M_so)
    assert 0 < r.improvement_p95 and r.montecarlo_improvement_p95 is not None
    v = r.volume
    again = design_map(target=str(out), x_mm=v["x_mm"], y_mm=v["y_mm"], z_mm=v["z_mm"],
                       grid=(3, 3, 3), montecarlo=0, noise_sigma=r.noise_sigma)
    assert again.position_mm["p95"] == pytest.approx(r.optimized["position_mm"]["p95"])
    # the solver reads it: noise-free couplings of the written model give back the poses
    from openemt.geometry import vector_from_pose
    from openemt.solve import prepare

    P = pose_from_vector(np.array([[0.24, -0.02, 0.03, 0.3, -0.2, 0.1],
                                   [0.27, 0.02, -0.04, -1.0, 0.5, 2.0]]))
    start = vector_from_pose(P) + np.array([0.004, -0.003, 0.002, 0.05, -0.04, 0.03])
    res = prepare(m, hemisphere=None)(m.coupling(P), initial=start)
    assert np.abs(res.poses[:, :3, 3] - P[:, :3, 3]).max() < 1e-7
    # no room to move: the positions stay
    fixed = optimize_layout(target="dipole-approx", grid=(2, 2, 2), max_evaluations=40,
                            montecarlo=0, offset_mm=0.0)
    m1 = truth_calibration("dipole-approx").model
    assert np.allclose([c["position"] for c in fixed.coils], m1.L_so.T, atol=0)


def test_optimize_refuses_what_it_cannot_change(capsys):
    rc = main(["design", "optimize", "anser", "--vary", "all", "--min-size-mm", "80",
               "--json"])
    assert rc == 2 and "--min-size-mm" in capsys.readouterr().err
    rc = main(["design", "optimize", "concentric", "--offset-mm", "-1", "--json"])
    assert rc == 2 and "--offset-mm" in capsys.readouterr().err
    rc = main(["design", "optimize", "concentric", "-o", "rig.toml", "--json"])
    assert rc == 2 and "expected a .json output" in capsys.readouterr().err
    rc = main(["design", "optimize", "anser", "--min-spacing-mm", "30", "--json"])
    assert rc == 2 and "30 mm spacing" in capsys.readouterr().err


def test_carrier_plans_reported_and_chosen_below_the_level(capsys):
    """The shipped plans' leakages are measured in the raw-signal simulator and demodulator;
    the chosen plan keeps crosstalk, mains and intermodulation below the stated level there,
    and a front end with more distortion shows in the intermodulation level."""
    from openemt.design import carrier_plan, plan_leakage

    rc = main(["design", "carriers", str(example_tracker("anser")), "--json"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    d = json.loads(cap.out)
    (anser,) = d["existing"]
    assert anser["frequencies_hz"][0] == 7500.0 and len(anser["frequencies_hz"]) == 8
    assert anser["crosstalk_db"] < -200          # on-bin carriers: orthogonal in a Hann frame
    assert d["chosen_below_level"] and len(d["chosen"]["frequencies_hz"]) == 8
    for key in ("crosstalk_db", "mains_db", "intermod_db"):
        assert d["chosen"][key] < d["max_level_db"]
    assert d["chosen"]["im2_collisions"] == 0
    # the measurement sees what it measures: 40 dB more distortion, about 40 dB more leakage
    r = carrier_plan(trackers=(str(example_tracker("anser")),), distortion_db=-60.0)
    lvl = r.existing[0]["intermod_db"]
    assert abs(lvl - (anser["intermod_db"] + 40)) < 3
    # and a carrier next to a mains harmonic leaks
    near = plan_leakage([2250.0, 7500.0], 96000.0, 1500.0, "hann")   # 250 Hz from 2 kHz
    assert near["mains_db"] > -20
    rc = main(["design", "carriers", "--n-carriers", "40", "--json"])
    assert rc == 2 and "expected room for 40 carriers" in capsys.readouterr().err


def test_a_dipole_calibration_maps_over_a_given_volume(tmp_path, capsys):
    from openemt.io import write_calibration
    from openemt.simulate import truth_calibration

    path = write_calibration(truth_calibration("concentric"), tmp_path / "cal.json")
    rc = main(["design", "map", str(path), "--json", "--montecarlo", "0"])
    assert rc == 2 and "expected a volume" in capsys.readouterr().err
    m = design_map(target=str(path), x_mm=(200, 280), y_mm=(-40, 40), z_mm=(-40, 40),
                   grid=(2, 2, 2), montecarlo=0, noise_sigma=1e-5)
    ref = design_map(target="concentric", x_mm=(200, 280), y_mm=(-40, 40), z_mm=(-40, 40),
                     grid=(2, 2, 2), montecarlo=0, noise_sigma=1e-5)
    assert m.kind == "calibration" and m.n_points == 8
    assert m.position_mm["p95"] == pytest.approx(ref.position_mm["p95"], rel=1e-12)


def test_map_page_renders_in_chromium(tmp_path):
    from chromium_render import render

    path = tmp_path / "map.html"
    design_map(target="anser", grid=(3, 3, 2), montecarlo=3, trials=20,
               montecarlo_noise="coupling", output=str(path))
    n_images, n_decoded, dom = render(path, tmp_path)
    assert (n_images, n_decoded) == (3, 3), f"images total/decoded = {n_images}/{n_decoded}"
    assert "Design map: anser" in dom and "Monte Carlo against the bound" in dom
    from openemt.design import optimize_layout

    page = tmp_path / "opt.html"
    optimize_layout(target="anser", grid=(3, 3, 2), orientations="down", max_evaluations=30,
                    montecarlo=3, trials=20, montecarlo_noise="coupling", html=str(page))
    n_images, n_decoded, dom = render(page, tmp_path)
    assert (n_images, n_decoded) == (5, 5), f"images total/decoded = {n_images}/{n_decoded}"
    assert "Layout optimisation: anser" in dom
    # a rig source: both maps, the distributions and the source coils' table (no outlines)
    page = tmp_path / "rig.html"
    optimize_layout(target="concentric", grid=(2, 2, 2), max_evaluations=30, montecarlo=3,
                    trials=20, montecarlo_noise="coupling", html=str(page))
    n_images, n_decoded, dom = render(page, tmp_path)
    assert (n_images, n_decoded) == (4, 4), f"images total/decoded = {n_images}/{n_decoded}"
    assert "Optimised source coils" in dom


def test_design_actions_say_a_first_run_compile(monkeypatch, capsys):
    """The design actions run their models' and solvers' kernels inside the workflows: the
    CLI watches numba's compiles, so a first run says 'compiling kernels (first run only)'."""
    import contextlib

    import openemt._compile_notice as notice
    from openemt.cli import main

    watched = []

    @contextlib.contextmanager
    def watch(out=None, what="kernels"):
        watched.append((getattr(out, "quiet", None), what))
        yield []

    monkeypatch.setattr(notice, "watch_compiles", watch)
    assert main(["design", "carriers", "--json"]) == 0
    capsys.readouterr()
    assert watched == [(False, "kernels")]
