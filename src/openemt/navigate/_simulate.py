"""Simulated recordings with known truth for the navigation fits (tests, docs, examples).

All functions take a ``numpy.random.Generator`` and return SI arrays; noise is isotropic
Gaussian per axis.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from .._options import option
from .._result import plain
from ..geometry import pose_from_rt

__all__ = ["MOTIONS", "MotionOptions", "simulate_grid_points", "simulate_pivot_poses",
           "simulate_spin_poses", "simulate_tool_session"]


def simulate_pivot_poses(n: int, tip, pivot, rng, *, spread_deg: float = 20.0,
                         noise: float = 2e-4, n_outliers: int = 0,
                         outlier_offset: float = 0.01) -> np.ndarray:
    """Poses (n, 4, 4) of a tool pivoting about ``pivot`` (tracker frame, m) with its tip at
    ``tip`` (tool frame): rotations with ``spread_deg`` RMS per axis about the identity,
    position noise ``noise`` (m per axis); the first ``n_outliers`` poses slipped by about
    ``outlier_offset`` (m)."""
    R = Rotation.from_rotvec(rng.normal(0.0, np.deg2rad(spread_deg), (n, 3)))
    p = np.asarray(pivot, float) - R.apply(np.asarray(tip, float))
    p = p + rng.normal(0.0, noise, (n, 3))
    if n_outliers:
        d = rng.normal(size=(n_outliers, 3))
        p[:n_outliers] += outlier_offset * d / np.linalg.norm(d, axis=1, keepdims=True)
    return pose_from_rt(R.as_matrix(), p)


def simulate_spin_poses(n: int, axis, point, rng, *, start=None, spin_deg: float = 90.0,
                        origin=(0.1, 0.0, 0.2), noise: float = 2e-4,
                        wobble_deg: float = 0.2) -> np.ndarray:
    """Poses (n, 4, 4) of a tool turned by up to +-``spin_deg`` about its ``axis`` (tool frame,
    unit) through ``point`` (tool frame, m); the axis point stays at ``origin`` (tracker frame);
    ``start`` (a scipy ``Rotation``) orients the tool, ``wobble_deg`` and ``noise`` perturb
    the rotations (deg per axis) and positions (m per axis)."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    G = Rotation.from_rotvec([0.3, -0.5, 0.2]) if start is None else start
    th = rng.uniform(-np.deg2rad(spin_deg), np.deg2rad(spin_deg), n)
    R = G * Rotation.from_rotvec(np.outer(th, a)) * Rotation.from_rotvec(
        rng.normal(0.0, np.deg2rad(wobble_deg), (n, 3)))
    p = np.asarray(origin, float) - R.apply(np.asarray(point, float)) + rng.normal(0.0, noise,
                                                                                   (n, 3))
    return pose_from_rt(R.as_matrix(), p)


def simulate_grid_points(nominal, rng, *, transform=None, noise: float = 2e-4,
                         repeats: int = 1, distortion=None):
    """Measured samples of grid points: ``transform`` (4x4, nominal -> tracker) applied to the
    nominal points (M, 3), plus ``distortion(points)`` (m) if given, plus noise per sample.
    Returns (samples (M * repeats, 3) in point-major order, labels (M * repeats,))."""
    nom = np.asarray(nominal, float)
    T = np.eye(4) if transform is None else np.asarray(transform, float)
    true = nom @ T[:3, :3].T + T[:3, 3]
    if distortion is not None:
        true = true + distortion(true)
    pts = np.repeat(true, repeats, axis=0) + rng.normal(0.0, noise, (len(nom) * repeats, 3))
    return pts, np.repeat(np.arange(len(nom)), repeats)


# ------------------------------------------------------------------------------------------
# a tracked tool performing the navigation motions on a simulated tracker

#: The motions :func:`simulate_tool_session` makes.
MOTIONS = ("pivot", "spin", "fiducials", "grid")
_LOG_HEADER = "time_s,x_m,y_m,z_m,rx_rad,ry_rad,rz_rad,status,residual,distortion,distorted"


@dataclass(frozen=True, kw_only=True)
class MotionOptions:
    """A tracked tool with a tip performing a navigation motion on a simulated tracker."""

    motion: str | None = option(None, "instead of the apparatus: a tracked tool with a tip "
                                "performing this motion; -o names the track log (.csv) and its "
                                "truth is written beside it (docs/navigation.md)",
                                choices=MOTIONS)
    tip_mm: tuple[float, ...] = option((2.0, -1.0, 120.0), "--motion: the tool tip in the tool "
                                       "frame (mm)")
    rate_hz: float = option(40.0, "--motion: pose rate (Hz)")
    n_fiducials: int = option(6, "--motion fiducials: points touched")
    preset: str = option("concentric", "", cli=False)
    snr_db: float | None = option(None, "", cli=False)
    seed: int = option(0, "", cli=False)
    output: str = option("", "", cli=False)


