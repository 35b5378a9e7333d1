"""Calibration modes: which parameter groups are fitted, which rows are used.

The paper's modes (MacLachlan et al. 2025, §VI; docs/paper-procedure.md#parameter-groups table):

========================  =========================================  ========================
mode                      rows (source fixtures x sensor fixtures)   free groups
========================  =========================================  ========================
``XYZ``                   home source x all sensor fixtures, md       coils + st_fix + se_fix
``concentric``            same                                        moments + st/se_fix, L = 0
``XYZ_all``               every fixture combination, md              XYZ + so_fix
``XYZ_all_concentric``    every fixture combination, md              concentric + so_fix
``so_fixture_all``        every fixture combination, md              so_fix + st_fix
``trans_only``            home x home, mdtrans (no rotations)        coils + st_fix
``Z_only``                home x home, md                            XYZ minus z of se_fix
========================  =========================================  ========================

``DEFAULT_FREEZE`` (``d_so_z_gain``, ``d_so_y_co``, ``d_se_y_co``) is always frozen, together
with the gauge of :class:`~openemt.calibrate.ParameterLayout`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .._errors import InputError
from ..geometry import SOURCE_FIXTURES

__all__ = [
    "DEFAULT_FREEZE",
    "DEFAULT_OPTIMIZE",
    "MODES",
    "CalibrationMode",
    "get_mode",
    "select_rows",
]

#: ILEMT's default free groups (docs/paper-procedure.md#parameter-groups).
DEFAULT_OPTIMIZE = ("d_so_pos", "d_so_mo", "d_se_pos", "d_se_mo", "st_fix", "se_fix")
#: ILEMT's default frozen groups: the source Z gain and the X coils' Y components.
DEFAULT_FREEZE = ("d_so_z_gain", "d_so_y_co", "d_se_y_co")

_HOME = SOURCE_FIXTURES[0]


@dataclass(frozen=True)
class CalibrationMode:
    """A named calibration configuration.

    Attributes
    ----------
    name : str
    optimize, freeze : tuple of str
        Parameter groups fitted / held (names of ``ParameterLayout.groups``).
    concentric : bool
        Force every coil position to zero (``L_so = L_se = 0``) before and during the fit.
    source_fixtures, sensor_fixtures : tuple of str or None
        Rows used (``None``: every fixture in the dataset).
    patterns : tuple of str or None
        Data patterns used (``None``: every pattern).
    description : str
    """

    name: str
    optimize: tuple[str, ...]
    freeze: tuple[str, ...] = DEFAULT_FREEZE
    concentric: bool = False
    source_fixtures: tuple[str, ...] | None = (_HOME,)
    sensor_fixtures: tuple[str, ...] | None = None
    patterns: tuple[str, ...] | None = ("md",)
    description: str = ""


_NO_POS = tuple(g for g in DEFAULT_OPTIMIZE if g not in ("d_so_pos", "d_se_pos"))

MODES: dict[str, CalibrationMode] = {m.name: m for m in (
    CalibrationMode("XYZ", DEFAULT_OPTIMIZE,
                    description="general dipole model, home source fixture, all sensor fixtures"),
    CalibrationMode("concentric", _NO_POS, concentric=True,
                    description="concentric coils (L = 0), home source fixture"),
    CalibrationMode("XYZ_all", ("so_fix",) + DEFAULT_OPTIMIZE, source_fixtures=None,
                    description="general dipole model and all three fixtures, every fixture"),
    CalibrationMode("XYZ_all_concentric", ("so_fix",) + _NO_POS, concentric=True,
                    source_fixtures=None,
                    description="concentric model and all three fixtures, every fixture"),
    CalibrationMode("so_fixture_all", ("so_fix", "st_fix"), source_fixtures=None,
                    description="source and stage fixtures only, every fixture"),
    CalibrationMode("trans_only", ("d_so_pos", "d_so_mo", "d_se_pos", "d_se_mo", "st_fix"),
                    freeze=DEFAULT_FREEZE + ("z_se_fix",), sensor_fixtures=(_HOME,),
                    patterns=("mdtrans",),
                    description="translation-only data (mdtrans), coils and stage fixture"),
    CalibrationMode("Z_only", DEFAULT_OPTIMIZE, freeze=DEFAULT_FREEZE + ("z_se_fix",),
                    sensor_fixtures=(_HOME,),
                    description="home source and sensor fixtures only"),
)}
MODES["XYZ_concentric"] = replace(MODES["concentric"], name="XYZ_concentric")


def get_mode(mode) -> CalibrationMode:
    """A :class:`CalibrationMode` from a name in :data:`MODES` (or the mode itself)."""
    if isinstance(mode, CalibrationMode):
        return mode
    if isinstance(mode, str) and mode in MODES:
        return MODES[mode]
    raise InputError(f"expected a calibration mode from {sorted(MODES)}, got {mode!r}")


def select_rows(dataset, mode: CalibrationMode) -> np.ndarray:
    """Boolean row mask of ``dataset`` for the mode's fixtures and patterns."""
    return dataset.mask(pattern=mode.patterns, source_fixture=mode.source_fixtures,
                        sensor_fixture=mode.sensor_fixtures)
