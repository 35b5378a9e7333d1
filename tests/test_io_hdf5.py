"""HDF5 dataset files: exact round trips, lazy row-block reads, one-line errors."""

from __future__ import annotations

import pickle

import h5py
import numpy as np
import pytest

from openemt.geometry import pose_from_vector
from openemt.io import Dataset, open_dataset_couplings, read_dataset, write_dataset


def _random_dataset(rng, n=37, n_so=3, n_se=2, complex_=True, poses=True):
    C = rng.normal(size=(n, n_so, n_se))
    if complex_:
        C = C + 1j * rng.normal(size=C.shape) * 1e-3
    pv = np.column_stack([rng.normal(size=(n, 3)) * 0.1, rng.normal(size=(n, 3))])
    return Dataset(
        couplings=C, stage=rng.normal(size=(n, 6)),
        source_fixture=rng.choice(["YoutZup", "XoutZup"], n),
        sensor_fixture=rng.choice(["ZinYup", "ZinXdown"], n),
        pattern=rng.choice(["md", "ld", "bloc µ"], n),
        file_index=rng.integers(0, 2, n), files=("a.dat", "b – ünïcode.dat"),
        stage_logged=rng.normal(size=(n, 6)),
        poses=pose_from_vector(pv) if poses else None,
        source_signs=rng.choice([-1.0, 1.0], (n, n_so)),
        sensor_signs=None,
        extra={"couplings_lr": C * 0.03, "temperature": rng.normal(size=n),
               "label": np.array([f"r{i}" for i in range(n)])},
        meta={"source": {"name": "cube"}, "provenance": {"inputs": {"a.dat": "00ff"}},
              "notes": ["x", 1.5, None]},
    )


def _assert_same(a: Dataset, b: Dataset):
    for name in ("couplings", "stage", "source_fixture", "sensor_fixture", "pattern",
                 "file_index", "stage_logged", "poses", "source_signs", "sensor_signs"):
        x, y = getattr(a, name), getattr(b, name)
        if x is None:
            assert y is None, name
            continue
        assert x.dtype == y.dtype, name
        np.testing.assert_array_equal(x, y, err_msg=name)
    assert a.files == b.files and a.meta == b.meta
    assert set(a.extra) == set(b.extra)
    for k in a.extra:
        np.testing.assert_array_equal(a.extra[k], b.extra[k], err_msg=k)
        assert np.asarray(a.extra[k]).dtype.kind == b.extra[k].dtype.kind


@pytest.mark.parametrize("complex_, poses", [(True, True), (False, False)])
def test_round_trip_exact(tmp_path, complex_, poses):
    ds = _random_dataset(np.random.default_rng(0), complex_=complex_, poses=poses)
    p = write_dataset(ds, tmp_path / "d.h5")
    _assert_same(ds, read_dataset(p))


def test_layout_is_plain_numeric_for_other_tools(tmp_path):
    ds = _random_dataset(np.random.default_rng(1))
    write_dataset(ds, tmp_path / "d.h5")
    with h5py.File(tmp_path / "d.h5") as f:
        assert f.attrs["schema"] == "openemt.dataset" and f.attrs["schema_version"] == 1
        assert f["couplings_real"].dtype == np.float64 and f["couplings_imag"].shape == (37, 3, 2)
        assert "units" in f["stage"].attrs
        assert h5py.check_string_dtype(f["pattern"].dtype).encoding == "utf-8"
        np.testing.assert_array_equal(f["extra/couplings_lr_imag"][()], ds.extra["couplings_lr"].imag)


def test_empty_dataset_round_trip(tmp_path):
    ds = Dataset(couplings=np.zeros((0, 3, 3)), stage=np.zeros((0, 6)), source_fixture=[],
                 sensor_fixture=[], pattern=[], file_index=np.zeros(0, int))
    _assert_same(ds, read_dataset(write_dataset(ds, tmp_path / "e.h5")))


def test_lazy_reader_blocks_pickle_and_dask(tmp_path):
    ds = _random_dataset(np.random.default_rng(2), n=1000)
    write_dataset(ds, tmp_path / "d.h5")
    with open_dataset_couplings(tmp_path / "d.h5") as r:
        assert r.shape == (1000, 3, 2) and r.dtype == np.complex128 and len(r) == 1000
        np.testing.assert_array_equal(r[100:250], ds.couplings[100:250])
        np.testing.assert_array_equal(r.read(990), ds.couplings[990:])
        blocks = list(r.iter_blocks(300))
        assert [s for s, _ in blocks] == [0, 300, 600, 900]
        np.testing.assert_array_equal(np.concatenate([b for _, b in blocks]), ds.couplings)
        r2 = pickle.loads(pickle.dumps(r))
        np.testing.assert_array_equal(r2[5], ds.couplings[5])
        r2.close()
    with open_dataset_couplings(tmp_path / "d.h5", real=True) as r:
        assert r.dtype == np.float64
        da = pytest.importorskip("dask.array")
        x = da.from_array(r, chunks=(128, 3, 2))
        np.testing.assert_allclose(x.sum(axis=0).compute(), ds.signed_real().sum(axis=0),
                                   rtol=1e-12)


def test_missing_foreign_and_corrupt_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing file"):
        read_dataset(tmp_path / "none.h5")
    (tmp_path / "text.h5").write_text("hello")
    with pytest.raises(ValueError, match=r"expected an openemt dataset HDF5 file with "
                                         r"schema_version 1.*not a readable HDF5 file"):
        read_dataset(tmp_path / "text.h5")
    with h5py.File(tmp_path / "other.h5", "w") as f:
        f["x"] = 1
    with pytest.raises(ValueError, match="got other.h5 with schema None"):
        read_dataset(tmp_path / "other.h5")
    ds = _random_dataset(np.random.default_rng(3))
    write_dataset(ds, tmp_path / "d.h5")
    with h5py.File(tmp_path / "d.h5", "a") as f:
        del f["stage"]
    with pytest.raises(ValueError, match="without the required dataset 'stage'"):
        read_dataset(tmp_path / "d.h5")
    write_dataset(ds, tmp_path / "d.h5")
    raw = (tmp_path / "d.h5").read_bytes()
    (tmp_path / "cut.h5").write_bytes(raw[: len(raw) // 2])
    with pytest.raises((ValueError, OSError)) as exc:
        read_dataset(tmp_path / "cut.h5")
    assert "expected an openemt dataset HDF5 file" in str(exc.value)
    assert "\n" not in str(exc.value)
    with h5py.File(tmp_path / "d.h5", "a") as f:
        f.attrs["schema_version"] = 99
    with pytest.raises(ValueError, match="newer schema_version 99"):
        read_dataset(tmp_path / "d.h5")


def test_failed_write_leaves_no_file(tmp_path):
    ds = _random_dataset(np.random.default_rng(4))
    bad = Dataset(**{**{k: getattr(ds, k) for k in (
        "couplings", "stage", "source_fixture", "sensor_fixture", "pattern", "file_index",
        "files")}, "meta": {"x": object()}})
    with pytest.raises(ValueError, match="JSON"):
        write_dataset(bad, tmp_path / "bad.h5")
    bad2 = Dataset(**{**{k: getattr(ds, k) for k in (
        "couplings", "stage", "source_fixture", "sensor_fixture", "pattern", "file_index",
        "files")}, "extra": {"a/b": np.zeros(37)}})
    with pytest.raises(ValueError, match="extra names"):
        write_dataset(bad2, tmp_path / "bad.h5")
    assert list(tmp_path.iterdir()) == []
