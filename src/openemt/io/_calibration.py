"""The in-memory calibration: a coupling model plus the fixture transforms of the rig.

Its on-disk form is a schema-versioned JSON file (``docs/calibration-format.md``); ILEMT
``.mat`` calibrations import into the same object.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from .._errors import InputError
from ..field import (
    CouplingModel,
    EnvironmentModel,
    EnvironmentTerms,
    OctupoleModel,
    check_coupling_model,
    solver_family,
)
from ..geometry import pose_from_vector

__all__ = ["COUPLING_SCALE_RANGE", "MAX_COIL_POSITION_M", "MAX_CORRECTION_CONDITION",
           "Calibration", "check_correction_matrix",
           "check_model_moments"]

#: The ``schema`` of every openemt calibration file (docs/calibration-format.md).
CALIBRATION_SCHEMA = "openemt.calibration"

#: Largest condition number of a homogeneous 4x4 output correction. A fitted correction is
#: close to the identity (condition ~1); a matrix beyond this is singular in practice (an
#: all-zero matrix, a zero row) and would turn every corrected position into NaN or garbage.
MAX_CORRECTION_CONDITION = 1e12

#: range of a dipole model's coupling scale ``|gain| * max|M_so| * max|M_se|`` (the coupling of
#: two coils 1 m apart): within it every distance from 1 um to 1 km gives finite, normal
#: couplings; outside it a file is damaged (a gain of 1e300 overflows every coupling)
COUPLING_SCALE_RANGE = (1e-100, 1e100)
#: largest coil position of a model, and fixture translation (m)
MAX_COIL_POSITION_M = 10.0


def check_correction_matrix(L, name: str = "linear_correction", where: str = "") -> np.ndarray:
    """A finite, non-singular homogeneous (4, 4) correction as float64, or an InputError naming
    ``where`` (e.g. ``"calibration file cal.json: "``) and ``name``."""
    try:
        a = np.asarray(L, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{where}expected `{name}` as a (4, 4) matrix of numbers, got "
                         f"{type(L).__name__}") from None
    if a.shape != (4, 4):
        raise InputError(f"{where}expected `{name}` of shape (4, 4), got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InputError(f"{where}expected finite numbers in `{name}`, got NaN/inf/null")
    cond = np.linalg.cond(a) if np.any(a) else np.inf
    if not cond <= MAX_CORRECTION_CONDITION:
        raise InputError(f"{where}expected a non-singular `{name}` (condition number <= "
                         f"{MAX_CORRECTION_CONDITION:g}), got condition number {cond:.3g}")
    return a


def check_model_moments(model, where: str = "") -> None:
    """Every coil of a loaded dipole model must have a non-zero moment (a zero moment couples
    to nothing: a damaged or placeholder calibration), its coupling scale must lie in
    :data:`COUPLING_SCALE_RANGE` and its coil positions within :data:`MAX_COIL_POSITION_M`."""
    for name in ("M_so", "M_se"):
        zero = np.flatnonzero(~np.any(getattr(model, name) != 0, axis=0))
        if zero.size:
            raise InputError(f"{where}expected non-zero coil moments in `{name}`, got all-zero "
                             f"column(s) {zero.tolist()}")
    for key in ("L_so", "L_se"):
        far = np.abs(getattr(model, key)).max(initial=0.0)
        if not far <= MAX_COIL_POSITION_M:
            raise InputError(f"{where}expected coil positions `{key}` within "
                             f"{MAX_COIL_POSITION_M:g} m of the origin, got {far:.3g} m")
    scale = abs(float(model.gain)) * np.abs(model.M_so).max(initial=0.0) \
        * np.abs(model.M_se).max(initial=0.0)
    lo, hi = COUPLING_SCALE_RANGE
    if not lo <= scale <= hi:
        raise InputError(f"{where}expected the coupling scale |gain| x max|M_so| x max|M_se| "
                         f"within [{lo:g}, {hi:g}], got {scale:.3g} (gain "
                         f"{float(model.gain):.3g})")


def _vec6(v, name):
    a = np.asarray(v, dtype=np.float64)
    if a.shape != (6,):
        raise InputError(f"expected `{name}` to be a pose vector of shape (6,), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InputError(f"expected finite `{name}`, got NaN or inf")
    return a


@dataclass(frozen=True, eq=False)
class Calibration:
    """A coupling model with the rig's fixture transforms and optional output correction: the
    one calibration type of every model (docs/calibration-format.md).

    Attributes
    ----------
    model : coupling model
        Any :class:`openemt.field.CouplingModel`: a :class:`~openemt.field.DipoleModel` (source
        and sensor coil parameters, SI units, gain units for moments), a finite-coil board
        (:class:`openemt.board.BoardModel`), ...
    source_fixture, stage_fixture, sensor_fixture : ndarray, shape (6,)
        F_so, F_st, F_se as pose vectors ``[x, y, z, rx, ry, rz]`` (m, rad); zeros if unknown.
    linear_correction : ndarray, shape (4, 4), optional
        Homogeneous DLT output correction applied to solved positions (docs/paper-procedure.md#applying-correction).
    mode : str
        Calibration mode that produced it (``XYZ``, ``concentric``, ``truth``, ``ilemt``, ...).
    free, frozen : tuple of str
        Named parameter groups that were fitted / held.
    standard_errors : dict of str -> ndarray, optional
        Standard errors with the shapes of the values they belong to (``L_so``, ``F_so``, ...).
    stats : dict
        Fit statistics (``rms_residue``, ``sum_squared_residue``, ``num_points``, ...).
    provenance : dict
        openemt version, input file hashes, the calibration it started from, ...
    extra : dict
        Model terms beyond the dipole (e.g. quadrupoles) and anything else, JSON-serialisable.
    """

    model: CouplingModel
    source_fixture: np.ndarray = field(default_factory=lambda: np.zeros(6))
    stage_fixture: np.ndarray = field(default_factory=lambda: np.zeros(6))
    sensor_fixture: np.ndarray = field(default_factory=lambda: np.zeros(6))
    linear_correction: np.ndarray | None = None
    mode: str = ""
    free: tuple[str, ...] = ()
    frozen: tuple[str, ...] = ()
    standard_errors: dict[str, np.ndarray] = field(default_factory=dict)
    stats: dict[str, Any] = field(default_factory=dict)
    provenance: dict[str, Any] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self):
        check_coupling_model(self.model)
        for name in ("source_fixture", "stage_fixture", "sensor_fixture"):
            object.__setattr__(self, name, _vec6(getattr(self, name), name))
        if self.linear_correction is not None:
            object.__setattr__(self, "linear_correction",
                               check_correction_matrix(self.linear_correction))
        object.__setattr__(self, "free", tuple(self.free))
        object.__setattr__(self, "frozen", tuple(self.frozen))
        object.__setattr__(self, "_coupling_model", self._build_coupling_model())

    @property
    def kind(self) -> str:
        """The model family, as in the file's model block (``dipole``, ``finite``, ...)."""
        return self.model.kind

    @property
    def n_source(self) -> int:
        return self.model.n_source

    @property
    def n_sensor(self) -> int:
        return self.model.n_sensor

    @property
    def fixture_poses(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(F_so, F_st, F_se) as (4, 4) poses."""
        return tuple(pose_from_vector(v) for v in
                     (self.source_fixture, self.stage_fixture, self.sensor_fixture))

    @property
    def coupling_model(self):
        """The model that predicts this calibration's couplings: ``model`` plus the axial
        octupole terms an improved calibration stores in ``extra['rig']`` (``octupole_k_so``,
        ``octupole_k_se``; an :class:`~openemt.field.OctupoleModel`), plus the environment
        terms (induced dipoles, gain non-linearity, coupling offset) of
        ``extra['environment']`` (an :class:`~openemt.field.EnvironmentModel`; files that
        have none read as before), else ``model`` itself. Built once, when the calibration is
        made."""
        return self._coupling_model

    @property
    def environment(self) -> EnvironmentTerms | None:
        """The environment terms of ``extra['environment']`` (None when there are none)."""
        env = self.extra.get("environment")
        if not env:
            return None
        terms = EnvironmentTerms.from_dict(env).check(self.model.n_source, self.model.n_sensor,
                                                       "calibration environment terms: ")
        return None if terms.empty else terms

    def _build_coupling_model(self):
        rig = self.extra.get("rig") or {}
        k_so, k_se = (rig.get("octupole_k_so"), rig.get("octupole_k_se")) \
            if isinstance(rig, dict) else (None, None)
        model = self.model
        if (k_so is not None or k_se is not None) and solver_family(self.model) == "dipole":
            model = OctupoleModel(self.model,
                                  np.zeros(self.model.n_source) if k_so is None else k_so,
                                  np.zeros(self.model.n_sensor) if k_se is None else k_se)
        terms = self.environment
        return model if terms is None else EnvironmentModel(model, terms)

    def replace(self, **changes) -> Calibration:
        return replace(self, **changes)
