"""Monte Carlo solves beside the bound (docs/design.md#monte-carlo).

At sampled (point, orientation) pairs of a map, noisy couplings are made in one of two ways:

* ``raw`` (the default): raw ADC samples of the sensor at that fixed pose from
  :class:`openemt.signal.RawSimulator` (the target's carrier plan: its tracker file, or the
  shipped tracker file of the same source; white sensor-channel noise set so the demodulated
  coupling noise is the map's sigma, noise-free current references, no mains), demodulated by
  :func:`openemt.signal.demodulate`; every second frame is kept (the Hann frames overlap by
  half, so the kept ones are independent) and its in-phase part is the coupling;
* ``coupling``: the model's noise-free couplings plus white Gaussian noise of the map's sigma.

Each draw is solved by the solver of :func:`openemt.solve.prepare` for the model, started at
the true pose (the bound describes the error of the estimate in the true pose's basin; a cold
start's choice of basin is another question). The RMS position and rotation errors over the
draws that converged are set beside the bounds.
"""

from __future__ import annotations

import numpy as np

from ._orient import map_poses

__all__ = ["FixedCoupling", "coupling_noise_rms", "montecarlo", "rotation_errors"]


def _sensor_axis(model) -> np.ndarray:
    """The sensor axis (sensor frame) of a single-coil sensor."""
    if hasattr(model, "board"):
        return model.board.sensor.coil_axes()[0]
    a = np.asarray(model.M_se, dtype=np.float64)[:, 0]
    return a / np.linalg.norm(a)


def rotation_errors(model, R_est, R_true) -> np.ndarray:
    """Rotation error angles (rad): of the sensor axis for a 5-DOF model, else of the whole
    rotation."""
    if model.dof == 5:
        a = _sensor_axis(model)
        u, v = R_est @ a, R_true @ a
        return np.arctan2(np.linalg.norm(np.cross(u, v), axis=-1), np.sum(u * v, axis=-1))
    D = R_est @ np.swapaxes(R_true, -1, -2)
    c = np.clip((np.trace(D, axis1=-2, axis2=-1) - 1) / 2, -1.0, 1.0)
    return np.arccos(c)


class FixedCoupling:
    """A model that gives one pose's couplings whatever it is asked (the raw simulator of a
    sensor held still evaluates its model at many times)."""

    def __init__(self, C):
        self.C = C
        self.n_source, self.n_sensor = C.shape

    def coupling(self, poses):
        return np.broadcast_to(self.C, (len(poses),) + self.C.shape).copy()


def coupling_noise_rms(layout, output_rate: float, window: str, noise_rms: float,
                       drive_amplitude: float = 1.0) -> float:
    """The demodulated coupling noise (per real component) of white sensor-channel noise
    ``noise_rms`` (V rms): ``noise_rms sqrt(2 sum w^2) / sum w / (drive sensor_gain)``."""
    from ..signal import frame_length, frame_window

    _, L = frame_length(layout, output_rate, window)
    w = frame_window(window, L)
    return float(noise_rms * np.sqrt(2 * np.sum(w ** 2)) / np.sum(w)
                 / (drive_amplitude * abs(layout.sensor_gain)))


def _raw_couplings(plan, C, trials, sigma, rng):
    """``trials`` demodulated couplings ``(trials, n_so, n_se)`` of a sensor held still."""
    from ..signal import RawSignalConfig, RawSimulator, demodulate, frame_length

    layout, rate, window = plan
    hop, L = frame_length(layout, rate, window)
    step = L // hop
    noise = sigma / coupling_noise_rms(layout, rate, window, 1.0)
    cfg = RawSignalConfig(layout=layout, noise_rms=noise, reference_noise_rms=0.0)
    sim = RawSimulator(FixedCoupling(C), np.eye(4), cfg, seed=int(rng.integers(2 ** 31)),
                       coupling_stride=hop)
    n = L + (trials * step - 1) * hop
    out = demodulate(sim.read(n), layout, output_rate=rate, window=window)
    return out.couplings[::step][:trials].real