def _path(times, key, values):
    """Values (K, d) at key times (K,), interpolated linearly at ``times``."""
    return np.stack([np.interp(times, key, v) for v in np.asarray(values).T], axis=1)


def _visits(home, targets, rng, tilt_deg, rate, move_s=1.5, dwell_s=1.5):
    """Times and (rotation vectors, tip positions) of a tool visiting ``targets`` in turn,
    still for ``dwell_s`` at each, with a tilt drawn per target; ends moving away."""
    k = len(targets)
    tilts = (Rotation.from_rotvec(rng.normal(0, np.deg2rad(tilt_deg), (k, 3))) * home).as_rotvec()
    pos = np.concatenate([targets[:1] + [0, 0, 0.03], np.repeat(targets, 2, axis=0),
                          targets[-1:] + [0, 0, 0.03]])
    rot = np.concatenate([tilts[:1], np.repeat(tilts, 2, axis=0), tilts[-1:]])
    key = np.concatenate([[0.0], (move_s + np.arange(k)[:, None] * (move_s + dwell_s)
                                  + [0.0, dwell_s]).ravel()])
    key = np.append(key, key[-1] + move_s)
    t = np.arange(0.0, key[-1], 1.0 / rate)
    return t, Rotation.from_rotvec(_path(t, key, rot)), _path(t, key, pos)


