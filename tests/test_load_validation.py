"""Calibration and correction files are validated on load: one clear error line naming the
file, what was expected and what arrived (docs/calibration-format.md#validation,
docs/correction.md#correction-files)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.io

import openemt.cli
from openemt import datasets
from openemt._errors import InputError
from openemt.correct import fit_correction, read_correction, write_correction
from openemt.correct._model import MAX_POLY_ORDER
from openemt.field import DipoleModel
from openemt.io import Calibration, read_calibration, write_calibration


@pytest.fixture()
def cal_doc(tmp_path):
    L = np.eye(4)
    L[:3, 3] = [0.001, 0.0, -0.002]
    cal = Calibration(DipoleModel.concentric(np.eye(3) * 0.9), linear_correction=L)
    path = tmp_path / "cal.json"
    write_calibration(cal, path)
    return path, json.loads(path.read_text())


def _write(path, doc):
    path.write_text(json.dumps(doc))
    return path


@pytest.mark.parametrize(("change", "match"), [
    (lambda d: d.update(linear_correction=np.zeros((4, 4)).tolist()), "non-singular"),
    (lambda d: d.update(linear_correction=[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0],
                                           [0, 0, 0, 0]]), "non-singular"),
    (lambda d: d["linear_correction"][0].__setitem__(0, None), "linear_correction"),
    (lambda d: d["model"]["L_so"][1].__setitem__(2, None), "L_so"),
    (lambda d: d.update(schema_version=2), "schema_version"),
    (lambda d: d["model"].update(n_source=4), "n_source"),
    (lambda d: d["model"].update(M_se=[[0, 1, 0], [0, 0, 0], [0, 0, 1]]), "non-zero coil"),
    (lambda d: d["model"].update(gain=0), "gain"),
    (lambda d: d.update(standard_errors={"M_so": [[0.1, 0.1], [0.1, 0.1]]}), "standard_errors"),
])
def test_bad_calibration_json_is_one_clear_error(cal_doc, change, match):
    path, doc = cal_doc
    change(doc)
    _write(path, doc)
    with pytest.raises(InputError, match=match) as err:
        read_calibration(path)
    msg = str(err.value)
    assert "cal.json" in msg and "expected" in msg and "\n" not in msg


def test_good_calibration_still_loads(cal_doc):
    path, _ = cal_doc
    assert read_calibration(path).linear_correction[0, 3] == pytest.approx(0.001)


def test_calibration_object_rejects_singular_correction():
    with pytest.raises(InputError, match="non-singular"):
        Calibration(DipoleModel.concentric(), linear_correction=np.zeros((4, 4)))


def test_cli_reports_bad_calibration(cal_doc, tmp_path, capsys):
    path, doc = cal_doc
    doc["linear_correction"] = np.zeros((4, 4)).tolist()
    _write(path, doc)
    code = openemt.cli.main(["solve", str(tmp_path / "missing.h5"), "--calibration", str(path),
                             "-o", str(tmp_path / "p.h5")])
    assert code == 2
    err = capsys.readouterr().err
    assert "error:" in err and "non-singular" in err and "cal.json" in err


@pytest.mark.parametrize(("key", "value", "match"), [
    ("linear_correction", np.zeros((4, 4)), "non-singular"),
    ("d_source_pos", np.full((3, 3), np.nan), "finite"),
    ("d_sensor_moment", np.zeros((3, 3)), "non-zero coil"),
])
def test_bad_ilemt_mat_is_one_clear_error(tmp_path, key, value, match):
    src = datasets.path("cal_9_15_premo_cmu")
    mats = sorted(src.rglob("XYZ_hr_cal.mat"))
    d = scipy.io.loadmat(mats[0])
    d = {k: v for k, v in d.items() if not k.startswith("__")}
    d[key] = value
    bad = tmp_path / "bad_cal.mat"
    scipy.io.savemat(bad, d)
    with pytest.raises(InputError, match=match) as err:
        read_calibration(bad)
    assert "bad_cal.mat" in str(err.value)


@pytest.fixture(scope="module")
def corrections():
    rng = np.random.default_rng(2)
    ref = rng.uniform(-0.1, 0.1, (80, 3)) + [0.25, 0, 0]
    meas = ref + 0.002 * np.sin(5 * ref)
    return {m: fit_correction(meas, ref, m, cross_validate=False).to_dict()
            for m in ("dlt", "poly", "grid", "rbf")}


@pytest.mark.parametrize(("method", "change", "match"), [
    ("poly", lambda d: d["params"].update(pos_order=1_000_000_000), "MAX_POLY_ORDER"),
    ("poly", lambda d: d["params"].update(pos_order=MAX_POLY_ORDER + 1), "pos_order"),
    ("poly", lambda d: d["params"].update(pos_order="3"), "pos_order"),
    ("poly", lambda d: d["params"].update(scale=0.0), "non-zero"),
    ("poly", lambda d: d["params"].update(scale=None), "scale"),
    ("poly", lambda d: d["params"]["pos_coef"][0].__setitem__(1, None), "pos_coef"),
    ("poly", lambda d: d["params"].update(pos_coef=d["params"]["pos_coef"][:-1]), "pos_coef"),
    ("dlt", lambda d: d["params"].update(matrix=np.zeros((4, 4)).tolist()), "non-singular"),
    ("dlt", lambda d: d.update(version=7), "version"),
    ("grid", lambda d: d["params"].update(shape=[4, 4, 1_000_000_000]), "values"),
    ("grid", lambda d: d["params"].update(lower=d["params"]["upper"]), "lower"),
    ("rbf", lambda d: d["params"].update(scale=float("inf")), "scale"),
    ("rbf", lambda d: d["params"].update(points=d["params"]["points"][:-1]), "values"),
    ("rbf", lambda d: d.update(method="spline"), "method"),
])
def test_bad_correction_file_is_one_clear_error(tmp_path, corrections, method, change, match):
    doc = json.loads(json.dumps(corrections[method]))
    change(doc)
    path = tmp_path / "corr.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(InputError, match=match) as err:
        read_correction(path)
    msg = str(err.value)
    assert "corr.json" in msg and "expected" in msg and "\n" not in msg


def test_good_correction_files_still_load(tmp_path, corrections):
    for method, doc in corrections.items():
        path = tmp_path / f"{method}.json"
        path.write_text(json.dumps(doc))
        c = read_correction(path)
        write_correction(c, path)
        assert read_correction(path).method == method
