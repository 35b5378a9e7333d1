"""The in-memory dataset: couplings with the motions and fixtures that produced them.

A ``Dataset`` is what every importer and the simulator produce and what calibration, solving
and evaluation consume. Its on-disk form is one HDF5 file (see ``docs/data-format.md``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from .._errors import InputError

__all__ = ["RECORDING_KEY", "Dataset", "is_recording", "recording_meta", "signed_real"]

#: ``Dataset.meta`` key whose presence says the rows are one recording, in time order
#: (consecutive samples of a moving sensor): ``openemt solve`` then solves them as a time series
RECORDING_KEY = "recording"


#: The ``extra`` key of the couplings of every carrier band.
BAND_COUPLINGS = "couplings_bands"


def recording_meta(sample_rate_hz: float | None = None, source: str = "") -> dict:
    """The ``meta[RECORDING_KEY]`` value a writer of a recording sets:
    ``{"sample_rate_hz": rate or None, "source": what recorded it}``."""
    rate = None if sample_rate_hz is None else float(sample_rate_hz)
    return {"sample_rate_hz": rate, "source": str(source)}


def is_recording(meta) -> bool:
    """True if a dataset's ``meta`` marks its rows as one recording in time order."""
    return isinstance(meta, dict) and isinstance(meta.get(RECORDING_KEY), dict)


def signed_real(C) -> np.ndarray:
    """Signed real coupling ``sign(Re z) * |z|`` elementwise (docs/ilemt-data.md#dat-format).

    Real input is returned as float64 unchanged.
    """
    C = np.asarray(C)
    if np.iscomplexobj(C):
        return np.where(C.real < 0, -1.0, 1.0) * np.abs(C)
    return C.astype(np.float64, copy=False)


def _str_array(a, n: int, name: str) -> np.ndarray:
    if isinstance(a, str):
        return np.full(n, a, dtype=object).astype(str)
    arr = np.asarray(a, dtype=str)
    if arr.shape != (n,):
        raise InputError(f"expected `{name}` to have shape ({n},), got {arr.shape}")
    return arr


