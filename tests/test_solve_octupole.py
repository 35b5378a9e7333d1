"""Calibrations with octupole (finite-coil) terms: solve() uses them, and they survive JSON."""

import numpy as np

from openemt.field import DipoleModel, OctupoleModel
from openemt.geometry import pose_from_vector
from openemt.io import Calibration, read_calibration, write_calibration
from openemt.solve import solve


def _octupole_calibration():
    rng = np.random.default_rng(3)
    dip = DipoleModel(rng.normal(scale=2e-3, size=(3, 3)), np.eye(3) + 0.02 * rng.normal(size=(3, 3)),
                      np.zeros((3, 3)), 0.4 * np.eye(3))
    k_so, k_se = np.array([-5e-4, -4e-4, -6e-4]), np.array([2e-5, 1e-5, 3e-5])
    cal = Calibration(model=dip, mode="improved",
                      extra={"rig": {"octupole_k_so": k_so.tolist(),
                                     "octupole_k_se": k_se.tolist()}})
    return cal, OctupoleModel(dip, k_so, k_se)


def test_coupling_model_of_a_calibration():
    cal, om = _octupole_calibration()
    assert isinstance(cal.coupling_model, OctupoleModel)
    np.testing.assert_array_equal(cal.coupling_model.k_so, om.k_so)
    plain = cal.replace(extra={})
    assert plain.coupling_model is plain.model


def test_solve_uses_the_octupole_terms(tmp_path):
    cal, om = _octupole_calibration()
    rng = np.random.default_rng(4)
    v = np.column_stack([rng.uniform(0.15, 0.25, 200), rng.uniform(-0.05, 0.05, (200, 2)),
                         rng.uniform(-1.0, 1.0, (200, 3))])
    P = pose_from_vector(v)
    C = om.coupling(P)
    with_oct = solve(C, cal, hemisphere="+x")
    dipole_only = solve(C, cal.replace(extra={}), hemisphere="+x")
    err_oct = np.linalg.norm(with_oct.poses[:, :3, 3] - P[:, :3, 3], axis=1)
    err_dip = np.linalg.norm(dipole_only.poses[:, :3, 3] - P[:, :3, 3], axis=1)
    assert err_oct.max() < 1e-9
    assert np.sqrt(np.mean(err_dip ** 2)) > 1e-3  # ignoring them costs millimetres here
    assert np.all(with_oct.residual < 1e-20)
    # the terms survive the calibration file
    write_calibration(cal, tmp_path / "cal.json")
    back = read_calibration(tmp_path / "cal.json")
    np.testing.assert_array_equal(back.coupling_model.k_se, om.k_se)
