"""Named constants used in more than one module, each defined once (plain Python: cheap to
import, also from the command line's parser)."""

from __future__ import annotations

__all__ = ["EXPLORE_RELATIVE_RESIDUAL", "ILEMT_POSITION_BOX_M", "MAX_RANGE_M", "MAX_RELATIVE_RESIDUAL", "OUTPUT_RATE_HZ",
           "SIMULATED_MAINS_AMPLITUDES_V"]

#: Largest relative coupling residual ``||C_pred - C_meas||_F / ||C_meas||_F`` of a valid
#: pose solution (docs/solve.md#validity-rule). 1 % is above the noise and model error of a
#: calibrated tracker (the bundled ILEMT data solve with 0.1 % median, 0.7 % at most under the
#: authors' calibration) and below the best dipole fit of garbage (random Gaussian matrices:
#: 2.5 % at least in 2000 draws, 40 % typical).
MAX_RELATIVE_RESIDUAL = 0.01

#: Relative residual above which the iterative solver tries more starts for a sample before
#: settling (docs/solve.md#validity-rule): far below the validity threshold, because a wrong
#: local minimum can fit the couplings to within 1 % (about 1 sample in 1000 with a 45 mm
#: coil-offset source at 5-60 cm), and above the residual of a right solution of clean data.
EXPLORE_RELATIVE_RESIDUAL = 1e-3

#: Largest plausible sensor distance from the source origin, in metres
#: (docs/solve.md#validity-rule). No magnetic tracker measures beyond a few metres; a solution
#: further out is a solver running off towards zero coupling, not a position.
MAX_RANGE_M = 3.0

#: Half-width (m) of the position box ILEMT's iterative solution is bounded by
#: (docs/paper-procedure.md#iterative-solution); a solution on it is out of volume.
ILEMT_POSITION_BOX_M = 0.4

#: Pose output rate (per second) of ILEMT's demodulator: one output per 64 samples at
#: 96 kS/s (MacLachlan et al. 2025, §VIII-E).
OUTPUT_RATE_HZ = 1500.0

#: Peak amplitudes (V) of the 1st, 2nd and 3rd mains harmonics on the sensor channels of the
#: simulated live tracker (the ``track`` command and the live simulated backend).
SIMULATED_MAINS_AMPLITUDES_V = (0.01, 0.002, 0.003)
