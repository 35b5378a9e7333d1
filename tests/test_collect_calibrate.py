"""``calibrate --mode reference`` refuses what no calibration can come from: data without
reference poses, and a fit whose reference residual is many times the stated reference noise
(unless --accept-reference-residual)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np

from openemt.calibrate._reference import REFERENCE_RESIDUAL_FACTOR
from openemt.io import write_dataset
from openemt.simulate import simulate_reference


def test_calibrate_refuses_a_reference_that_does_not_belong(run_cli, tmp_path):
    ds = simulate_reference("concentric", "robot", 30, seed=4)
    B = ds.extra["reference_poses"]
    bad = dataclasses.replace(ds, extra={**ds.extra, "reference_poses": np.roll(B, 3, axis=0)})
    write_dataset(ds, tmp_path / "good.h5")
    write_dataset(bad, tmp_path / "bad.h5")
    code, out, err = run_cli("calibrate", tmp_path / "good.h5", "--mode", "reference", "--json")
    assert code == 0, err
    w = json.loads(out)["weighting"]
    assert w["reference_residual_trans_m"] < REFERENCE_RESIDUAL_FACTOR * 0.05e-3
    code, out, err = run_cli("calibrate", tmp_path / "bad.h5", "--mode", "reference", "-o",
                             tmp_path / "cal.json")
    assert code == 2 and err.count("error:") == 1 and "stated reference noise" in err, err
    assert not (tmp_path / "cal.json").exists()
    code, out, err = run_cli("calibrate", tmp_path / "bad.h5", "--mode", "reference",
                             "--accept-reference-residual", "--json")
    assert code == 0, err


def test_calibrate_reference_refuses_data_without_reference_poses(run_cli, tmp_path):
    ds = simulate_reference("concentric", "robot", 20, seed=4)
    extra = {k: v for k, v in ds.extra.items() if k != "reference_poses"}
    write_dataset(dataclasses.replace(ds, extra=extra), tmp_path / "plain.h5")
    code, out, err = run_cli("calibrate", tmp_path / "plain.h5", "--mode", "reference")
    assert code == 2 and err.count("error:") == 1 and "reference poses" in err, err
