"""The compiled 6-DOF board solver (``solver_family`` 'board': the dipole LM kernels on a
board's packed form) gives the interface-level LM's answers: the same statuses, positions to
1e-9 m and rotations to 1e-8 rad, on random poses including hard ones, from given starts, cold
and tracking."""

from __future__ import annotations

import numpy as np
import pytest

from openemt.board import BoardModel
from openemt.geometry import pose_from_vector
from openemt.solve import SolveOptions, Status, pose_from_axis, prepare
from openemt.solve._model_lm import ModelSolver, PackedModelSolver

POS_TOL = 1e-9
ROT_TOL = 1e-8


@pytest.fixture(scope="module")
def model():
    return BoardModel.from_board("anser-6dof")


def _compare(new, old, ref=None):
    """Statuses as ``old``'s; poses as ``ref``'s (default ``old``: the interface LM, with the
    same options or, where its own step tolerance leaves it further off on ill-conditioned
    samples, run to a tighter one)."""
    np.testing.assert_array_equal(new.status, old.status)
    ok = new.status == int(Status.CONVERGED)
    assert ok.any()
    old = old if ref is None else ref
    dp = np.abs(new.pose_vectors[ok, :3] - old.pose_vectors[ok, :3]).max()
    dR = new.poses[ok, :3, :3] - old.poses[ok, :3, :3]
    assert dp <= POS_TOL, dp
    assert np.abs(dR).max() <= ROT_TOL
    # every sample of another status: the same rule on nearly the same pose
    np.testing.assert_allclose(new.relative_residual[ok], old.relative_residual[ok],
                               rtol=1e-6, atol=1e-12)


def _random_poses(rng, n):
    xy = rng.uniform(-0.15, 0.15, (n, 2))
    z = rng.uniform(0.04, 0.25, n)
    return np.column_stack([xy, z, rng.normal(0.0, 1.5, (n, 3))])


def test_registry_builds_the_compiled_solver(model):
    assert model.solver_family == "board"
    assert isinstance(prepare(model), PackedModelSolver)


def test_same_answers_from_given_starts_incl_hard_ones(model):
    rng = np.random.default_rng(1)
    v = _random_poses(rng, 24)
    v[0, 2] = 0.004                 # just above the board
    v[1, :3] = [0.25, -0.2, 0.06]   # beside it: weak, ill-conditioned
    v[2, :3] = [0.0, 0.0, 0.6]      # far above it
    C = model.coupling(pose_from_vector(v))
    noise = 10 ** (-60 / 20) * np.sqrt(np.mean(C ** 2, axis=(1, 2)))
    C = C + noise[:, None, None] * rng.normal(size=C.shape)
    C[3] = 0.0                                          # no signal: invalid input
    C[4, 2, 1] = np.nan                                 # not finite: invalid input
    starts = v + np.column_stack([rng.normal(0, 0.01, (24, 3)), rng.normal(0, 0.2, (24, 3))])
    starts[5, :3] += [0.1, -0.1, 0.05]                  # a start far off
    starts[6, 3:] += [2.0, 0.0, 0.0]                    # turned far off
    starts[7] = np.nan                                  # no start: solved cold
    opts = SolveOptions(initial="cold", max_relative_residual=5e-3)
    new = PackedModelSolver(model, opts, prepare(model).packed)(C, starts)
    old = ModelSolver(model, opts)(C, starts)
    tight = ModelSolver(model, opts.replace(xtol=1e-13, max_iter=200))(C, starts)
    _compare(new, old, tight)
    assert {int(Status.INVALID_INPUT), int(Status.CONVERGED)} <= set(new.status.tolist())
    truth_ok = new.status == int(Status.CONVERGED)
    assert np.abs(new.pose_vectors[truth_ok, :3] - v[truth_ok, :3]).max() < 1e-3


def test_same_answers_cold(model):
    rng = np.random.default_rng(2)
    v = _random_poses(rng, 12)
    C = model.coupling(pose_from_vector(v))
    opts = SolveOptions(initial="cold")
    _compare(prepare(model, opts)(C), ModelSolver(model, opts)(C))


def test_same_answers_tracking_with_a_jump(model):
    n = 120
    t = np.arange(n) / 1000.0
    pos = np.column_stack([0.05 * np.sin(2 * np.pi * 2 * t), 0.04 * np.cos(2 * np.pi * 3 * t),
                           0.1 + 0.03 * np.sin(2 * np.pi * t)])
    th = np.pi - 0.5 + 0.3 * np.sin(2 * np.pi * 2 * t)
    axes = np.column_stack([np.sin(th), np.zeros(n), np.cos(th)])
    P, _ = pose_from_axis(pos, axes)
    P = P @ pose_from_vector(np.column_stack([np.zeros((n, 5)), 0.8 * np.sin(8 * t)]))
    P[60:, :3, 3] += [0.05, -0.04, 0.03]               # a jump: tracking fails, cold retry
    C = model.coupling(P)
    C = C + 1e-4 * np.sqrt(np.mean(C ** 2)) * np.random.default_rng(3).normal(size=C.shape)
    C[30] = np.nan
    opts = SolveOptions(initial="track")
    new, old = prepare(model, opts)(C), ModelSolver(model, opts)(C)
    _compare(new, old)
    assert (new.status == int(Status.CONVERGED)).sum() == n - 1
