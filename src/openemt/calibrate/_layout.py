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
from ..field import DipoleModel, solver_family

__all__ = ["FIELD_NAMES", "ParameterLayout"]

#: Names of the blocks of the full vector, in order.
FIELD_NAMES = ("L_so", "M_so", "L_se", "M_se", "F_so", "F_st", "F_se")


@dataclass(frozen=True, eq=False)
class ParameterLayout:
    """Layout of the full calibration vector: the model's parameters, then F_so, F_st, F_se.

    ``ParameterLayout(n_source, n_sensor)`` is the dipole model's layout; any other coupling
    model (:class:`openemt.field.CouplingModel`) has its own with :meth:`for_model`, whose
    model block is ``template.params`` with the template's groups and gauge.

    Attributes
    ----------
    n_source, n_sensor : int
        Coil counts.
    template : coupling model or None
        The model whose parameter vector the model block is (None: a dipole model).
    slices : dict of str -> slice
        Block of each field in the full vector (``model``, the dipole's ``L_so`` ... ``M_se``,
        ``F_so``, ``F_st``, ``F_se``).
    groups : dict of str -> ndarray of int
        Named parameter groups (indices into the full vector), as docs/paper-procedure.md#parameter-groups.
    gauge : ndarray of int
        Indices that are never fitted (the model's gauge).
    """

    n_source: int
    n_sensor: int
    template: object = None
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
        if self.template is None:
            # a dipole model of these coil counts: only its shape and gain matter here
            object.__setattr__(self, "template", DipoleModel(
                np.zeros((3, ns)), np.ones((3, ns)), np.zeros((3, ne)), np.ones((3, ne))))
        t = self.template
        if (t.n_source, t.n_sensor) != (ns, ne):
            raise InputError(f"expected a template model with {ns} x {ne} coils, got "
                             f"{t.n_source} x {t.n_sensor}")
        p = int(np.asarray(t.params).size)
        slices = {"model": slice(0, p)}
        if self.is_dipole:
            slices.update(t.param_slices())
        for k, name in enumerate(("F_so", "F_st", "F_se")):
            slices[name] = slice(p + 6 * k, p + 6 * k + 6)
        object.__setattr__(self, "slices", slices)
        g = {k: np.asarray(v, dtype=np.int64) for k, v in t.parameter_groups.items()}
        for short, name in (("so", "F_so"), ("st", "F_st"), ("se", "F_se")):
            full = np.arange(slices[name].start, slices[name].stop)
            g[f"{short}_fix"] = full
            for k, ax in enumerate("xyz"):
                g[f"{ax}_{short}_fix"] = full[k:k + 1]
            g[f"{short}_fix_trans"] = full[:3]
            g[f"{short}_fix_rot"] = full[3:]
        for v in g.values():
            v.setflags(write=False)
        gauge = np.asarray(t.gauge, dtype=np.int64)
        gauge.setflags(write=False)
        object.__setattr__(self, "groups", g)
        object.__setattr__(self, "gauge", gauge)

    @property
    def is_dipole(self) -> bool:
        return solver_family(self.template) == "dipole"

    # -- sizes -----------------------------------------------------------------------------
    @property
    def size(self) -> int:
        """Length of the full vector (the model's parameters + 18; ``6 (n_source + n_sensor)
        + 18`` for a dipole model)."""
        return self.slices["F_se"].stop

    @classmethod
    def for_model(cls, model) -> ParameterLayout:
        """The layout of ``model``'s parameters and the three fixtures."""
        if solver_family(model) == "dipole":
            return cls(model.n_source, model.n_sensor, model)
        from ..field import check_coupling_model

        check_coupling_model(model)
        return cls(model.n_source, model.n_sensor, model)

    # -- pack / unpack ----------------------------------------------------------------------
    def pack(self, model, source_fixture, stage_fixture, sensor_fixture) -> np.ndarray:
        """Model and fixture pose vectors -> full vector ``(size,)``."""
        if (model.n_source, model.n_sensor) != (self.n_source, self.n_sensor):
            raise InputError(f"expected a model with {self.n_source} source and {self.n_sensor} "
                             f"sensor coils, got {model.n_source} and {model.n_sensor}")
        x = np.empty(self.size)
        params = np.asarray(model.params, dtype=np.float64)
        if params.size != self.slices["model"].stop:
            raise InputError(f"expected a model of {self.slices['model'].stop} parameters like "
                             f"the layout's, got {params.size}")
        x[self.slices["model"]] = params
        x[self.slices["F_so"]] = source_fixture
        x[self.slices["F_st"]] = stage_fixture
        x[self.slices["F_se"]] = sensor_fixture
        return x

    def pack_calibration(self, cal) -> np.ndarray:
        """A :class:`openemt.io.Calibration` -> full vector ``(size,)``."""
        return self.pack(cal.model, cal.source_fixture, cal.stage_fixture, cal.sensor_fixture)

    def coil_arrays(self, x) -> dict[str, np.ndarray]:
        """Full vector of a dipole layout -> ``{'L_so': (3, n_so), 'M_so', 'L_se', 'M_se'}``."""
        if not self.is_dipole:
            raise InputError("expected a dipole-model layout for coil arrays, got a "
                             f"{type(self.template).__name__} layout")
        return self.template.split_params(np.asarray(x)[self.slices["model"]])

    def fixtures(self, x) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Full vector -> (F_so, F_st, F_se) pose vectors, each ``(6,)`` (copies)."""
        return tuple(np.array(x[self.slices[n]]) for n in ("F_so", "F_st", "F_se"))

    def model(self, x, gain: float | None = None):
        """Full vector -> the model (a :class:`DipoleModel` of coupling scale ``gain`` for a
        dipole layout; the template with these parameters otherwise)."""
        if self.is_dipole:
            return DipoleModel(gain=self.template.gain if gain is None else gain,
                               **self.coil_arrays(x))
        return self.template.with_params(np.asarray(x)[self.slices["model"]])

    def as_fields(self, values) -> dict[str, np.ndarray]:
        """Full-length per-parameter values (e.g. standard errors) -> arrays keyed like a
        calibration: the model's blocks (``L_so``... as (3, n) for a dipole model) and
        ``source_fixture``/... as (6,)."""
        v = np.asarray(values, dtype=np.float64)
        out = self.template.split_params(v[self.slices["model"]])
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
        if 0 <= i < self.slices["model"].stop:
            return self.template.parameter_label(int(i))
        for name in ("F_so", "F_st", "F_se"):
            s = self.slices[name]
            if s.start <= i < s.stop:
                return f"{name}[{i - s.start}]"
        raise InputError(f"expected an index below {self.size}, got {i}")