@dataclass(frozen=True, eq=False)
class Dataset:
    """Couplings and, per row, the known motion that produced them.

    Attributes
    ----------
    couplings : ndarray, shape (N, n_source, n_sensor), complex128 or float64
        ``C[k, i, j]`` = source coil i into sensor coil j, sign flips already applied.
        Complex where the acquisition gives a phase (in-phase = coupling).
    stage : ndarray, shape (N, 6)
        Stage vector used for the kinematics, ``[x, y, z, a, b, c]`` in m and rad
        (rotation ``Rz(c) Ry(b) Rx(a)``), after stage-error compensation if any.
    source_fixture, sensor_fixture : ndarray of str, shape (N,)
        Manual fixture code of each row (``YoutZup``, ``ZinXdown``, ...).
    pattern : ndarray of str, shape (N,)
        Motion pattern of each row (``md``, ``ld``, ``sweep``, ``mdtrans``, ...).
    file_index : ndarray of int, shape (N,)
        Index into ``files`` of the input file each row came from (-1: none).
    files : tuple of str
        Names of the input files (or simulated blocks), in order.
    stage_logged : ndarray, shape (N, 6), optional
        Stage vector as logged, before compensation (m, rad).
    poses : ndarray, shape (N, 4, 4), optional
        Ground-truth sensor poses in the source frame, when known (simulation).
    source_signs, sensor_signs : ndarray, shape (N, n_source) / (N, n_sensor), optional
        Sign flips that were applied to rows / columns of each coupling matrix.
    extra : dict of str -> ndarray
        Further per-row arrays (first axis N), e.g. ``couplings_lr`` for ILEMT low-rate data.
    meta : dict
        Descriptions and provenance: ``source``, ``sensor`` (dicts), ``provenance`` (openemt
        version, input file SHA-256), ``units``, free-form notes. JSON-serialisable.
    """

    couplings: np.ndarray
    stage: np.ndarray
    source_fixture: np.ndarray
    sensor_fixture: np.ndarray
    pattern: np.ndarray
    file_index: np.ndarray
    files: tuple[str, ...] = ()
    stage_logged: np.ndarray | None = None
    poses: np.ndarray | None = None
    source_signs: np.ndarray | None = None
    sensor_signs: np.ndarray | None = None
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self):
        C = np.asarray(self.couplings)
        if C.ndim != 3:
            raise InputError(f"expected `couplings` to have shape (N, n_source, n_sensor), "
                             f"got {C.shape}")
        if C.dtype.kind not in "iufc":
            raise TypeError(f"expected numeric `couplings`, got dtype {C.dtype}")
        C = C.astype(np.complex128 if C.dtype.kind == "c" else np.float64, copy=False)
        n = C.shape[0]
        object.__setattr__(self, "couplings", C)
        stage = np.asarray(self.stage, dtype=np.float64)
        if stage.shape != (n, 6):
            raise InputError(f"expected `stage` to have shape ({n}, 6), got {stage.shape}")
        object.__setattr__(self, "stage", stage)
        for name in ("source_fixture", "sensor_fixture", "pattern"):
            object.__setattr__(self, name, _str_array(getattr(self, name), n, name))
        fi = np.asarray(self.file_index)
        if fi.shape != (n,) or fi.dtype.kind not in "iu":
            raise InputError(f"expected integer `file_index` of shape ({n},), got {fi.dtype} "
                             f"{fi.shape}")
        object.__setattr__(self, "file_index", fi.astype(np.int64))
        object.__setattr__(self, "files", tuple(str(f) for f in self.files))
        if fi.size and fi.max() >= len(self.files):
            raise InputError(f"expected `file_index` < {len(self.files)} (number of files), "
                             f"got {fi.max()}")
        for name, shape in (("stage_logged", (n, 6)), ("poses", (n, 4, 4)),
                            ("source_signs", (n, C.shape[1])), ("sensor_signs", (n, C.shape[2]))):
            v = getattr(self, name)
            if v is not None:
                v = np.asarray(v, dtype=np.float64)
                if v.shape != shape:
                    raise InputError(f"expected `{name}` to have shape {shape}, got {v.shape}")
                object.__setattr__(self, name, v)
        for k, v in self.extra.items():
            v = np.asarray(v)
            if v.ndim < 1 or v.shape[0] != n:
                raise InputError(f"expected extra array {k!r} to have first axis {n}, got {v.shape}")
        bands = self.extra.get(BAND_COUPLINGS)
        if bands is not None and (np.ndim(bands) != 4 or np.shape(bands)[2:] != C.shape[1:]):
            raise InputError(f"expected extra {BAND_COUPLINGS!r} of shape ({n}, n_bands, "
                             f"{C.shape[1]}, {C.shape[2]}), got {np.shape(bands)}")

    # -- shape -------------------------------------------------------------------------------
    @property
    def n_samples(self) -> int:
        return self.couplings.shape[0]

    @property
    def n_source(self) -> int:
        return self.couplings.shape[1]

    @property
    def n_sensor(self) -> int:
        return self.couplings.shape[2]

    def __len__(self) -> int:
        return self.n_samples

    # -- carrier bands -------------------------------------------------------------------
    @property
    def band_couplings(self) -> np.ndarray | None:
        """Couplings of every carrier band ``(N, n_bands, n_source, n_sensor)`` (``extra``
        :data:`BAND_COUPLINGS`; ``couplings`` is band 0), or None for one band
        (docs/data-format.md#carrier-bands)."""
        return self.extra.get(BAND_COUPLINGS)

    @property
    def band_frequencies(self) -> np.ndarray | None:
        """``(n_bands, n_source)`` carriers (Hz) of :attr:`band_couplings` (``meta
        ["band_frequencies_hz"]``), or None."""
        f = self.meta.get("band_frequencies_hz")
        return None if f is None else np.asarray(f, dtype=np.float64)

    # -- views -------------------------------------------------------------------------------
    def signed_real(self) -> np.ndarray:
        """Couplings as signed real values ``sign(Re z) |z|``, shape (N, n_source, n_sensor)."""
        return signed_real(self.couplings)

    def file_names(self) -> np.ndarray:
        """Input file name of each row (empty string where none), shape (N,)."""
        names = np.array(list(self.files) + [""], dtype=str)
        return names[self.file_index]

    def mask(self, *, files=None, pattern=None, source_fixture=None, sensor_fixture=None
             ) -> np.ndarray:
        """Boolean row mask; each argument is a value or a collection of accepted values."""
        def accept(values, wanted):
            if wanted is None:
                return np.ones(self.n_samples, dtype=bool)
            wanted = [wanted] if isinstance(wanted, str) else list(wanted)
            return np.isin(values, wanted)

        return (accept(self.file_names(), files) & accept(self.pattern, pattern)
                & accept(self.source_fixture, source_fixture)
                & accept(self.sensor_fixture, sensor_fixture))

    def select(self, rows) -> Dataset:
        """A new dataset with the rows picked by a boolean mask or an index array."""
        idx = np.flatnonzero(rows) if np.asarray(rows).dtype == bool else np.asarray(rows)

        def take(v):
            return None if v is None else v[idx]

        return replace(
            self, couplings=self.couplings[idx], stage=self.stage[idx],
            source_fixture=self.source_fixture[idx], sensor_fixture=self.sensor_fixture[idx],
            pattern=self.pattern[idx], file_index=self.file_index[idx],
            stage_logged=take(self.stage_logged), poses=take(self.poses),
            source_signs=take(self.source_signs), sensor_signs=take(self.sensor_signs),
            extra={k: v[idx] for k, v in self.extra.items()}, meta=dict(self.meta))
