"""Live tracking with a finite-coil (board) calibration: a planar field generator of
``n_coils`` source coils, one carrier each, read by single-coil (5-DOF) sensors
(docs/planar.md#tracking-live).

The live chain is the dipole tracker's (:mod:`openemt.live._pipeline`): the raw-signal
simulator and the demodulator take the board's ``n_coils`` carriers and one channel per sensor
coil, and the demodulated ``(N, n_coils, 1)`` couplings of each sensor go to
:func:`board_solver`, the 5-DOF board solver of :func:`openemt.solve.prepare` warm-started
from the last converged pose of the previous chunk. Its pose's rotation is the smallest one
taking the sensor's z axis to the measured coil axis (a 5-DOF sensor has no measurable roll),
and that is the TRANSFORM sent over OpenIGTLink.
"""

from __future__ import annotations

import numpy as np

from .._errors import InputError
from ..geometry import pose_from_vector

__all__ = [
    "BOARD_FREQUENCIES",
    "BOARD_PEAK_VOLTS",
    "board_default_spec",
    "board_frequencies",
    "board_solver",
    "board_trajectory",
    "board_truth",
    "fit_sensor_gain",
]



def board_frequencies(n: int) -> tuple:
    """Default carriers of an ``n``-coil board (Hz): from 7.5 kHz in 3 kHz steps, the ILEMT plan
    (7.5, 10.5, 13.5 kHz) continued; 1.5 kHz steps beyond 8 coils (below the 48 kHz Nyquist
    limit up to 27 coils). At 96 kS/s and 1500 outputs/s they fall on bins 10, 14, ... (10, 12,
    ...) of the 128-sample Hann frame, where the window keeps them exactly apart
    (docs/live.md, "Demodulator")."""
    step = 3000.0 if n <= 8 else 1500.0
    return tuple(7500.0 + step * k for k in range(int(n)))


#: Default carriers of the 8 board coils (Hz): 7.5 kHz to 28.5 kHz, 3 kHz apart
#: (docs/planar.md#tracking-live).
BOARD_FREQUENCIES = board_frequencies(8)
#: Peak sensor voltage (V) the simulated board tracker's sensor gain is set for.
BOARD_PEAK_VOLTS = 0.3


def board_trajectory(t) -> np.ndarray:
    """A slow figure-of-eight over the board centre with a rocking sensor, poses (N, 4, 4).

    Position ``x = 50 sin(w t)`` mm, ``y = 40 sin(2 w t)`` mm, ``z = 120 + 30 sin(w t / 2)`` mm
    with ``w = 2 pi / 8 s``; rotation vector ``(0.3 sin(w t), 0.25 cos(w t), 0.4 sin(w t / 2))``
    rad, so the sensor axis (z) stays within 23 degrees of the board normal.
    """
    t = np.atleast_1d(np.asarray(t, dtype=np.float64))
    w = 2 * np.pi / 8.0
    v = np.stack([0.050 * np.sin(w * t), 0.040 * np.sin(2 * w * t),
                  0.120 + 0.030 * np.sin(w * t / 2), 0.3 * np.sin(w * t),
                  0.25 * np.cos(w * t), 0.4 * np.sin(w * t / 2)], axis=1)
    return pose_from_vector(v)


def fit_sensor_gain(model, trajectory=board_trajectory, offsets=None,
                    peak: float = BOARD_PEAK_VOLTS) -> float:
    """Sensor gain (V per coupling x A) that puts the largest coupling of ``model`` along one
    8 s period of ``trajectory`` (each sensor shifted by its ``offsets``) at ``peak`` volts."""
    t = np.linspace(0.0, 8.0, 401)
    P = np.asarray(trajectory(t), dtype=np.float64)
    off = np.zeros((1, 3)) if offsets is None else np.asarray(offsets, dtype=np.float64)
    big = 0.0
    for d in off:
        Q = P.copy()
        Q[:, :3, 3] += d
        big = max(big, float(np.abs(model.coupling(Q)).max()))
    if not big > 0:
        raise InputError("expected a board model with non-zero couplings along the simulated "
                         "path, got none")
    return peak / big


def board_solver(model, **options):
    """The pipeline's solver callable for a board model: ``solve(C (N, n_coils, 1), initial)``.

    ``initial`` is a string while acquiring (the first sample starts cold from the seed grid,
    the next from its predecessor) or the tiled pose vector of the last converged sample; a
    sample that does not converge from it is solved again cold. The solver is
    :func:`openemt.solve.prepare`'s for the board (``options``: the validity rule,
    ``max_iter``, ... of :class:`openemt.solve.SolveOptions`).
    """
    from ..solve import prepare

    solver = prepare(model, **options)

    def solve(C, initial):
        return solver(C, None if isinstance(initial, str) else initial)

    return solve


def board_default_spec(calibration, name: str = "Sensor", device_name: str | None = None, *,
                       preset=None, compiling=None):
    """The tracker of ``openemt track --calibration CAL`` without a tracker file when ``CAL``
    is a board calibration (else None): the shipped ``anser`` tracker (one sensor channel,
    one carrier and reference channel per coil) with that calibration, the sensor ``name``
    and device name (default ``<name>ToTracker``), and a sensor gain that puts the simulated
    path's largest coupling at :data:`BOARD_PEAK_VOLTS`. ``compiling(kernels)`` is told the
    board's compiled kernels before that first runs them (a compile notice)."""
    from dataclasses import replace
    from pathlib import Path

    from ..io import read_calibration
    from ._tracker_file import SensorSpec, example_tracker, read_tracker, sensor_device_name

    try:
        cal = read_calibration(calibration)
    except (ValueError, OSError):
        return None                       # the dipole path reports an unreadable file
    if not hasattr(cal.model, "board"):
        return None
    if preset is not None:
        raise InputError(f"expected no --preset with a finite-coil board calibration (the "
                         f"simulation's truth is the calibration's board), got {preset!r}")
    n = cal.model.n_coils
    if n > 27:
        raise InputError(f"expected a board of at most 27 coils for the default tracker (one "
                         f"carrier each below 48 kHz), got {n}: describe it in a tracker file")
    if compiling is not None:
        from .._compile_notice import model_kernels

        compiling(model_kernels(cal.model))
    spec = read_tracker(example_tracker("anser"))
    freqs = board_frequencies(n)
    sensor = SensorSpec(name=name, channels=(0,), calibration=Path(calibration),
                        device_name=device_name or sensor_device_name(name),
                        device_given=device_name is not None)
    return replace(spec, n_channels=n + 1, frequencies=freqs,
                   reference_channels=tuple(range(1, n + 1)), sensors=(sensor,),
                   sensor_gain=fit_sensor_gain(cal.model), path=None)


def board_truth(spec):
    """The simulated truth of a board tracker: its sensors' board model (a coupling model like
    any other; None for a dipole tracker). Every sensor must name a board calibration of the
    same coil count, with one channel, and the tracker one carrier per coil."""
    cals = spec.calibrations()
    boards = [c for c in cals if c is not None and hasattr(c.model, "board")]
    if not boards:
        return None
    if len(boards) != len(cals):
        raise InputError(f"{spec._where()}: expected every sensor of a board tracker to name a "
                         f"finite-coil board calibration (the simulation's truth), got "
                         f"{len(boards)} of {len(cals)}")
    return boards[0].model
