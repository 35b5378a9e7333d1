"""One model interface, one calibration type, one solver factory (docs/field-models.md#the-model-interface):
every coupling model's analytic Jacobians against finite differences, its parameter vector,
the codec round trip of every model kind (and the old board file form), and the
interface-level solver on a board read by a two-coil 6-DOF sensor."""

import json

import numpy as np
import pytest

from openemt._errors import InputError
from openemt.board import BoardModel, builtin_board
from openemt.calibrate import ParameterLayout
from openemt.field import (
    CouplingModel,
    DipoleModel,
    FiniteCoilModel,
    OctupoleModel,
    check_coupling_model,
    numeric_jacobians,
)
from openemt.geometry import pose_from_vector
from openemt.io import Calibration, read_calibration, write_calibration
from openemt.simulate import get_preset
from openemt.solve import Status, prepare


def _dipole(ne=3):
    rng = np.random.default_rng(0)
    return DipoleModel(rng.normal(0, 0.003, (3, 3)), np.eye(3) + rng.normal(0, 0.05, (3, 3)),
                       rng.normal(0, 0.002, (3, ne)),
                       np.eye(3)[:, :ne] + rng.normal(0, 0.05, (3, ne)))


def _board(name="anser-6dof", seed=1):
    rng = np.random.default_rng(seed)
    ne = builtin_board(name).sensor.n_coils
    return BoardModel.from_board(name, gains=rng.uniform(0.5, 2.0, 8),
                                  offsets=rng.normal(0.0, 1e-3, (8, 3)),
                                  tilts=rng.normal(0.0, 1e-2, (8, 3)),
                                  sensor_gains=np.r_[1.0, rng.uniform(0.9, 1.1, ne - 1)])


MODELS = {
    "dipole 3x3": lambda: _dipole(3),
    "dipole 3x1": lambda: _dipole(1),
    "octupole": lambda: OctupoleModel(_dipole(3), [1e-4, -2e-4, 5e-5], [3e-5, 1e-5, -2e-5]),
    "board 5-DOF": lambda: _board("anser"),
    "board 6-DOF": lambda: _board("anser-6dof"),
}
POSES = pose_from_vector(np.array([[0.03, -0.02, 0.15, 0.3, -0.2, 0.5],
                                   [-0.05, 0.04, 0.21, -0.4, 0.3, 2.0]]))


@pytest.mark.parametrize("name", MODELS)
def test_analytic_jacobians_match_finite_differences(name):
    model = MODELS[name]()
    assert isinstance(model, CouplingModel) and check_coupling_model(model) is model
    a, b = model.jacobians(POSES), numeric_jacobians(model, POSES)
    assert a.C.shape == (2, model.n_source, model.n_sensor)
    np.testing.assert_allclose(a.C, model.coupling(POSES), rtol=1e-12, atol=0)
    for key in ("d_translation", "d_rotation", "d_params"):
        x, y = getattr(a, key), getattr(b, key)
        assert x.shape == y.shape
        assert np.abs(x - y).max() <= 1e-6 * np.abs(y).max(), key
    assert model.jacobians(POSES, params=False).d_params is None


@pytest.mark.parametrize("name", MODELS)
def test_parameter_vector_groups_and_gauge(name):
    model = MODELS[name]()
    x = model.params
    again = model.with_params(x)
    np.testing.assert_array_equal(again.params, x)
    np.testing.assert_array_equal(again.coupling(POSES), model.coupling(POSES))
    moved = model.with_params(x * 1.01)
    assert not np.allclose(moved.coupling(POSES), model.coupling(POSES))
    parts = model.split_params(x)
    assert sum(np.size(v) for v in parts.values()) == x.size
    for g in model.fit_groups + model.fixed_groups:
        idx = model.parameter_groups[g]       # empty for a side's lone reference coil
        assert idx.size == 0 or idx.max() < x.size, g
    assert np.unique(np.concatenate([model.parameter_groups[g] for g in model.fit_groups])).size

    assert np.all(model.gauge < x.size)
    labels = {model.parameter_label(i) for i in range(x.size)}
    assert len(labels) == x.size
    assert model.dof == (5 if model.n_sensor == 1 else 6)
    lay = ParameterLayout.for_model(model)
    assert lay.size == x.size + 18
    np.testing.assert_array_equal(lay.model(lay.pack(model, *np.zeros((3, 6)))).params, x)


def test_simulation_truth_is_not_a_calibratable_model():
    # the finite-coil simulator has no parameter vector: it stays the independent truth
    p = get_preset("dipole-approx")
    assert isinstance(p.model, FiniteCoilModel) and not isinstance(p.model, CouplingModel)
    with pytest.raises(TypeError, match="coupling model"):
        Calibration(p.model)


