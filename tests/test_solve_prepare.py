"""The one solver factory: ``openemt.solve.prepare`` and ``SolveOptions`` give today's results
for every kind of calibration and model, options are checked once, and the live pipeline and
``openemt solve`` build their solvers with it."""

from __future__ import annotations

import json

import numpy as np
import pytest

import openemt.solve
from openemt._errors import InputError
from openemt.board import BoardModel
from openemt.field import DipoleModel, OctupoleModel
from openemt.geometry import pose_from_vector
from openemt.io import Calibration, Dataset, write_calibration, write_dataset
from openemt.live._board import board_trajectory
from openemt.simulate import truth_calibration
from openemt.solve import (
    SolveOptions,
    Status,
    apply_position_correction,
    prepare,
    read_poses,
    solve_kim18,
    solve_lm,
    solve_svd,
)
from openemt.solve._options import SolveOptions as _Options
from openemt.solve._planar import solve_planar
from openemt.solve._prepared import PreparedLM
from openemt.solve._refine import refine_result


def _poses(n, seed):
    rng = np.random.default_rng(seed)
    v = np.column_stack([rng.uniform(0.15, 0.35, n), rng.uniform(-0.08, 0.08, (n, 2)),
                         rng.uniform(-1.0, 1.0, (n, 3))])
    return pose_from_vector(v)


def _noisy(C, seed, snr_db=70.0):
    rng = np.random.default_rng(seed)
    sigma = np.sqrt(np.mean(C ** 2, axis=tuple(range(1, C.ndim)), keepdims=True))
    return C + sigma * 10 ** (-snr_db / 20) * rng.normal(size=C.shape)


