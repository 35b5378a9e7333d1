"""Calibration JSON files: exact round trip, validation messages, .mat dispatch and import."""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.io

from openemt.field import DipoleModel
from openemt.io import Calibration, read_calibration, read_ilemt_calibration, write_calibration


def _random_cal(rng, n_so=3, n_se=4):
    model = DipoleModel(rng.normal(size=(3, n_so)) * 1e-3, rng.normal(size=(3, n_so)),
                        rng.normal(size=(3, n_se)) * 1e-4, rng.normal(size=(3, n_se)),
                        gain=1 / 250)
    return Calibration(
        model=model, source_fixture=rng.normal(size=6), stage_fixture=rng.normal(size=6),
        sensor_fixture=rng.normal(size=6), linear_correction=rng.normal(size=(4, 4)),
        mode="XYZ", free=("d_so_pos", "st_fix"), frozen=("d_so_z_gain",),
        standard_errors={"L_so": np.abs(rng.normal(size=(3, n_so))) * 1e-6,
                         "F_st": np.array([1e-6, np.nan, 2e-6, 3e-7, 4e-7, 5e-7])},
        stats={"rms_residue": float(rng.random()), "num_points": 426, "ok": True},
        provenance={"openemt_version": "0.1", "inputs": {"a.dat": "ab" * 32}},
        extra={"quadrupole": {"q_source_distance": 0.004, "q": [[0.0, 1e-300]]}},
    )


