"""Named constants used in more than one module, each defined once (plain Python: cheap to
import, also from the command line's parser)."""

from __future__ import annotations

__all__ = ["MAX_RANGE_M", "MAX_RELATIVE_RESIDUAL"]

#: Largest relative coupling residual ``||C_pred - C_meas||_F / ||C_meas||_F`` of a valid
#: pose solution (docs/solve.md#validity-rule). 1 % is above the noise and model error of a
#: calibrated tracker (the bundled ILEMT data solve with 0.1 % median, 0.7 % at most under the
#: authors' calibration) and below the best dipole fit of garbage (random Gaussian matrices:
#: 2.5 % at least in 2000 draws, 40 % typical).
MAX_RELATIVE_RESIDUAL = 0.01

#: Largest plausible sensor distance from the source origin, in metres
#: (docs/solve.md#validity-rule). No magnetic tracker measures beyond a few metres; a solution
#: further out is a solver running off towards zero coupling, not a position.
MAX_RANGE_M = 3.0
