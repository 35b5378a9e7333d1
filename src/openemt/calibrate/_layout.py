"""The calibration parameter vector, defined once: named slices, named groups and the gauge.

The full vector holds every number of a calibration (MacLachlan et al. 2025, §V-VI, ``rho``)::

    [ L_so (coil-major, 3 per coil) | M_so | L_se | M_se | F_so (6) | F_st (6) | F_se (6) ]

Coil arrays are stored coil by coil, so ``L_so[:, i]`` occupies ``3 i .. 3 i + 2`` of its slice.
The gauge of docs/ilemt-data.md#dipole-model (MacLachlan et al. 2025, eq. 7) is built in, generalised to any coil count:

* the **reference coil** of each side is its last coil (the Z coil of a tri-axial set): its
  position is held at the frame origin and its moment along +z, ``[0, 0, k]``;
* the **y component of coil 0's moment** (``M[1, 0]``, the X coil's Y component) is held, which
  fixes the rotation of the frame about z (groups ``d_so_y_co``/``d_se_y_co``);
* the source reference gain ``k_so`` is held by default (group ``d_so_z_gain`` is in the
  default freeze set) because a common scale of source and sensor moments is not observable.

With one coil on a side (a 5-DOF sensor) only the reference-coil rules apply. Named groups follow
docs/paper-procedure.md#parameter-groups; the 82-element ILEMT vector itself is not reproduced (quadrupole slots are
not part of the dipole model).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._errors import InputError
from ..field import DipoleModel

__all__ = ["FIELD_NAMES", "ParameterLayout"]

#: Names of the blocks of the full vector, in order.
FIELD_NAMES = ("L_so", "M_so", "L_se", "M_se", "F_so", "F_st", "F_se")


def _coil_block(arr: np.ndarray) -> np.ndarray:
    """(3, n) coil array -> coil-major flat vector (3 n,)."""
    return np.asarray(arr, dtype=np.float64).T.ravel()


@dataclass(frozen=True, eq=False)
class ParameterLayout:
    """Layout of the full calibration vector for ``n_source`` and ``n_sensor`` coils.

    Attributes
    ----------
    n_source, n_sensor : int
        Coil counts.
    slices : dict of str -> slice
        Block of each field of ``FIELD_NAMES`` in the full vector.
    groups : dict of str -> ndarray of int
        Named parameter groups (indices into the full vector), as docs/paper-procedure.md#parameter-groups.
    gauge : ndarray of int
        Indices that are never fitted (reference-coil position and transverse moment).
    """

    n_source: int
    n_sensor: int
    slices: dict = field(init=False)
    groups: dict = field(init=False)
    gauge: np.ndarray = field(init=False)

    def __post_init__(self):
        for name in ("n_source", "n_sensor"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or v < 1:
                raise InputError(f"expected `{name}` to be a positive integer, got {v!r}")
            object.__setattr__(self, name, int(v))
        ns, ne = self.n_source, self.n_sensor
        sizes = {"L_so": 3 * ns, "M_so": 3 * ns, "L_se": 3 * ne, "M_se": 3 * ne,
                 "F_so": 6, "F_st": 6, "F_se": 6}
        slices, start = {}, 0
        for name in FIELD_NAMES:
            slices[name] = slice(start, start + sizes[name])
            start += sizes[name]
        object.__setattr__(self, "slices", slices)

        def idx(name, coil=None, comp=None):
            s = slices[name]
            base = np.arange(s.start, s.stop)
            if coil is None:
                return base
            c = np.atleast_1d(coil)
            comps = np.arange(3) if comp is None else np.atleast_1d(comp)
            return np.array([s.start + 3 * i + a for i in c for a in comps], dtype=np.int64)

        g: dict[str, np.ndarray] = {}
        gauge = []
        for side, n in (("so", ns), ("se", ne)):
            L, M = f"L_{side}", f"M_{side}"
            ref = n - 1
            others = np.arange(n - 1)
            g[f"d_{side}_pos"] = idx(L, others)
            g[f"{side}_z_gain"] = idx(M, ref, 2)
            g[f"d_{side}_z_gain"] = g[f"{side}_z_gain"]
            g[f"d_{side}_mo"] = np.concatenate([idx(M, others), g[f"d_{side}_z_gain"]])
            g[f"d_{side}_y_co"] = idx(M, 0, 1) if n > 1 else np.zeros(0, dtype=np.int64)
            gauge.append(idx(L, ref))
            gauge.append(idx(M, ref, [0, 1]))
            del g[f"{side}_z_gain"]
        for short, name in (("so", "F_so"), ("st", "F_st"), ("se", "F_se")):
            full = idx(name)
            g[f"{short}_fix"] = full
            for k, ax in enumerate("xyz"):
                g[f"{ax}_{short}_fix"] = full[k:k + 1]
            g[f"{short}_fix_trans"] = full[:3]
            g[f"{short}_fix_rot"] = full[3:]
        for v in g.values():
            v.setflags(write=False)
        gauge_arr = np.unique(np.concatenate(gauge))
        gauge_arr.setflags(write=False)
        object.__setattr__(self, "groups", g)
        object.__setattr__(self, "gauge", gauge_arr)

    # -- sizes -----------------------------------------------------------------------------
    @property
    def size(self) -> int:
        """Length of the full vector, ``6 (n_source + n_sensor) + 18``."""
        return self.slices["F_se"].stop

    @classmethod
    def for_model(cls, model: DipoleModel) -> ParameterLayout:
        return cls(model.n_source, model.n_sensor)

    # -- pack / unpack ----------------------------------------------------------------------
    def pack(self, model: DipoleModel, source_fixture, stage_fixture, sensor_fixture
             ) -> np.ndarray:
        """Model and fixture pose vectors -> full vector ``(size,)``."""
        if (model.n_source, model.n_sensor) != (self.n_source, self.n_sensor):
            raise InputError(f"expected a model with {self.n_source} source and {self.n_sensor} "
                             f"sensor coils, got {model.n_source} and {model.n_sensor}")
        x = np.empty(self.size)
        x[self.slices["L_so"]] = _coil_block(model.L_so)
        x[self.slices["M_so"]] = _coil_block(model.M_so)
        x[self.slices["L_se"]] = _coil_block(model.L_se)
        x[self.slices["M_se"]] = _coil_block(model.M_se)
        x[self.slices["F_so"]] = source_fixture
        x[self.slices["F_st"]] = stage_fixture
        x[self.slices["F_se"]] = sensor_fixture
        return x

    def pack_calibration(self, cal) -> np.ndarray:
        """A :class:`openemt.io.Calibration` -> full vector ``(size,)``."""
        return self.pack(cal.model, cal.source_fixture, cal.stage_fixture, cal.sensor_fixture)

    def coil_arrays(self, x) -> dict[str, np.ndarray]:
        """Full vector -> ``{'L_so': (3, n_so), 'M_so', 'L_se', 'M_se'}`` (copies)."""
        out = {}
        for name, n in (("L_so", self.n_source), ("M_so", self.n_source),
                        ("L_se", self.n_sensor), ("M_se", self.n_sensor)):
            out[name] = np.ascontiguousarray(np.asarray(x[self.slices[name]]).reshape(n, 3).T)
        return out

    def fixtures(self, x) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Full vector -> (F_so, F_st, F_se) pose vectors, each ``(6,)`` (copies)."""
        return tuple(np.array(x[self.slices[n]]) for n in ("F_so", "F_st", "F_se"))

    def model(self, x, gain: float) -> DipoleModel:
        """Full vector -> :class:`DipoleModel`."""
        return DipoleModel(gain=gain, **self.coil_arrays(x))

    def as_fields(self, values) -> dict[str, np.ndarray]:
        """Full-length per-parameter values (e.g. standard errors) -> arrays keyed like a
        calibration: ``L_so``... as (3, n) and ``source_fixture``/... as (6,)."""
        v = np.asarray(values, dtype=np.float64)
        out = self.coil_arrays(v)
        F = self.fixtures(v)
        out.update(source_fixture=F[0], stage_fixture=F[1], sensor_fixture=F[2])
        return out

    # -- free / frozen ----------------------------------------------------------------------
    def group_indices(self, names) -> np.ndarray:
        """Union of the named groups (sorted indices). Unknown names raise ``ValueError``."""
        names = [names] if isinstance(names, str) else list(names)
        bad = [n for n in names if n not in self.groups]
        if bad:
            raise InputError(f"expected parameter group names from {sorted(self.groups)}, "
                             f"got {bad}")
        if not names:
            return np.zeros(0, dtype=np.int64)
        return np.unique(np.concatenate([self.groups[n] for n in names]))

    def free_indices(self, optimize, freeze=()) -> np.ndarray:
        """Indices fitted for the ``optimize`` groups minus ``freeze`` groups and the gauge."""
        free = np.setdiff1d(self.group_indices(optimize), self.group_indices(freeze))
        return np.setdiff1d(free, self.gauge)

    def label(self, i: int) -> str:
        """Human-readable name of full-vector entry ``i``, e.g. ``M_so[1, 0]`` or ``F_st[3]``."""
        for name in FIELD_NAMES:
            s = self.slices[name]
            if s.start <= i < s.stop:
                k = i - s.start
                if name.startswith("F_"):
                    return f"{name}[{k}]"
                return f"{name}[{k % 3}, {k // 3}]"
        raise InputError(f"expected an index below {self.size}, got {i}")