def _same(a, b):
    for name in ("poses", "pose_vectors", "status", "residual", "iterations"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


@pytest.fixture(scope="module")
def dipole():
    cal = truth_calibration("dipole-approx")
    C = _noisy(cal.model.coupling(_poses(300, 1)), 2)
    C[7] = np.nan                                  # an invalid sample keeps its flag
    return cal, C


@pytest.mark.parametrize("kw", [{}, {"initial": "track", "max_iter": 30},
                                {"bounds": 0.4, "max_relative_residual": 0.02,
                                 "retry_resnorm": 1e-12, "hemisphere": None}])
def test_dipole_model_same_as_solve_lm(dipole, kw):
    cal, C = dipole
    solver = prepare(cal.model, **kw)
    assert isinstance(solver, PreparedLM)
    assert (solver.n_source, solver.n_sensor, solver.dof) == (3, 3, 6)
    assert solver.options.to_dict() == SolveOptions(**kw).to_dict()
    got, ref = solver(C), solve_lm(C, cal.model, **kw)
    _same(got, ref)
    assert got.status[7] == Status.INVALID_INPUT and (got.status == 0).sum() > 290


def test_calibration_applies_its_linear_correction(dipole):
    cal, C = dipole
    L = np.eye(4)
    L[:3, 3] = [0.001, -0.002, 0.0005]
    L[:3, :3] += 0.01 * np.eye(3)
    corrected = cal.replace(linear_correction=L)
    ref = apply_position_correction(solve_lm(C, cal.model), L)
    _same(prepare(corrected)(C), ref)
    _same(openemt.solve.solve(C, corrected), ref)
    _same(prepare(corrected, apply_correction=False)(C), solve_lm(C, cal.model))
    # the closed forms through the factory: the same functions, the same correction
    conc = cal.model.replace(L_so=np.zeros((3, 3)), L_se=np.zeros((3, 3)))
    plain = Calibration(conc, linear_correction=L)
    for name, f in (("svd", solve_svd), ("kim18", solve_kim18)):
        _same(prepare(plain, solver=name)(C), apply_position_correction(f(C, conc), L))


def test_improved_calibration_refines_for_its_octupole_terms():
    rng = np.random.default_rng(3)
    dip = DipoleModel(rng.normal(scale=2e-3, size=(3, 3)),
                      np.eye(3) + 0.02 * rng.normal(size=(3, 3)), np.zeros((3, 3)),
                      0.4 * np.eye(3))
    k_so, k_se = np.array([-5e-4, -4e-4, -6e-4]), np.array([2e-5, 1e-5, 3e-5])
    cal = Calibration(model=dip, mode="improved",
                      extra={"rig": {"octupole_k_so": k_so.tolist(),
                                     "octupole_k_se": k_se.tolist()}})
    P = _poses(100, 4)
    C = OctupoleModel(dip, k_so, k_se).coupling(P)
    got = prepare(cal, max_relative_residual=0.02)(C)
    ref = refine_result(solve_lm(C, dip, max_relative_residual=0.02), cal.coupling_model, C,
                        max_relative_residual=0.02)
    _same(got, ref)
    assert np.abs(got.poses[:, :3, 3] - P[:, :3, 3]).max() < 1e-9


@pytest.fixture(scope="module")
def board():
    rng = np.random.default_rng(5)
    model = BoardModel.from_board("anser", gains=rng.uniform(0.9, 1.1, 8),
                                   offsets=rng.normal(0.0, 1e-3, (8, 3)))
    P = board_trajectory(np.linspace(0.0, 4.0, 120))
    return model, P, model.coupling(P)


def test_board_calibration_same_as_solve_planar(board):
    model, P, C = board
    solver = prepare(Calibration(model, mode="planar"), max_iter=80, bounds=0.5)
    assert (solver.n_source, solver.n_sensor, solver.dof) == (8, 1, 5)
    got = solver(C)
    _same(got, solve_planar(C, model, max_iter=80, bounds=0.5))
    assert np.all(got.status == Status.CONVERGED)
    np.testing.assert_allclose(got.poses[:, :3, 3], P[:, :3, 3], atol=1e-8)
    _same(prepare(model, initial="grid")(C[:5]), solve_planar(C[:5], model, initial="grid"))
    # a warm start (pose vectors, the live pipeline's) falls back to a cold start per sample
    far = got.pose_vectors.copy()
    far[:, :3] += [0.06, -0.05, 0.04]
    warm = solver(C, far)
    assert np.all(warm.status == Status.CONVERGED)
    np.testing.assert_allclose(warm.poses[:, :3, 3], P[:, :3, 3], atol=1e-8)
    with pytest.raises(InputError, match="finite-coil board"):
        prepare(model, concentric_model=DipoleModel.concentric())
    with pytest.raises(InputError, match="solver 'lm'"):
        prepare(model, solver="svd")


def test_options_are_checked_once_with_one_line_errors(dipole, monkeypatch):
    cal, _ = dipole
    bad = [({"max_iter": 0}, "max_iter"), ({"max_range": -1.0}, "max_range"),
           ({"max_relative_residual": "x"}, "max_relative_residual"),
           ({"retry_resnorm": 0}, "retry_resnorm"), ({"explore_above": -1}, "explore_above"),
           ({"bounds": np.zeros((2, 2))}, "bounds"), ({"xtol": np.nan}, "xtol"),
           ({"ambiguity_tol": -1}, "ambiguity_tol"), ({"fallback": "grid"}, "fallback"),
           ({"initial": "nearest"}, "initial"), ({"hemisphere": "+w"}, "hemisphere"),
           ({"concentric_model": "conc"}, "concentric_model")]
    for kw, word in bad:
        for make in (lambda: SolveOptions(**kw), lambda: prepare(cal, **kw),
                     lambda: SolveOptions().replace(**kw)):
            with pytest.raises(InputError, match=word) as e:
                make()
            assert "\n" not in str(e.value) and str(e.value).startswith("expected")
    with pytest.raises(InputError, match="'max_iters'"):
        prepare(cal, max_iters=5)
    with pytest.raises(InputError, match="max_iter"):
        prepare(cal, solver="svd", max_iter=5)          # an LM option for a closed form
    with pytest.raises(InputError, match="solver in"):
        prepare(cal, solver="newton")
    with pytest.raises(TypeError, match="coupling model, got ndarray"):
        prepare(np.eye(3))
    opts = SolveOptions(hemisphere=np.array([1.0, 0.0, 0.0]), bounds=0.4,
                        concentric_model=DipoleModel.concentric(), initial="track")
    json.dumps(opts.to_dict())
    assert opts.replace(max_iter=7).max_iter == 7 and opts.max_iter is None
    # a record is checked when it is made, not again when a solver is prepared from it
    calls = []
    real = _Options.__post_init__
    monkeypatch.setattr(_Options, "__post_init__", lambda self: calls.append(1) or real(self))
    opts = SolveOptions(max_iter=50)
    assert len(calls) == 1
    prepare(cal, opts)
    prepare(cal.model, opts)
    assert len(calls) == 1


def _spy(monkeypatch, module):
    """Count the calls of ``module.prepare`` (the factory's results unchanged)."""
    calls = []
    real = openemt.solve._factory.prepare

    def spy(*a, **k):
        calls.append(type(a[0]).__name__)
        return real(*a, **k)

    monkeypatch.setattr(module, "prepare", spy)
    return calls


def test_live_pipeline_builds_its_solvers_with_the_factory(board, monkeypatch):
    from openemt.live import SimulatedBackend, TrackingPipeline, lm_solver
    from openemt.live._board import board_solver

    calls = _spy(monkeypatch, openemt.solve)
    model = DipoleModel.concentric()
    s = TrackingPipeline(SimulatedBackend(model, duration=0.05, seed=1), model).run()
    assert calls == ["DipoleModel"] and s.status_counts["converged"] > 0
    assert isinstance(lm_solver(model), PreparedLM)
    bmodel, P, C = board
    solve = board_solver(bmodel)
    assert calls[-1] == "BoardModel"
    first = solve(C[:1], "kim18")                          # acquiring: cold, from the grid
    _same(first, solve_planar(C[:1], bmodel))
    warm = solve(C[1:4], np.tile(first.pose_vectors[0], (3, 1)))
    assert np.all(warm.status == Status.CONVERGED)


def test_solve_command_builds_its_solvers_with_the_factory(dipole, board, tmp_path,
                                                           monkeypatch, capsys):
    import openemt.cli as cli

    cal, _ = dipole
    P = _poses(40, 6)
    ds = Dataset(couplings=cal.model.coupling(P).astype(complex), stage=np.zeros((40, 6)),
                 source_fixture="YoutZup", sensor_fixture="YoutZup", pattern="sim",
                 file_index=np.zeros(40, int), files=("sim",), poses=P)
    write_dataset(ds, tmp_path / "d.h5")
    write_calibration(cal, tmp_path / "cal.json")
    calls = _spy(monkeypatch, openemt.solve._runner)
    argv = ["solve", str(tmp_path / "d.h5"), "-c", str(tmp_path / "cal.json"), "--hemisphere",
            "+x", "--max-iter", "60", "-o", str(tmp_path / "p.h5"), "--json"]
    assert cli.main(argv) == 0, capsys.readouterr().err
    assert calls == ["Calibration"]
    got = read_poses(tmp_path / "p.h5")
    ref = solve_lm(ds.couplings, cal.model, max_iter=60)
    np.testing.assert_array_equal(got.poses, ref.poses)
    np.testing.assert_array_equal(got.status, ref.status)

    bmodel, BP, BC = board
    bds = Dataset(couplings=BC.astype(complex), stage=np.zeros((len(BP), 6)),
                  source_fixture="YoutZup", sensor_fixture="YoutZup", pattern="sim",
                  file_index=np.zeros(len(BP), int), files=("sim",), poses=BP)
    write_dataset(bds, tmp_path / "b.h5")
    write_calibration(Calibration(bmodel, mode="planar"), tmp_path / "bcal.json")
    calls = _spy(monkeypatch, openemt.solve._runner)     # the one block runner, any model
    argv = ["solve", str(tmp_path / "b.h5"), "-c", str(tmp_path / "bcal.json"), "-o",
            str(tmp_path / "bp.h5"), "--json"]
    assert cli.main(argv) == 0, capsys.readouterr().err
    assert calls == ["Calibration"]
    got = read_poses(tmp_path / "bp.h5")
    ref = solve_planar(BC, bmodel, max_iter=100)
    np.testing.assert_array_equal(got.poses, ref.poses)
    np.testing.assert_array_equal(got.status, ref.status)