def simulate_tool_session(options: MotionOptions):
    """Simulate a tracked tool (a 6-DOF sensor with a tip at ``tip_mm``) performing a pivot,
    spin, fiducial-touch or grid-visit motion in the preset's volume, and write its track log.

    The poses are those the tracker reports: the preset's finite-coil couplings at the true
    poses, Gaussian noise at ``snr_db`` (default 70 dB), solved with the preset's
    dipole-equivalent truth calibration, so the log carries the solver's status and the
    dipole approximation's error. Writes ``output`` (a track-log CSV, the columns of ``openemt
    track --log``) and beside it ``<stem>.truth.json`` (tip, pivot point, axis, fiducials in
    both frames, image transform, grid), and for ``fiducials`` the image fiducials as
    ``<stem>.image.mrk.json``, for ``grid`` the nominal grid as ``<stem>.nominal.csv``.
    Returns a :class:`NavigationRun` whose ``result`` is the truth dict.
    """
    import json

    from .._atomic import atomic_path
    from .._errors import InputError
    from ..geometry import pose_from_vector, vector_from_pose
    from ..simulate import add_noise, get_preset, noise_sigma, truth_calibration, working_volume
    from ..solve import solve
    from ._markups import _text, write_markups
    from ._steps import NavigationRun, _checked

    o = options
    if o.motion not in MOTIONS:
        raise InputError(f"expected a motion in {MOTIONS}, got {o.motion!r}")
    p = get_preset(o.preset)
    if p.n_sensor < 2:
        raise InputError(f"expected a preset with a 6-DOF sensor (two or more coils) for a "
                         f"tool motion, got {p.name!r} with {p.n_sensor} sensor coil")
    out = Path(o.output)
    if out.suffix.lower() != ".csv":
        raise InputError(f"expected -o naming a track log ending in .csv for --motion, got "
                         f"{str(out)!r}")
    stem = out.with_suffix("")
    truth_path = stem.with_suffix(".truth.json")
    rate = float(o.rate_hz)
    if not 1 <= rate <= 1000:
        raise InputError(f"expected --rate-hz within 1 to 1000, got {o.rate_hz!r}")
    tip = 1e-3 * np.asarray(o.tip_mm, dtype=np.float64)
    if tip.shape != (3,) or not np.all(np.isfinite(tip)) or not 0.01 <= np.linalg.norm(tip) <= 0.5:
        raise InputError(f"expected --tip-mm as 3 numbers, a tip 10 to 500 mm from the sensor, "
                         f"got {o.tip_mm!r}")
    rng = np.random.default_rng(o.seed)
    lo, hi, R0 = working_volume(p)
    centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    home = Rotation.from_matrix(R0)
    pivot = centre + home.apply(tip)            # the sensor at the centre at home
    truth = {"motion": o.motion, "preset": p.name, "seed": o.seed, "tip_mm": 1e3 * tip,
             "poses_from": "finite-coil couplings at the true poses, noise at snr_db, solved "
                          "with the preset's truth calibration (lm)"}
    writes = []
    if o.motion in ("pivot", "spin"):
        t = np.arange(0.0, 20.0, 1.0 / rate)
        if o.motion == "pivot":
            a = np.deg2rad(25.0)
            rv = np.column_stack([a * np.sin(2 * np.pi * t / 7.0),
                                  a * np.sin(2 * np.pi * t / 5.3 + 1.0),
                                  0.3 * a * np.sin(2 * np.pi * t / 11.0)])
            R = Rotation.from_rotvec(rv) * home
        else:
            axis = tip / np.linalg.norm(tip)
            R = home * Rotation.from_rotvec(np.outer(np.deg2rad(80.0) * np.sin(
                2 * np.pi * t / 8.0), axis))
            truth["axis_tool"] = axis
        tips = np.broadcast_to(pivot, (len(t), 3))
        truth["pivot_mm"] = 1e3 * pivot
    else:
        if o.motion == "fiducials":
            k = int(o.n_fiducials)
            if not 3 <= k <= 100:
                raise InputError(f"expected --n-fiducials within 3 to 100, got {k}")
            targets = pivot + rng.uniform(-0.8, 0.8, (k, 3)) * half
            T = pose_from_vector(np.concatenate([rng.uniform(-0.2, 0.2, 3),
                                                 rng.normal(0, 0.5, 3)]))
            image = targets @ T[:3, :3].T + T[:3, 3]
            labels = [f"F-{i + 1}" for i in range(k)]
            fid = stem.with_suffix(".image.mrk.json")
            writes.append((fid, lambda path: write_markups(path, image, labels)))
            truth.update(image_from_tracker=T, fiducials_tracker_mm=1e3 * targets,
                         fiducials_image_mm=1e3 * image, labels=labels)
        else:
            from ._assess import regular_grid

            nominal = regular_grid(0.025, (3, 3, 2))
            G = pose_from_vector(np.concatenate([np.zeros(3), rng.normal(0, 0.1, 3)]))
            G[:3, 3] = pivot - G[:3, :3] @ nominal.mean(axis=0)
            targets = nominal @ G[:3, :3].T + G[:3, 3]
            text = "x_mm,y_mm,z_mm\n" + "".join(f"{a:.6f},{b:.6f},{c:.6f}\n"
                                                 for a, b, c in 1e3 * nominal)
            writes.append((stem.with_suffix(".nominal.csv"), lambda path: _text(path, text)))
            truth.update(grid_to_tracker=G, grid_nominal_mm=1e3 * nominal,
                         grid_tracker_mm=1e3 * targets)
        t, R, tips = _visits(home, targets, rng, 10.0 if o.motion == "fiducials" else 0.0,
                             rate)
    true = pose_from_rt(R.as_matrix(), tips - R.apply(tip))
    C = p.model.coupling(true)
    C = add_noise(C, noise_sigma(C, snr_db=70.0 if o.snr_db is None else o.snr_db), rng)
    res = solve(C, truth_calibration(p), hemisphere=tuple(centre / np.linalg.norm(centre)))
    rows = np.column_stack([t, vector_from_pose(res.poses), res.status, res.residual,
                            np.zeros(len(t)), np.zeros(len(t))])
    with atomic_path(out) as tmp:
        np.savetxt(tmp, rows, delimiter=",", header=_LOG_HEADER, comments="",
                   fmt=["%.6f"] + ["%.9g"] * 6 + ["%d", "%.6g", "%.6g", "%d"])
    writes.append((truth_path, lambda path: _text(path, json.dumps(plain(truth), indent=1)
                                                  + "\n")))
    for path, _ in writes:
        _checked(path, out)
    for path, write in writes:
        write(path)
    files = [str(path) for path, _ in writes]
    n_ok = int(np.sum(res.status == 0))
    s = {"output": str(out), "files": files, "n_samples": len(t), "n_converged": n_ok,
         "truth": plain(truth)}
    lines = [f"simulated {o.motion} of a tool with its tip at "
             + ", ".join(f"{v:g}" for v in 1e3 * tip) + f" mm on {p.name}: {len(t)} poses "
             f"({n_ok} converged) at {rate:g} Hz", f"  -> {out}, truth {', '.join(files)}"]
    return NavigationRun(truth, s, tuple(lines))