def montecarlo(model, bound_map, noise_sigma: float, *, n_points: int = 20,
               trials: int = 200, seed: int = 0, pick=None, plan=None,
               start: str = "truth") -> dict:
    """Monte Carlo RMS errors at ``n_points`` (point, orientation) pairs of ``bound_map``
    drawn at random (seeded; or the flat indices ``pick``), ``trials`` noise draws each;
    ratios MC RMS / bound. ``plan`` ``(ChannelLayout, output_rate, window)``: raw signals
    demodulated with this carrier plan; None: coupling-level noise. ``start``: ``truth``
    (each draw solved from the true pose) or ``cold`` (from the model's cold start, as with
    no prior pose: ``model.cold_start``)."""
    from ..geometry import vector_from_pose
    from ..solve import Status, prepare

    n_points, trials = int(n_points), int(trials)
    if n_points <= 0:
        return {}
    if trials < 2:
        from .._errors import InputError

        raise InputError(f"expected at least 2 Monte Carlo trials, got {trials}")
    rng = np.random.default_rng(seed)
    P_all = map_poses(bound_map.points, bound_map.rotations)
    pos = bound_map.position_std.ravel()
    rot = bound_map.rotation_std.ravel()
    usable = np.flatnonzero(np.isfinite(pos))
    if pick is None:
        pick = rng.choice(usable, size=min(n_points, usable.size), replace=False)
    pick = np.asarray(pick, dtype=np.int64)
    P = P_all[pick]
    C = model.coupling(P)
    if plan is None:
        Cn = np.repeat(C, trials, axis=0)
        Cn = Cn + noise_sigma * rng.standard_normal(Cn.shape)
    else:
        Cn = np.concatenate([_raw_couplings(plan, c, trials, noise_sigma, rng) for c in C])
    Pt = np.repeat(P, trials, axis=0)
    opts = {} if hasattr(model, "board") else {"hemisphere": None}
    solver = prepare(model, **opts)
    if start not in ("truth", "cold"):
        from .._errors import InputError

        raise InputError(f"expected a Monte Carlo start 'truth' or 'cold', got {start!r}")
    res = solver(Cn, initial=vector_from_pose(Pt) if start == "truth" else model.cold_start)
    ok = (np.asarray(res.status) == int(Status.CONVERGED)).reshape(len(pick), trials)
    dpos = np.linalg.norm(res.poses[:, :3, 3] - Pt[:, :3, 3], axis=1).reshape(len(pick), trials)
    drot = rotation_errors(model, res.poses[:, :3, :3], Pt[:, :3, :3]).reshape(len(pick), trials)
    with np.errstate(invalid="ignore", divide="ignore"):
        n_ok = ok.sum(axis=1)
        rms_pos = np.sqrt(np.where(ok, dpos ** 2, 0).sum(axis=1) / n_ok)
        rms_rot = np.sqrt(np.where(ok, drot ** 2, 0).sum(axis=1) / n_ok)
        ratio_pos = rms_pos / pos[pick]
        ratio_rot = rms_rot / rot[pick]
    good = n_ok >= 2
    return {
        "noise": ("coupling-level (white Gaussian on each coupling; no raw signal)"
                  if plan is None else
                  f"raw ADC samples (openemt.signal.RawSimulator, carriers "
                  f"{list(plan[0].frequencies)} Hz at {plan[0].sample_rate:g} S/s, "
                  f"{plan[1]:g} outputs/s, {plan[2]} window) demodulated by "
                  f"openemt.signal.demodulate"),
        "solver": f"openemt.solve.prepare({type(model).__name__}), started "
                  + ("at the true pose" if start == "truth" else
                     f"cold ({model.cold_start!r}: no prior pose)"),
        "n_points": int(len(pick)), "indices": pick.tolist(), "trials": trials, "seed": int(seed),
        "n_failed": int(ok.size - ok.sum()),
        "ratio_median": float(np.median(ratio_pos[good])) if good.any() else None,
        "ratio_rotation_median": float(np.median(ratio_rot[good])) if good.any() else None,
        "ratio_min": float(np.min(ratio_pos[good])) if good.any() else None,
        "ratio_max": float(np.max(ratio_pos[good])) if good.any() else None,
        "points": [{"position_mm": (P[i, :3, 3] * 1e3).round(3).tolist(),
                    "axis": P[i, :3, 2].round(6).tolist(),
                    "bound_mm": float(pos[pick[i]] * 1e3),
                    "montecarlo_rms_mm": float(rms_pos[i] * 1e3),
                    "bound_deg": float(np.degrees(rot[pick[i]])),
                    "montecarlo_rms_deg": float(np.degrees(rms_rot[i])),
                    "converged": int(n_ok[i])} for i in range(len(pick))],
    }
