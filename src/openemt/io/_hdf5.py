"""Datasets on disk: one HDF5 file per dataset (``docs/data-format.md``).

Complex arrays are stored as two float64 datasets ``<name>_real`` and ``<name>_imag`` so that
any HDF5 reader (MATLAB ``h5read``, h5py, HDFView) gets plain numeric arrays. Large files can be
read lazily in row blocks through :func:`open_dataset_couplings`.
"""

from __future__ import annotations

import json
from contextlib import contextmanager
from pathlib import Path
from typing import Self

import numpy as np

from .. import __version__
from .._errors import InputError
from ._dataset import Dataset, signed_real
from ._h5safe import SEAL_SIZE, check_rows, open_h5
from ._h5write import atomic_h5
from ._jsontext import loads_json

__all__ = ["DATASET_SCHEMA", "DATASET_SCHEMA_VERSION", "CouplingReader", "open_dataset_couplings",
           "read_dataset", "write_dataset"]

DATASET_SCHEMA = "openemt.dataset"
DATASET_SCHEMA_VERSION = 1

#: Rows per HDF5 chunk of the per-row arrays (a chunk of couplings is ~4.7 MB for 3x3 real).
CHUNK_ROWS = 65536

_UNITS = {
    "couplings": "1 (coupling, arbitrary hardware scale; C[k, i, j] = source i into sensor j)",
    "stage": "m, m, m, rad, rad, rad ([x, y, z, a, b, c], rotation Rz(c) Ry(b) Rx(a))",
    "stage_logged": "m, m, m, rad, rad, rad",
    "poses": "homogeneous 4x4, translation in m (sensor frame -> source frame)",
    "source_signs": "1 (+1/-1)",
    "sensor_signs": "1 (+1/-1)",
    "file_index": "index into /files (-1: none)",
}


def _expected(got: str) -> InputError:
    return InputError(f"expected an openemt dataset HDF5 file with schema_version "
                      f"{DATASET_SCHEMA_VERSION} (schema {DATASET_SCHEMA!r}), got {got}")


@contextmanager
def _damaged(path: Path):
    """Turn the HDF5 library's errors on a damaged file (failed checksums, unreadable object
    headers: ``OSError``, ``RuntimeError`` or h5py's ``KeyError`` for an object it cannot open)
    into one clear error naming the user's file."""
    try:
        yield
    except (OSError, RuntimeError, KeyError) as exc:
        if isinstance(exc, FileNotFoundError):
            raise
        raise _expected(f"{path.name}, which is damaged "
                        f"({' '.join(str(exc).split())[:100]})") from None


def _str_dtype():
    import h5py
    return h5py.string_dtype(encoding="utf-8")


def _write_array(group, name: str, a: np.ndarray, units: str | None = None) -> None:
    a = np.asarray(a)
    if a.dtype.kind in "USO":
        group.create_dataset(name, data=a.astype(str).astype(object), dtype=_str_dtype())
        return
    if a.dtype.kind == "b":
        a = a.astype(np.uint8)
    chunks = None
    if a.ndim >= 1 and all(a.shape):  # HDF5 chunks must be non-empty (pose-only datasets)
        chunks = (min(a.shape[0], CHUNK_ROWS),) + a.shape[1:]
    parts = [("_real", a.real), ("_imag", a.imag)] if a.dtype.kind == "c" else [("", a)]
    for suffix, data in parts:
        # Fletcher-32 checksums on chunked data: a damaged file is an error, not wrong numbers
        ds = group.create_dataset(name + suffix, data=data, chunks=chunks,
                                  fletcher32=chunks is not None)
        if suffix:
            ds.attrs["complex_part"] = suffix[1:]
        if units is not None:
            ds.attrs["units"] = units


