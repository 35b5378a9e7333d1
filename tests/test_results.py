"""Result objects: frozen dataclasses with typed fields and a JSON-ready ``to_dict()``."""

from __future__ import annotations

import copy
import dataclasses
import json
import pickle

import numpy as np
import pytest

from openemt import calibrate, evaluate, paper

RESULT_CLASSES = [
    calibrate.ResidueStats, calibrate.HeldOutTest, calibrate.CrossValidation,
    calibrate.ImprovedTest, paper.ParameterRecovery, paper.DipoleCost,
    evaluate.ErrorSummary, evaluate.UncertaintySummary, evaluate.Characterization,
    evaluate.SweepTable, evaluate.SweepAnalysis, paper.Table2Reproduction,
    paper.Table3Reproduction, paper.Table4Reproduction, paper.CalibrationCharacterization,
]


@pytest.mark.parametrize("cls", RESULT_CLASSES, ids=lambda c: c.__name__)
def test_result_classes_are_documented_frozen_dataclasses(cls):
    assert dataclasses.is_dataclass(cls)
    assert cls.__dataclass_params__.frozen
    assert callable(cls.to_dict)
    assert "Attributes" in cls.__doc__


def test_error_summary_is_a_read_only_dict_with_the_same_keys():
    s = evaluate.error_summary(np.array([1e-3, 2e-3, np.inf]), np.array([0.01, 0.02, 0.0]))
    assert list(s) == ["trans_rms_mm", "trans_max_mm", "trans_p50_mm", "trans_p95_mm",
                       "rot_rms_deg", "rot_max_deg", "rot_p50_deg", "rot_p95_deg", "n",
                       "n_nonfinite"]
    assert s["trans_max_mm"] == s.trans_max_mm == pytest.approx(2.0)
    assert s.n == 3 and s.n_nonfinite == 1
    assert s.to_dict() == dict(s)
    assert json.loads(json.dumps(s)) == dict(s)
    with pytest.raises(TypeError, match="read-only"):
        s["n"] = 4
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.n = 4
    for other in (copy.deepcopy(s), pickle.loads(pickle.dumps(s))):
        assert type(other) is type(s) and other == s and other.n == 3


def test_uncertainty_summary_extends_error_summary():
    u = evaluate.uncertainty_summary(np.full(4, 3e-4), np.zeros(4), stage_uncertainty_m=4e-4)
    assert isinstance(u, evaluate.ErrorSummary)
    assert u.u_P_trans_mm == pytest.approx(0.5)
    assert list(u)[-6:] == ["u_cal_trans_mm", "u_P_trans_mm", "u_cal_rot_deg", "u_P_rot_deg",
                            "u_stage_trans_mm", "u_stage_rot_deg"]


def test_plain_result_to_dict_and_deprecated_indexing():
    cv = calibrate.CrossValidation(trans_rms_mm=np.float64(0.2), rot_rms_deg=0.1, n=9)
    d = cv.to_dict()
    assert d == {"trans_rms_mm": 0.2, "rot_rms_deg": 0.1, "n": 9}
    assert type(d["trans_rms_mm"]) is float
    json.dumps(d)
    with pytest.warns(DeprecationWarning, match="attributes"):
        assert cv["n"] == 9


def test_to_dict_leaves_out_per_row_arrays():
    t = calibrate.HeldOutTest(trans=np.zeros(3), rot=np.zeros(3),
                              summary=evaluate.error_summary(np.zeros(3), np.zeros(3)),
                              n_invalid=0, poses=np.tile(np.eye(4), (3, 1, 1)))
    assert set(t.to_dict()) == {"summary", "n_invalid"}
    assert t.to_dict()["summary"]["n"] == 3
