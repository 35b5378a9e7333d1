"""ILEMT calibration ``.mat`` files -> :class:`Calibration` (docs/ilemt-data.md#calibration-mat)."""

from __future__ import annotations

import struct
import warnings
import zlib
from pathlib import Path

import numpy as np

from .. import __version__
from .._errors import InputError
from ..field import ILEMT_GAIN, DipoleModel
from ._calibration import Calibration, check_correction_matrix, check_model_moments
from ._ilemt import file_sha256
from ._isolated import run_isolated
from ._safefile import MAX_JSON_BYTES, check_regular

__all__ = ["read_ilemt_calibration"]


_QUADRUPOLE_FIELDS = ("q_source_pos", "q_source_moment", "q_sensor_pos", "q_sensor_moment",
                      "q_source_distance", "q_sensor_distance", "pin_quadrupole")


def _jsonable(v):
    """MATLAB struct / cell / numeric values -> plain JSON types (lists, dicts, str, numbers)."""
    if hasattr(v, "_fieldnames"):
        return {k: _jsonable(getattr(v, k)) for k in v._fieldnames}
    if isinstance(v, np.ndarray):
        if v.dtype == object:
            return [_jsonable(x) for x in v.tolist()] if v.ndim else _jsonable(v.item())
        if v.dtype.kind in "US":
            return v.tolist()
        if v.dtype.kind == "b":
            return v.tolist()
        if v.dtype.kind in "iu":
            return v.astype(np.int64).tolist()
        if v.dtype.kind == "f":
            return [_jsonable(x) for x in v.tolist()] if v.ndim else _jsonable(float(v))
        if v.dtype.kind == "c":
            return {"real": _jsonable(v.real), "imag": _jsonable(v.imag)}
        return str(v)
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, np.generic):
        return _jsonable(v.item())
    if isinstance(v, float):
        return v if np.isfinite(v) else None
    if isinstance(v, (bool, int, str)) or v is None:
        return v
    if isinstance(v, bytes):
        return v.decode("utf-8", errors="replace")
    return str(v)


def _names(v) -> tuple[str, ...]:
    """A MATLAB cell of strings (squeezed: str, or object array) -> tuple of str."""
    if v is None:
        return ()
    if isinstance(v, str):
        return (v,)
    arr = np.atleast_1d(np.asarray(v, dtype=object)).ravel()
    return tuple(str(x) for x in arr.tolist() if isinstance(x, str))


def _matrix(d: dict, key: str, shape, path: Path) -> np.ndarray:
    if key not in d:
        raise InputError(f"{path.name}: expected an ILEMT calibration with variable {key!r}, "
                         f"got variables {sorted(k for k in d if not k.startswith('__'))}")
    a = np.asarray(d[key])
    if a.dtype.kind not in "iuf" or a.shape != shape:
        raise InputError(f"{path.name}: expected {key!r} to be a real {shape} array, "
                         f"got {a.dtype} {a.shape}")
    a = a.astype(np.float64)
    if not np.all(np.isfinite(a)):
        raise InputError(f"{path.name}: expected finite numbers in {key!r}, got "
                         f"{int((~np.isfinite(a)).sum())} NaN/inf")
    return a


#: seconds the MATLAB reader may take for a calibration file (a few kB) before it is refused
MAT_READ_TIMEOUT_S = 20.0


def _loadmat(path: str) -> dict:
    import scipy.io

    return scipy.io.loadmat(path, squeeze_me=True, struct_as_record=False)


