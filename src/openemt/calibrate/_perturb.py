"""A start for a fit: a calibration with the parameters a mode fits moved at random (simulation
studies, the demo)."""

from __future__ import annotations

import numpy as np

from ..io import Calibration
from ._layout import ParameterLayout
from ._modes import get_mode

__all__ = ["perturb_calibration"]


def perturb_calibration(cal: Calibration, rng, *, mode="XYZ_all", pos=5e-4, rel=0.01,
                        fix_t=1e-3, fix_r=0.01) -> Calibration:
    """A start for a fit: every parameter ``mode`` fits moved by a random normal amount.

    Standard deviations: ``pos`` (m) for coil positions, ``rel`` times the largest moment
    component of the side for coil moments, ``fix_t`` (m) and ``fix_r`` (rad) for fixture
    translations and rotations. Parameters the mode holds keep their values; the result's
    ``mode`` is ``"start"``.
    """
    lay = ParameterLayout.for_model(cal.model)
    m = get_mode(mode)
    x = lay.pack_calibration(cal)
    free = lay.free_indices(m.optimize, m.freeze)
    scale = np.zeros(lay.size)
    for name in ("L_so", "L_se"):
        scale[lay.slices[name]] = pos
    for name in ("M_so", "M_se"):
        s = lay.slices[name]
        scale[s] = rel * np.abs(x[s]).max()
    for name in ("F_so", "F_st", "F_se"):
        s = lay.slices[name]
        scale[s.start:s.start + 3] = fix_t
        scale[s.start + 3:s.stop] = fix_r
    x[free] += rng.normal(size=free.size) * scale[free]
    F = lay.fixtures(x)
    return cal.replace(model=lay.model(x, cal.model.gain), source_fixture=F[0],
                       stage_fixture=F[1], sensor_fixture=F[2], mode="start")
