"""Degenerate inputs give per-sample flags, never exceptions: coils at zero distance, tracking
that starts on an all-zero or NaN row."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from test_solve import dipole_approx_model

import openemt.cli
from openemt.field import DipoleModel, OctupoleModel, coupling_jacobians
from openemt.geometry import pose_from_vector
from openemt.io import Calibration, Dataset, write_calibration, write_dataset
from openemt.solve import Status, read_poses, solve_kim18, solve_lm


def _track_poses(n):
    v = np.zeros((n, 6))
    v[:, 0] = 0.3 + 0.002 * np.arange(n)
    v[:, 1] = 0.05
    v[:, 3] = 0.01 * np.arange(n)
    return pose_from_vector(v)


def test_dipole_coupling_at_zero_distance_is_nan_not_an_error():
    P = np.stack([np.eye(4), pose_from_vector(np.array([0.3, 0, 0, 0, 0, 0]))])
    model = DipoleModel.concentric()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        C = model.coupling(P)
        jac = coupling_jacobians(model, P)
        oct_c = OctupoleModel(model, np.full(3, 1e-4), np.zeros(3)).coupling(P)
    assert np.all(np.isnan(C[0])) and np.all(np.isfinite(C[1]))
    assert np.all(np.isnan(jac.d_translation[0])) and np.all(np.isfinite(jac.d_translation[1]))
    assert np.all(np.isnan(oct_c[0])) and np.all(np.isfinite(oct_c[1]))
    # only the coil pairs that coincide are undefined
    m = dipole_approx_model()
    at_coil = np.eye(4)
    at_coil[:3, 3] = m.L_so[:, 0] - m.L_se[:, 0]
    C = m.coupling(at_coil[None])[0]
    assert np.isnan(C[0, 0]) and np.isfinite(C[1, 1])


@pytest.mark.parametrize("first", ["zeros", "nan"])
@pytest.mark.parametrize("kind", ["concentric", "offsets", "five_coil"])
def test_track_with_a_bad_first_row(first, kind):
    if kind == "concentric":
        model = DipoleModel.concentric()
    elif kind == "offsets":
        model = dipole_approx_model()
    else:  # no closed form applies: the start comes from the multi-start grid
        rng = np.random.default_rng(0)
        model = DipoleModel(rng.normal(size=(3, 5)) * 0.01,
                            np.eye(3)[:, [0, 1, 2, 0, 1]] + 0.1 * rng.normal(size=(3, 5)),
                            np.zeros((3, 3)), np.eye(3))
    P = _track_poses(6)
    C = model.coupling(P)
    C[0] = 0.0 if first == "zeros" else np.nan
    res = solve_lm(C, model, initial="track")
    assert res.status[0] == Status.INVALID_INPUT
    assert np.all(res.status[1:] == Status.CONVERGED)
    np.testing.assert_allclose(res.poses[1:, :3, 3], P[1:, :3, 3], atol=1e-6)


def test_track_with_no_usable_row_and_zero_starts():
    model = DipoleModel.concentric()
    res = solve_lm(np.zeros((3, 3, 3)), model, initial="track")
    assert np.all(res.status == Status.INVALID_INPUT)
    # an LM start at the source itself (zero distance) is a NaN cost, not an exception
    C = model.coupling(_track_poses(2))
    res = solve_lm(C, model, initial=np.zeros(6), retries=False)
    assert np.all(res.status != Status.CONVERGED) or np.allclose(res.poses[:, :3, 3],
                                                                  _track_poses(2)[:, :3, 3])
    assert solve_kim18(np.zeros((1, 3, 3))).status[0] == Status.INVALID_INPUT


def test_cli_track_with_zero_first_row(tmp_path, capsys):
    model = DipoleModel.concentric()
    P = _track_poses(8)
    C = model.coupling(P)
    C[0] = 0.0
    ds = Dataset(couplings=C.astype(complex), stage=np.zeros((8, 6)), source_fixture="YoutZup",
                 sensor_fixture="YoutZup", pattern="sim", file_index=np.zeros(8, int),
                 files=("sim",), poses=P)
    write_dataset(ds, tmp_path / "d.h5")
    write_calibration(Calibration(model), tmp_path / "c.json")
    code = openemt.cli.main(["solve", str(tmp_path / "d.h5"), "-c", str(tmp_path / "c.json"),
                             "--initial", "track", "-o", str(tmp_path / "p.h5"), "--json"])
    assert code == 0
    res = read_poses(tmp_path / "p.h5")
    assert res.status[0] == Status.INVALID_INPUT and np.all(res.status[1:] == Status.CONVERGED)