def write_dataset(ds: Dataset, path) -> Path:
    """Write a Dataset to one HDF5 file (atomically: a failure leaves no file).

    Layout: root attributes ``schema``, ``schema_version``, ``openemt_version``, ``n_samples``,
    ``n_source``, ``n_sensor``, ``couplings_complex``, ``meta`` (JSON); datasets
    ``couplings_real`` [+ ``couplings_imag``], ``stage``, ``source_fixture``, ``sensor_fixture``,
    ``pattern``, ``file_index``, ``files`` and the optional ``stage_logged``, ``poses``,
    ``source_signs``, ``sensor_signs``; group ``extra``. See docs/data-format.md.
    """
    if not isinstance(ds, Dataset):
        raise TypeError(f"expected a Dataset, got {type(ds).__name__}")
    try:
        meta_json = json.dumps(ds.meta, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise InputError(f"expected JSON-serialisable dataset `meta`, got {exc}") from None
    path = Path(path)
    # libver="latest": the newest object-header format, whose metadata carry checksums, so a
    # damaged header is refused on open instead of being parsed (HDF5 >= 1.10 reads it)
    with atomic_h5(path, seal=True, libver="latest", userblock_size=SEAL_SIZE) as f:
        _write_contents(f, ds, meta_json)
    return path


def _write_contents(f, ds: Dataset, meta_json: str) -> None:
    f.attrs["schema"] = DATASET_SCHEMA
    f.attrs["schema_version"] = DATASET_SCHEMA_VERSION
    f.attrs["openemt_version"] = __version__
    f.attrs["n_samples"] = ds.n_samples
    f.attrs["n_source"] = ds.n_source
    f.attrs["n_sensor"] = ds.n_sensor
    f.attrs["couplings_complex"] = bool(np.iscomplexobj(ds.couplings))
    f.attrs["meta"] = meta_json
    # couplings_real always exists; couplings_imag only for complex couplings
    _write_array(f, "couplings" if np.iscomplexobj(ds.couplings) else "couplings_real",
                 ds.couplings, _UNITS["couplings"])
    _write_array(f, "stage", ds.stage, _UNITS["stage"])
    for name in ("source_fixture", "sensor_fixture", "pattern"):
        _write_array(f, name, getattr(ds, name))
    _write_array(f, "file_index", ds.file_index, _UNITS["file_index"])
    f.create_dataset("files", data=np.array(list(ds.files), dtype=object),
                     dtype=_str_dtype(), shape=(len(ds.files),))
    for name in ("stage_logged", "poses", "source_signs", "sensor_signs"):
        v = getattr(ds, name)
        if v is not None:
            _write_array(f, name, v, _UNITS[name])
    g = f.create_group("extra")
    for k, v in ds.extra.items():
        if "/" in k or k.endswith(("_real", "_imag")):
            raise InputError(f"expected extra names without '/' or a _real/_imag suffix, "
                             f"got {k!r}")
        _write_array(g, k, np.asarray(v))


def _open(path):
    """Open (through :func:`~openemt.io._h5safe.open_h5`: a regular file that holds what it
    declares) and check the header; returns the h5py.File (caller closes)."""
    path = Path(path)
    f = open_h5(path, f"an openemt dataset HDF5 file with schema_version "
                      f"{DATASET_SCHEMA_VERSION} (schema {DATASET_SCHEMA!r})")
    try:
        with _damaged(path):
            _check_header(f, path)
    except BaseException:
        f.close()
        raise
    return f


def _check_header(f, path: Path) -> None:
    schema = f.attrs.get("schema")
    version = f.attrs.get("schema_version")
    if isinstance(schema, bytes):
        schema = schema.decode()
    if schema != DATASET_SCHEMA or version is None:
        raise _expected(f"{path.name} with schema {schema!r} and schema_version {version!r}")
    if int(version) > DATASET_SCHEMA_VERSION:
        raise _expected(f"{path.name} with newer schema_version {int(version)} "
                        f"(upgrade openemt)")
    for name in ("couplings_real", "stage", "source_fixture", "sensor_fixture", "pattern",
                 "file_index", "files"):
        if name not in f:
            raise _expected(f"{path.name} without the required dataset {name!r}")
    if bool(f.attrs.get("couplings_complex", False)) and "couplings_imag" not in f:
        raise _expected(f"{path.name} without 'couplings_imag' although couplings_complex "
                        "is set")
    for name in ("couplings_real", "couplings_imag"):
        d = f.get(name)
        if d is None:
            continue
        if not hasattr(d, "dtype") or d.ndim != 3 or d.dtype.kind not in "fiu":
            got = (f"a {len(d.shape)}-D {d.dtype} array" if hasattr(d, "dtype")
                   else "a group")
            raise _expected(f"{path.name} whose {name!r} is {got} instead of a 3-D numeric "
                            "array (N, n_source, n_sensor)")
    if "couplings_imag" in f and f["couplings_imag"].shape != f["couplings_real"].shape:
        raise _expected(f"{path.name} whose 'couplings_imag' shape "
                        f"{f['couplings_imag'].shape} differs from 'couplings_real' "
                        f"{f['couplings_real'].shape}")
    _check_rows(f, path)


#: the fixture and pattern columns of a dataset file: (N,) like couplings_real, or one scalar
#: string for all rows
_ROWS_OR_SCALAR = ("source_fixture", "sensor_fixture", "pattern")


def _check_rows(f, path: Path) -> None:
    """Every per-row array declares the row count of the couplings (checked on the declared
    shapes, before anything is read or allocated)."""
    import h5py

    n, n_source, n_sensor = f["couplings_real"].shape
    check_rows(f, path.name, n, {"stage": (6,), "file_index": (), "stage_logged": (6,),
                                 "poses": (4, 4), "source_signs": (n_source,),
                                 "sensor_signs": (n_sensor,)}, reference="couplings_real")
    check_rows(f, path.name, n, {k: () for k in _ROWS_OR_SCALAR
                                 if getattr(f[k], "shape", None) != ()},
               reference="couplings_real")
    g = f.get("extra")
    if isinstance(g, h5py.Group):
        check_rows(f, path.name, n, [f"extra/{k}" for k in g],
                   reference="couplings_real")


def _read_array(group, name: str):
    if name + "_real" in group:
        re_ = group[name + "_real"][()]
        if name + "_imag" in group:
            return re_ + 1j * group[name + "_imag"][()]
        return re_
    if name not in group:
        return None
    d = group[name]
    if d.dtype.kind == "O" or _h5_is_string(d):
        return np.array(d.asstr()[()], dtype=str) if d.shape != () else str(d.asstr()[()])
    return d[()]


def _h5_is_string(d) -> bool:
    import h5py
    return h5py.check_string_dtype(d.dtype) is not None


def read_dataset(path) -> Dataset:
    """Read a whole dataset file written by :func:`write_dataset`.

    Missing, non-HDF5 or foreign files raise a one-line ``FileNotFoundError``/``ValueError``:
    ``expected an openemt dataset HDF5 file with schema_version 1 ..., got ...``.

    Examples
    --------
    >>> import pathlib, tempfile
    >>> import openemt
    >>> md = openemt.import_ilemt_folder(openemt.datasets.path("cal_9_15_premo_cmu"),
    ...                                  patterns="md")
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     path = openemt.write_dataset(md, pathlib.Path(tmp) / "md.h5")
    ...     back = openemt.read_dataset(path)
    >>> len(back), back.n_source, back.n_sensor, bool((back.couplings == md.couplings).all())
    (852, 3, 3, True)
    """
    path = Path(path)
    f = _open(path)
    try:
        with _damaged(path):
            return _read_open(f, path)
    finally:
        f.close()


def _read_open(f, path: Path) -> Dataset:
    meta_text = f.attrs.get("meta", "{}")
    if isinstance(meta_text, bytes):
        meta_text = meta_text.decode("utf-8", errors="replace")
    if not isinstance(meta_text, str):
        raise _expected(f"{path.name} with a `meta` attribute that is not JSON text")
    meta = loads_json(meta_text, "a JSON `meta` attribute", path.name)
    if not isinstance(meta, dict):
        raise _expected(f"{path.name} whose `meta` is a JSON {type(meta).__name__}, "
                        "not an object")
    extra = {}
    if "extra" in f:
        g = f["extra"]
        names = sorted({k[:-5] if k.endswith(("_real", "_imag")) else k for k in g})
        extra = {k: _read_array(g, k) for k in names}
    try:
        return Dataset(
            couplings=_read_array(f, "couplings"),
            stage=f["stage"][()],
            source_fixture=_read_array(f, "source_fixture"),
            sensor_fixture=_read_array(f, "sensor_fixture"),
            pattern=_read_array(f, "pattern"),
            file_index=f["file_index"][()],
            files=tuple(_read_array(f, "files").tolist()),
            stage_logged=_read_array(f, "stage_logged"),
            poses=_read_array(f, "poses"),
            source_signs=_read_array(f, "source_signs"),
            sensor_signs=_read_array(f, "sensor_signs"),
            extra=extra,
            meta=meta,
        )
    except (TypeError, ValueError) as exc:
        raise _expected(f"{path.name} with inconsistent contents: {exc}") from None


class CouplingReader:
    """Lazy, row-block access to the couplings of a dataset file.

    Behaves like a read-only array of shape ``(N, n_source, n_sensor)`` (complex128 or
    float64): ``reader[a:b]`` reads only rows ``a:b`` from disk. It has ``shape``, ``dtype``,
    ``ndim`` and ``__getitem__``, so ``dask.array.from_array(reader, chunks=(R, n_so, n_se))``
    streams it; it pickles by path (each worker reopens the file), so it works with
    ``dask.distributed`` too. Use as a context manager or call :meth:`close`.

    Parameters
    ----------
    path : path-like
        A dataset file written by :func:`write_dataset`.
    real : bool
        Return signed real couplings ``sign(Re z)|z|`` (what the pose solvers take) instead of
        the stored complex values.
    """

    def __init__(self, path, *, real: bool = False):
        self.path = Path(path)
        self.real = bool(real)
        self._file = None
        f = _open(self.path)
        try:
            self._set_handles(f)
        except BaseException:
            f.close()
            raise

    def _set_handles(self, f) -> None:
        self._file = f
        self._re = f["couplings_real"]
        self._im = f.get("couplings_imag", None)
        self.shape = tuple(self._re.shape)
        self.ndim = len(self.shape)
        self.is_complex = self._im is not None
        self.dtype = np.dtype(np.complex128 if self.is_complex and not self.real else np.float64)
        self.chunk_rows = (self._re.chunks or self.shape)[0]

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, key) -> np.ndarray:
        if self._file is None:
            self._set_handles(_open(self.path))
        with _damaged(self.path):
            a = self._re[key]
            if self._im is None:
                return np.asarray(a, dtype=np.float64)
            C = a + 1j * self._im[key]
        return signed_real(C) if self.real else C

    def read(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Rows ``start:stop`` as an array ``(stop - start, n_source, n_sensor)``."""
        return self[slice(start, stop)]

    def iter_blocks(self, rows: int | None = None):
        """Yield ``(start, block)`` over the whole file in blocks of ``rows`` rows."""
        rows = int(rows or self.chunk_rows or 65536)
        if rows < 1:
            raise InputError(f"expected a positive block size, got {rows}")
        for start in range(0, self.shape[0], rows):
            yield start, self[start:start + rows]

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __getstate__(self):
        return {"path": self.path, "real": self.real}

    def __setstate__(self, state):
        self.__init__(state["path"], real=state["real"])

    def __repr__(self) -> str:
        return (f"CouplingReader({str(self.path)!r}, shape={self.shape}, dtype={self.dtype}, "
                f"real={self.real})")


def open_dataset_couplings(path, *, real: bool = False) -> CouplingReader:
    """Open the couplings of a dataset file for lazy row-block reads.

    Example (10 million rows, streamed through Dask)::

        with open_dataset_couplings("big.h5", real=True) as C:
            X = dask.array.from_array(C, chunks=(C.chunk_rows, C.shape[1], C.shape[2]))
            ...

    The per-row side arrays (``stage``, fixtures, ...) can be read the same way with h5py:
    ``h5py.File(path)["stage"][a:b]``.
    """
    return CouplingReader(path, real=real)
