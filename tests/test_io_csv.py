"""Couplings CSV export/import: documented header, exact round trip, bad input."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from openemt.geometry import pose_from_vector
from openemt.io import Dataset, export_csv, import_csv


def _ds(rng, n=25, complex_=True, poses=True, n_so=3, n_se=3):
    C = rng.normal(size=(n, n_so, n_se))
    if complex_:
        C = C + 1j * rng.normal(size=C.shape) * 1e-3
    pv = np.column_stack([rng.normal(size=(n, 3)) * 0.1, rng.uniform(-1, 1, (n, 3))])
    return Dataset(couplings=C, stage=rng.normal(size=(n, 6)),
                   source_fixture=rng.choice(["YoutZup", "XinYup"], n),
                   sensor_fixture=rng.choice(["ZinYup", "YoutZup"], n),
                   pattern=rng.choice(["md", "ld"], n), file_index=rng.integers(0, 2, n),
                   files=("f1.dat", "f2, with comma.dat"),
                   poses=pose_from_vector(pv) if poses else None)


@pytest.mark.parametrize("complex_, poses", [(True, True), (False, False), (True, False)])
def test_round_trip(tmp_path, complex_, poses):
    ds = _ds(np.random.default_rng(0), complex_=complex_, poses=poses)
    back = import_csv(export_csv(ds, tmp_path / "c.csv"))
    np.testing.assert_array_equal(back.couplings, ds.couplings)     # repr precision: exact
    assert back.couplings.dtype == ds.couplings.dtype
    np.testing.assert_array_equal(back.stage, ds.stage)
    for name in ("source_fixture", "sensor_fixture", "pattern"):
        np.testing.assert_array_equal(getattr(back, name), getattr(ds, name))
    np.testing.assert_array_equal(back.file_names(), ds.file_names())
    if poses:
        np.testing.assert_allclose(back.poses, ds.poses, rtol=0, atol=1e-14)
    else:
        assert back.poses is None


def test_header_documented_columns(tmp_path):
    ds = _ds(np.random.default_rng(1), n_so=2, n_se=3)
    export_csv(ds, tmp_path / "c.csv")
    lines = (tmp_path / "c.csv").read_text().splitlines()
    assert lines[0].startswith("# openemt couplings csv v1; pose=truth;")
    header = next(csv.reader([lines[1]]))
    c_names = [f"c_{i}_{j}" for i in range(2) for j in range(3)]
    assert header == (["x", "y", "z", "rx", "ry", "rz"] + c_names + [c + "_im" for c in c_names]
                      + ["stage_x", "stage_y", "stage_z", "stage_a", "stage_b", "stage_c",
                         "source_fixture", "sensor_fixture", "pattern", "file"])
    assert len(lines) == 2 + ds.n_samples


def test_minimal_foreign_csv(tmp_path):
    (tmp_path / "m.csv").write_text("x,y,z,rx,ry,rz,c_0_0,c_0_1,c_1_0,c_1_1\n"
                                    "0.1,0,0,0,0,0,1.5,2,3,4\n\n0.2,0,0,0,0,0.5,5,6,7,8e-3\n")
    ds = import_csv(tmp_path / "m.csv")
    assert ds.couplings.shape == (2, 2, 2) and ds.couplings.dtype == np.float64
    assert ds.couplings[1, 1, 1] == 8e-3 and ds.poses[0, 0, 3] == 0.1
    np.testing.assert_array_equal(ds.stage, 0.0)
    assert ds.file_index.tolist() == [-1, -1] and ds.files == ()


@pytest.mark.parametrize("text, match", [
    ("x,y,z,rx,ry,c_0_0\n1,2,3,4,5,6\n", r"expected columns .*without \['rz'\]"),
    ("x,y,z,rx,ry,rz\n1,2,3,4,5,6\n", "coupling columns"),
    ("x,y,z,rx,ry,rz,c_0_0,c_1_1\n1,2,3,4,5,6,7,8\n", "expected column c_0_1"),
    ("x,y,z,rx,ry,rz,c_0_0\n1,2,3,4,5,6,7\n1,2,3\n", "line 3: expected 7 fields, got 3"),
    ("# c\nx,y,z,rx,ry,rz,c_0_0\n1,2,3,4,5,six,7\n",
     "line 3: column 'rz': expected a number, got 'six'"),
    ("", "empty file"),
    ("# pose=weird\nx,y,z,rx,ry,rz,c_0_0\n", "pose=truth or pose=stage"),
])
def test_bad_csv(tmp_path, text, match):
    (tmp_path / "b.csv").write_text(text)
    with pytest.raises(ValueError, match=match):
        import_csv(tmp_path / "b.csv")