def read_ilemt_calibration(path) -> Calibration:
    """Load an ILEMT calibration ``.mat`` file (MATLAB v5, one variable per field).

    Parameters
    ----------
    path : path-like
        E.g. ``output/XYZ_hr_cal.mat`` or ``base_calibration.mat``.

    Returns
    -------
    Calibration
        ``model`` = ``DipoleModel(d_source_pos, d_source_moment, d_sensor_pos,
        d_sensor_moment, gain=1/250)``; the three fixtures; ``linear_correction`` when present;
        ``stats`` as a dict; ``mode`` = ``options.cal_mode`` (``+ "_concentric"`` for concentric
        calibrations); ``free``/``frozen`` = ``options.optimize``/``options.freeze``;
        ``provenance`` with the file hash and all ILEMT ``options``; quadrupole terms in
        ``extra["quadrupole"]`` (a warning is issued if any quadrupole moment is non-zero,
        since the dipole model ignores them).
    """
    from scipy.io.matlab import MatReadError

    path = Path(path)
    st = check_regular(path, "an ILEMT calibration .mat file")
    if st.st_size > MAX_JSON_BYTES:
        raise InputError(f"expected an ILEMT calibration .mat file of at most "
                         f"{MAX_JSON_BYTES >> 20} MiB, got {path.name} of {st.st_size} bytes")
    # scipy's MATLAB reader is compiled code that can crash the interpreter on a damaged file
    # (seen: a segmentation fault), so it runs in a child process (io/_isolated.py)
    out = run_isolated(_loadmat, (str(path),), timeout=MAT_READ_TIMEOUT_S)
    if out.kind != "ok":
        exc = out.value
        # MemoryError: a damaged header declaring an array far larger than the file (a
        # calibration file is a few kB), which the reader tries to allocate; ArithmeticError:
        # damaged sizes the reader divides by (ZeroDivisionError seen)
        if out.kind == "raised" and not isinstance(
                exc, (ValueError, TypeError, OSError, KeyError, IndexError, EOFError,
                      NotImplementedError, MatReadError, zlib.error, struct.error,
                      MemoryError, ArithmeticError)):
            raise exc
        why = {"timeout": f"no answer within {MAT_READ_TIMEOUT_S:g} s",
               "died": f"the MATLAB reader crashed (exit {exc})"}.get(
            out.kind, f"{type(exc).__name__}: {' '.join(str(exc).split())[:120]}")
        raise InputError(f"expected an ILEMT calibration .mat file (MATLAB v5), got "
                         f"{path.name} that cannot be read ({why})")
    d = out.value
    model = DipoleModel(
        L_so=_matrix(d, "d_source_pos", (3, 3), path),
        M_so=_matrix(d, "d_source_moment", (3, 3), path),
        L_se=_matrix(d, "d_sensor_pos", (3, 3), path),
        M_se=_matrix(d, "d_sensor_moment", (3, 3), path),
        gain=ILEMT_GAIN,
    )
    check_model_moments(model, f"{path.name}: ")
    fixtures = {k: _matrix(d, k, (6,), path)
                for k in ("source_fixture", "stage_fixture", "sensor_fixture")}
    L = None
    if "linear_correction" in d:
        L = check_correction_matrix(_matrix(d, "linear_correction", (4, 4), path),
                                    where=f"{path.name}: ")

    stats = _jsonable(d["stats"]) if "stats" in d else {}
    if not isinstance(stats, dict):
        stats = {"value": stats}
    options = _jsonable(d["options"]) if "options" in d else {}
    if not isinstance(options, dict):
        options = {"value": options}
    opt = d.get("options")
    cal_mode = str(getattr(opt, "cal_mode", "")) if opt is not None else ""
    concentric = bool(np.asarray(getattr(opt, "concentric", 0)).any()) if opt is not None else False
    mode = cal_mode + ("_concentric" if concentric else "") if cal_mode else "ilemt"
    free = _names(getattr(opt, "optimize", None)) if opt is not None else ()
    frozen = _names(getattr(opt, "freeze", None)) if opt is not None else ()

    quad = {k: _jsonable(d[k]) for k in _QUADRUPOLE_FIELDS if k in d}
    moments = [np.asarray(d[k], dtype=np.float64) for k in ("q_source_moment", "q_sensor_moment")
               if k in d]
    if any(np.any(m != 0) for m in moments):
        warnings.warn(f"{path.name}: non-zero quadrupole moments are ignored by the dipole model",
                      stacklevel=2)
    extra = {"quadrupole": quad} if quad else {}
    provenance = {
        "format": "ilemt-mat",
        "importer": "openemt.io.read_ilemt_calibration",
        "openemt_version": __version__,
        "file": path.name,
        "inputs": {path.name: file_sha256(path)},
        "concentric": concentric,
        "ilemt_options": options,
    }
    return Calibration(model=model, linear_correction=L, mode=mode, free=free, frozen=frozen,
                       stats=stats, provenance=provenance, extra=extra, **fixtures)