@pytest.mark.parametrize("name", ["dipole 3x3", "board 5-DOF", "board 6-DOF"])
def test_every_kind_round_trips_through_one_codec(name, tmp_path):
    model = MODELS[name]()
    se = {k: np.full(np.shape(v), 1e-4) for k, v in model.split_params(model.params).items()}
    cal = Calibration(model, stage_fixture=np.r_[0.1, 0.2, 0.3, 0.01, 0.02, 0.03],
                      mode="reference", free=("st_fix",), standard_errors=se,
                      stats={"rms_residue": 0.5}, extra={"note": name})
    path = write_calibration(cal, tmp_path / "cal.json")
    back = read_calibration(path)
    assert type(back.model) is type(model) and back.kind == model.kind
    np.testing.assert_array_equal(back.model.params, model.params)
    np.testing.assert_array_equal(back.stage_fixture, cal.stage_fixture)
    assert back.free == ("st_fix",) and back.extra == {"note": name}
    for k in se:
        np.testing.assert_array_equal(back.standard_errors[k], se[k])
    np.testing.assert_array_equal(back.model.coupling(POSES), model.coupling(POSES))


def test_old_board_calibration_files_still_read(tmp_path):
    # the form written before one calibration type: no fixtures, free/frozen, extra or
    # sensor_gains, and a board without a dual-sensor key
    model = _board("anser")
    doc = {"schema": "openemt.calibration", "schema_version": 1, "written_by": "openemt 0.9",
           "units": {}, "mode": "planar",
           "model": {"kind": "finite", "n_source": 8, "n_sensor": 1,
                     "board": model.board.to_dict(), "gains": model.gains.tolist(),
                     "offsets": model.offsets.tolist(), "tilts": model.tilts.tolist()},
           "standard_errors": {"gains": [1e-3] * 8}, "stats": {"status": "converged"},
           "provenance": {"grid_file": "grid.csv"}}
    (tmp_path / "old.json").write_text(json.dumps(doc))
    cal = read_calibration(tmp_path / "old.json")
    assert cal.mode == "planar" and not np.any(cal.stage_fixture)
    np.testing.assert_array_equal(cal.model.sensor_gains, [1.0])
    np.testing.assert_array_equal(cal.model.coupling(POSES), model.coupling(POSES))
    doc["model"]["gains"] = [1.0] * 7
    (tmp_path / "bad.json").write_text(json.dumps(doc))
    with pytest.raises(InputError, match=r"model.gains of shape \(8,\)"):
        read_calibration(tmp_path / "bad.json")
    doc["model"]["kind"] = "magic"
    (tmp_path / "bad.json").write_text(json.dumps(doc))
    with pytest.raises(InputError, match="model.kind"):
        read_calibration(tmp_path / "bad.json")


def _six_dof_path(n=60):
    t = np.linspace(0.0, 1.0, n)
    v = np.column_stack([0.04 * np.sin(3 * t), 0.03 * np.cos(2 * t), 0.09 + 0.05 * t,
                         np.pi + 0.3 * np.sin(2 * t), 0.2 * np.cos(3 * t), 1.5 * t])
    return pose_from_vector(v)


def test_six_dof_board_solved_from_the_interface_alone():
    model = _board("anser-6dof", seed=3)
    P = _six_dof_path()
    C = model.coupling(P)
    solver = prepare(Calibration(model))
    assert (solver.n_source, solver.n_sensor, solver.dof) == (8, 2, 6)
    for start in ("cold", "track", P):
        res = solver(C, start)
        assert np.all(res.status == Status.CONVERGED), start if isinstance(start, str) else "P"
        np.testing.assert_allclose(res.poses, P, atol=1e-7)
        assert res.relative_residual.max() < 1e-9
    # the roll about the sensor axis is measured: a 5-DOF read of the same board is not
    five = prepare(_board("anser", seed=3))
    assert five.dof == 5 and solver.dof == 6
    # bad samples are flagged per sample, the batch goes on
    bad = C.copy()
    bad[3] = np.nan
    bad[7] = 0.0
    res = solver(bad, "cold")
    assert res.status[3] == res.status[7] == Status.INVALID_INPUT
    assert np.all(np.delete(res.status, [3, 7]) == Status.CONVERGED)
    with pytest.raises(InputError, match=r"shape \(N, 8, 2\)"):
        solver(C[:, :, :1])
    with pytest.raises(InputError, match="closed forms"):
        prepare(model, solver="kim18")


def test_octupole_calibration_round_trips_and_is_solved_with_its_terms(tmp_path):
    model = MODELS["octupole"]()
    cal = Calibration(model, mode="improved")
    back = read_calibration(write_calibration(cal, tmp_path / "oct.json"))
    assert back.kind == "octupole"
    np.testing.assert_array_equal(back.model.params, model.params)
    P = pose_from_vector(np.array([[0.25, 0.05, -0.04, 0.3, -0.2, 0.7],
                                   [0.18, -0.07, 0.06, -1.0, 0.4, 2.2]]))
    C = model.coupling(P)
    res = prepare(back, hemisphere="+x")(C)        # the dipole kernel, refined by the octupoles
    assert np.all(res.status == Status.CONVERGED)
    np.testing.assert_allclose(res.poses, P, atol=1e-9)
    plain = prepare(model.dipole, hemisphere="+x")(C)   # the dipole alone misses the terms
    assert np.abs(plain.poses[:, :3, 3] - P[:, :3, 3]).max() > 1e-7
