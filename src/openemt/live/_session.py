"""From a tracker description to running parts: the backend for a source and the pipeline's
sensors (models, corrections, device names, filters)."""

from __future__ import annotations

import numpy as np

from .._constants import SIMULATED_MAINS_AMPLITUDES_V
from .._errors import InputError
from ..field import DipoleModel
from ._tracker_file import TrackerSpec

__all__ = ["tracker_backend", "tracker_sensors"]


def tracker_sensors(spec: TrackerSpec, *, filter=None) -> list:
    """One :class:`~openemt.live.SensorSetup` per sensor of ``spec``: its coupling columns,
    the model and linear correction of its calibration (the simulated preset's model when it
    names none), its OpenIGTLink device name and its filter (the file's
    ``[filter.sensors.<name>]``, else ``[filter]``; ``filter`` overrides both)."""
    from ._pipeline import SensorSetup

    cals = spec.calibrations()
    # sensors calibrated by one file share its model (and so one batched solver call)
    first: dict = {}
    for i, s in enumerate(spec.sensors):
        if s.calibration is not None:
            key = s.calibration.resolve()
            cals[i] = first.setdefault(key, cals[i])
    preset_model = None
    out = []
    boards: dict = {}
    for s, cols, cal in zip(spec.sensors, spec.sensor_columns(), cals):
        if cal is not None and not isinstance(cal.model, DipoleModel):
            # not a dipole model: the solver of openemt.solve.prepare for its model (the
            # dipole path below adds the preset model, hemisphere and correction per sensor)
            from ._board import board_solver

            solver = boards.setdefault(id(cal), board_solver(cal.model))
            out.append(SensorSetup(name=s.name, columns=cols, solver=solver,
                                   device_name=s.device_name,
                                   filter=s.filter_or(spec.filter) if filter is None else filter,
                                   tip=s.tip))
            continue
        if cal is None:
            if preset_model is None:
                from ..simulate import get_preset

                preset_model = get_preset(spec.simulation.get("preset", "concentric")).dipole
            model, corr = preset_model, None
        else:
            model, corr = cal.model, getattr(cal, "linear_correction", None)
        out.append(SensorSetup(name=s.name, columns=cols, model=model, correction=corr,
                               hemisphere=s.hemisphere, device_name=s.device_name,
                               filter=s.filter_or(spec.filter) if filter is None else filter,
                               tip=s.tip))
    return out


def tracker_backend(spec: TrackerSpec, source: str, *, file=None, device=None,
                    realtime: bool = True, duration: float | None = None, seed=None,
                    noise_rms: float | None = None, eddy_strength: float | None = None,
                    chunk: int = 640, match_layout: bool = True, trajectory=None):
    """The backend of ``source`` (``"sim"``, ``"replay"`` or ``"sound"``) for a tracker.

    ``sim`` simulates the tracker's channel layout (every sensor follows ``trajectory``, a
    callable of times giving poses, by default :func:`~openemt.live.default_trajectory`,
    shifted by its ``simulation_offset``; truth model from ``[simulation] preset``); ``replay`` reads a raw recording whose channel layout must
    match the tracker's (``match_layout=False``: the recording's own layout is used); ``sound``
    opens the audio input ``device`` with ``adc.channels``
    channels at ``adc.sample_rate``.
    """
    from ._backends import ReplayBackend, SimulatedBackend, SoundDeviceBackend

    layout = spec.layout()
    if source == "sound":
        return SoundDeviceBackend(layout, device=device, channels=spec.n_channels,
                                  chunk=chunk)
    if source == "replay":
        b = ReplayBackend(file, realtime=realtime, chunk=chunk)
        if not match_layout:
            return b
        got = b.layout
        same = (got.sample_rate == layout.sample_rate
                and got.frequencies == layout.frequencies
                and got.sensor_channels == layout.sensor_channels
                and got.reference_channels == layout.reference_channels)
        if not same:
            raise InputError(f"expected a recording with the channel layout of "
                             f"{spec._where()} (sensor channels {layout.sensor_channels}, "
                             f"references {layout.reference_channels}, "
                             f"{layout.sample_rate:g} Hz), got {got.sensor_channels}, "
                             f"{got.reference_channels}, {got.sample_rate:g} Hz in {str(file)!r}")
        return b
    if source != "sim":
        raise InputError(f"expected a source in ('sim', 'replay', 'sound'), got {source!r}")
    from ..signal import RawSignalConfig
    from ..simulate import get_preset
    from ._board import board_trajectory, board_truth

    sim = spec.simulation
    model, path = board_truth(spec), board_trajectory   # a board calibration's truth
    if model is None:
        preset = get_preset(sim.get("preset", "concentric"))
        n_coils = {len(s.channels) for s in spec.sensors}
        if n_coils != {preset.n_sensor} or preset.n_source != len(spec.frequencies):
            raise InputError(f"{spec._where()}: expected sensors of {preset.n_sensor} coils "
                             f"and {preset.n_source} carriers for the simulated preset "
                             f"{preset.name!r}, got {sorted(n_coils)} coils and "
                             f"{len(spec.frequencies)} carriers")
        model, path = preset.dipole, None
    kw = {"mains_amplitudes": sim.get("mains_amplitudes", SIMULATED_MAINS_AMPLITUDES_V)}
    for key, over in (("noise_rms", noise_rms), ("eddy_strength", eddy_strength)):
        v = sim.get(key) if over is None else over
        if v is not None:
            kw[key] = v
    cfg = RawSignalConfig(layout=layout, **kw)
    offsets = np.array([s.simulation_offset for s in spec.sensors], dtype=np.float64)
    return SimulatedBackend(model, path if trajectory is None else trajectory, config=cfg,
                            seed=sim.get("seed", 0)
                            if seed is None else seed, realtime=realtime, duration=duration,
                            offsets=offsets, chunk=chunk)