def _assert_same(a: Calibration, b: Calibration):
    for name in ("L_so", "M_so", "L_se", "M_se"):
        np.testing.assert_array_equal(getattr(a.model, name), getattr(b.model, name))
    assert a.model.gain == b.model.gain
    for name in ("source_fixture", "stage_fixture", "sensor_fixture", "linear_correction"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert (a.mode, a.free, a.frozen) == (b.mode, b.free, b.frozen)
    assert set(a.standard_errors) == set(b.standard_errors)
    for k in a.standard_errors:
        np.testing.assert_array_equal(a.standard_errors[k], b.standard_errors[k])
    assert a.stats == b.stats and a.provenance == b.provenance and a.extra == b.extra


def test_round_trip_bit_exact(tmp_path):
    rng = np.random.default_rng(42)
    for _ in range(3):
        cal = _random_cal(rng)
        p = write_calibration(cal, tmp_path / "c.json")
        _assert_same(cal, read_calibration(p))
    cal = cal.replace(linear_correction=None, standard_errors={})
    _assert_same(cal, read_calibration(write_calibration(cal, tmp_path / "c.json")))


def test_document_fields(tmp_path):
    write_calibration(_random_cal(np.random.default_rng(1)), tmp_path / "c.json")
    doc = json.loads((tmp_path / "c.json").read_text())
    assert doc["schema"] == "openemt.calibration" and doc["schema_version"] == 1
    assert doc["units"]["model.L_so"] == "m"
    assert doc["model"]["n_source"] == 3 and doc["model"]["n_sensor"] == 4
    assert len(doc["model"]["L_se"]) == 3 and len(doc["model"]["L_se"][0]) == 4
    assert doc["standard_errors"]["F_st"][1] is None          # NaN is written as null


def _doc(tmp_path):
    write_calibration(_random_cal(np.random.default_rng(2)), tmp_path / "c.json")
    return json.loads((tmp_path / "c.json").read_text())


@pytest.mark.parametrize("edit, match", [
    (lambda d: d.pop("fixtures"), r"expected field `fixtures`, got no such field"),
    (lambda d: d["model"].pop("M_se"), r"expected field `model.M_se`"),
    (lambda d: d["fixtures"].update(stage=[0, 0, 0]),
     r"expected `fixtures.stage` of shape \(6,\), got shape \(3,\)"),
    (lambda d: d["model"].update(L_so=[[1, 2], [3, 4]]), r"`model.L_so` of shape \(3, n\)"),
    (lambda d: d["model"].update(L_so="abc"), r"expected `model.L_so` to be list"),
    (lambda d: d["model"].update(n_source=5), r"expected `model.n_source` = 3"),
    (lambda d: d["model"].update(kind=[None]),
     r"expected `model.kind` in \['dipole', 'finite', 'octupole'\], got \[None\]"),
    (lambda d: d.update(schema="other"), r"expected schema 'openemt.calibration', got 'other'"),
    (lambda d: d.update(schema_version=7), r"expected schema_version 1..1, got 7"),
    (lambda d: d.update(linear_correction=[[1, 0], [0, 1]]), r"`linear_correction` of shape"),
    (lambda d: d["fixtures"].update(source=[0, 0, None, 0, 0, 0]),
     r"`fixtures.source` as a list of numbers.*got list"),
    (lambda d: d.update(free="d_so_pos"), r"expected `free` to be a list of strings"),
    (lambda d: d.update(stats=[1]), r"expected `stats` to be an object"),
])
def test_validation_messages_name_the_field(tmp_path, edit, match):
    doc = _doc(tmp_path)
    edit(doc)
    (tmp_path / "bad.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=match) as exc:
        read_calibration(tmp_path / "bad.json")
    msg = str(exc.value)
    assert msg.startswith("calibration file bad.json: ") and "\n" not in msg


def test_bad_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing file"):
        read_calibration(tmp_path / "none.json")
    (tmp_path / "x.json").write_text("{not json")
    with pytest.raises(ValueError, match=r"invalid JSON in x.json \(line 1"):
        read_calibration(tmp_path / "x.json")
    (tmp_path / "x.mat").write_bytes(b"garbage" * 20)
    with pytest.raises(ValueError, match="expected an ILEMT calibration .mat file"):
        read_calibration(tmp_path / "x.mat")
    scipy.io.savemat(tmp_path / "y.mat", {"d_source_pos": np.zeros((3, 3))})
    with pytest.raises(ValueError, match="y.mat: expected an ILEMT calibration with variable "
                                         "'d_source_moment'"):
        read_calibration(tmp_path / "y.mat")


def _mat_fields(rng):
    M = np.eye(3)
    return {"d_source_pos": rng.normal(size=(3, 3)) * 1e-3, "d_source_moment": M,
            "d_sensor_pos": np.zeros((3, 3)), "d_sensor_moment": 0.4 * M,
            "source_fixture": rng.normal(size=6), "stage_fixture": rng.normal(size=6),
            "sensor_fixture": rng.normal(size=6),
            "q_source_pos": np.zeros((3, 3)), "q_source_moment": np.zeros((3, 3)),
            "q_sensor_pos": np.zeros((3, 3)), "q_sensor_moment": np.zeros((3, 3)),
            "q_source_distance": 0.004, "q_sensor_distance": 0.0005, "pin_quadrupole": 1,
            "stats": {"rms_residue": 0.5, "num_points": 10},
            "options": {"cal_mode": "XYZ", "concentric": 1, "optimize": np.array(
                ["d_so_mo", "st_fix"], dtype=object), "freeze": "d_so_z_gain"}}


def test_synthetic_mat_import_and_quadrupole_warning(tmp_path):
    rng = np.random.default_rng(9)
    fields = _mat_fields(rng)
    scipy.io.savemat(tmp_path / "cal.mat", fields)
    cal = read_calibration(tmp_path / "cal.mat")
    np.testing.assert_array_equal(cal.model.L_so, fields["d_source_pos"])
    np.testing.assert_array_equal(cal.stage_fixture, fields["stage_fixture"])
    assert cal.mode == "XYZ_concentric" and cal.free == ("d_so_mo", "st_fix")
    assert cal.frozen == ("d_so_z_gain",) and cal.linear_correction is None
    assert cal.stats == {"rms_residue": 0.5, "num_points": 10}
    assert cal.extra["quadrupole"]["pin_quadrupole"] == 1
    # the imported calibration survives the JSON round trip
    _assert_same(cal, read_calibration(write_calibration(cal, tmp_path / "cal.json")))
    fields["q_sensor_moment"] = np.diag([0.0, 1e-3, 0.0])
    scipy.io.savemat(tmp_path / "q.mat", fields)
    with pytest.warns(UserWarning, match="quadrupole"):
        read_ilemt_calibration(tmp_path / "q.mat")


@pytest.mark.parametrize("edit, match", [
    (lambda d: d["standard_errors"].update(source_fixture=[1e-6, 2e-6]),
     r"standard_errors.source_fixture` of shape \(6,\)"),
    (lambda d: d["standard_errors"].update(L_se=[[1e-6]]),
     r"standard_errors.L_se` of shape \(3, 4\)"),
    (lambda d: d["standard_errors"].update(gains=[1.0]), r"blocks among .*got `gains`"),
    (lambda d: d["standard_errors"].update(F_so=[-1e-6, 0, 0, 0, 0, 0]), r">= 0"),
    (lambda d: d["model"].update(gain=1e300), r"coupling scale .* got \d\.\d+e\+30\d"),
    (lambda d: d["model"].update(gain=1e-300), r"coupling scale"),
    (lambda d: d["model"]["L_so"][0].__setitem__(0, 50.0), r"within 10 m"),
])
def test_blocks_are_checked_against_each_other_and_their_ranges(tmp_path, edit, match):
    from openemt._errors import InputError

    path = write_calibration(_random_cal(np.random.default_rng(5)), tmp_path / "c.json")
    doc = json.loads(path.read_text())
    edit(doc)
    path.write_text(json.dumps(doc))
    with pytest.raises(InputError, match=match):
        read_calibration(path)


def test_solve_options_refuse_non_finite_limits():
    from openemt._errors import InputError
    from openemt.solve import SolveOptions

    for name in ("max_relative_residual", "max_range"):
        with pytest.raises(InputError, match=f"finite positive `{name}`"):
            SolveOptions(**{name: float("inf")})
        assert getattr(SolveOptions(**{name: None}), name) is None   # None disables
    with pytest.raises(InputError, match="max_iter` <= 10000"):
        SolveOptions(max_iter=10**9)
    with pytest.raises(InputError, match="finite positive `retry_resnorm`"):
        SolveOptions(retry_resnorm=float("inf"))
