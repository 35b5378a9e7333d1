"""Packed arguments of the compiled solver kernels.

The kernels take a coil model as one float64 array (``pack_model`` of the dipole kernel,
re-exported here) and their options as another, read through the named index constants below,
instead of long runs of positional scalars (which can be swapped without any error). One array
type per argument also means one compiled specialisation per kernel.
"""

from __future__ import annotations

import numpy as np

from ..field._dipole_kernel import M_GAIN, M_N_SENSOR, M_N_SOURCE, pack_model, unpack_model

__all__ = ["M_GAIN", "M_N_SENSOR", "M_N_SOURCE", "N_OPTIONS", "O_AMBIGUITY_TOL", "O_CF_GAIN", "O_EXTRAPOLATE", "O_FIVE_DOF", "O_MAX_ITER",
           "O_MAX_RANGE", "O_MAX_RELATIVE_RESIDUAL", "O_RANK_TOL", "O_RETRIES", "O_RETRY_RELATIVE",
           "O_RETRY_RESNORM", "O_UNCONSTRAINED", "O_USE_CLOSED_FORM", "O_XTOL", "pack_box", "pack_model",
           "pack_options", "unpack_model"]

# option array indices
O_MAX_ITER = 0                 #: LM iterations per run
O_XTOL = 1                     #: LM step tolerance (relative translation, rad)
O_RETRY_RESNORM = 2            #: retry while resnorm >= this (inf: no such test)
O_RETRY_RELATIVE = 3           #: retry while the relative residual > this (inf: none)
O_AMBIGUITY_TOL = 4            #: t . n <= tol |t| is on the hemisphere plane
O_MAX_RELATIVE_RESIDUAL = 5    #: validity threshold on the relative residual
O_MAX_RANGE = 6                #: plausible range (m)
O_RETRIES = 7                  #: 1: ILEMT's sign-flip retries
O_FIVE_DOF = 8                 #: 1: single-coil sensor, 5-DOF solve
O_USE_CLOSED_FORM = 9          #: 1: tracking restarts from the Kim18 closed form
O_CF_GAIN = 10                 #: gain of the closed-form (concentric) model
O_RANK_TOL = 11                #: closed forms: s3 < rank_tol * s1 is rank deficient
#: 1: LM iterates are not projected onto the hemisphere and box, a start outside the
#: hemisphere is not mirrored and a step is not limited to half the distance from the origin
#: (the constraints only judge the result, as the interface-level LM's do)
O_UNCONSTRAINED = 12
#: 1: tracking starts from the constant-velocity extrapolation of the last two samples
O_EXTRAPOLATE = 13
N_OPTIONS = 14


def pack_options(**values) -> np.ndarray:
    """Options array from keywords named after the ``O_*`` constants (lower case, no ``O_``);
    unnamed entries are 0."""
    out = np.zeros(N_OPTIONS)
    for name, v in values.items():
        out[globals()["O_" + name.upper()]] = float(v)
    return out


def pack_box(lo, hi) -> np.ndarray:
    """Position box ``[[lo_x, lo_y, lo_z], [hi_x, hi_y, hi_z]]`` (2, 3)."""
    return np.ascontiguousarray(np.stack([np.asarray(lo, float), np.asarray(hi, float)]))
