"""Planar (Anser-style) field-generator calibration from grid data (Jaeger et al. 2017)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from openemt.board import BoardModel, board_coils, builtin_board
from openemt.calibrate import GridData, fit_planar, read_grid_csv, write_grid_csv
from openemt.field import FiniteCoilModel, circular_coil
from openemt.geometry import pose_from_vector
from openemt.simulate import simulate, stage_pattern
from openemt.simulate._presets import board_gain_scale

PITCH = 0.04286
HEIGHT = 0.072


def _grid():
    st = stage_pattern("grid")
    pts = st[:, :3].copy()
    pts[:, 2] += HEIGHT
    return pts, np.tile([0.0, 0.0, -1.0], (len(pts), 1))


def test_grid_is_the_anser_test_grid():
    pts, _ = _grid()
    assert pts.shape == (49, 3)
    xs = np.unique(np.round(pts[:, 0], 6))
    assert xs.size == 7
    np.testing.assert_allclose(np.diff(xs), PITCH, atol=1e-5)


def test_board_model_matches_the_finite_coil_truth():
    # the board model (segment kernel) against the simulator's finite-coil quadrature of the
    # same board file: proportional, coil by coil (the constant is the sensor's gain)
    board = builtin_board("anser")
    board = replace(board, sensor=replace(board.sensor, length=0.0))   # a point sensor
    pts, u = _grid()
    sensor = circular_coil(np.zeros(3), [0.0, 0.0, 1.0], radius=1e-4)
    P = pose_from_vector(np.c_[pts, np.tile([np.pi, 0.0, 0.0], (len(pts), 1))])
    C_ref = FiniteCoilModel(tuple(board_coils(board)), (sensor,)).coupling(P)[:, :, 0]
    C = BoardModel.from_board(board).coupling_points(pts, u)
    k = np.sum(C * C_ref) / np.sum(C * C)
    np.testing.assert_allclose(k * C, C_ref, rtol=0, atol=1e-5 * np.abs(C_ref).max())


def test_planar_calibration_recovers_gains_and_offsets(tmp_path):
    rng = np.random.default_rng(0)
    pts, u = _grid()
    g_true = 0.01 * (1 + rng.normal(0, 0.02, 8))
    d_true = rng.normal(0, 0.5e-3, (8, 3))
    C = BoardModel.from_board("anser", gains=g_true, offsets=d_true).coupling_points(pts, u)
    C = C + rng.normal(0, 1e-4 * np.sqrt(np.mean(C ** 2)), C.shape)
    path = tmp_path / "grid.csv"
    write_grid_csv(GridData(pts, u, C), path)
    data = read_grid_csv(path)
    np.testing.assert_array_equal(data.couplings, C)
    fit = fit_planar(data, "anser")
    m = fit.model
    z_g = (m.gains - g_true) / fit.gains_se
    z_d = (m.offsets - d_true) / fit.offsets_se
    assert fit.status == "converged"
    assert np.abs(m.offsets - d_true).max() < 2e-5       # 20 um
    assert np.abs(m.gains / g_true - 1).max() < 1e-3
    assert np.abs(np.r_[z_g, z_d.ravel()]).max() < 4.0
    assert fit.rms_residual == pytest.approx(1e-4 * np.sqrt(np.mean(C ** 2)), rel=0.2)


def test_planar_calibration_on_simulated_anser_data():
    """The simulator's Anser board (finite 8 mm sensor, noise): offsets come out near zero and
    the gains equal the simulated sensor's coupling per unit board gain, in the board frame of
    the true poses."""
    ds = simulate("anser", "grid", source_fixtures="YoutZup", sensor_fixtures="YoutZup",
                  snr_db=80.0, stage_sigma=0.0,
                  seed=3)
    P = ds.poses
    data = GridData(P[:, :3, 3], P[:, :3, 2], ds.couplings[:, :, 0].real)
    fit = fit_planar(data, "anser")
    assert np.abs(fit.model.offsets).max() < 5e-5
    np.testing.assert_allclose(fit.model.gains, board_gain_scale(builtin_board("anser")),
                               rtol=2e-3)


def test_grid_csv_rejects_bad_files(tmp_path):
    p = tmp_path / "bad.csv"
    p.write_text("x,y,z,ux,uy\n0,0,0,0,0\n")
    with pytest.raises(ValueError, match="missing"):
        read_grid_csv(p)
    with pytest.raises(FileNotFoundError):
        read_grid_csv(tmp_path / "none.csv")
    with pytest.raises(ValueError, match="coil columns"):
        fit_planar(GridData(np.zeros((2, 3)) + 0.07, np.ones((2, 3)), np.ones((2, 3))))
