"""``openemt design map``: the Cramer-Rao bound of position and orientation over a volume
(docs/design.md#map), with Monte Carlo solves beside it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._errors import InputError
from .._options import option
from .._result import Result
from ._crb import pose_bound
from ._orient import ORIENTATIONS, map_poses, orientation_set
from ._targets import Volume, resolve_target

__all__ = ["BoundMap", "DesignMap", "MapOptions", "bound_map", "design_map", "map_summary",
           "noise_from_snr"]


@dataclass(frozen=True)
class MapOptions:
    """The options of :func:`design_map` (and the map part of ``optimize``)."""

    target: str = option("anser", "built-in board (anser, anser-6dof), rig preset (concentric, "
                         "dipole-approx), board file, calibration or tracker file",
                         positional=True)
    x_mm: tuple[float, ...] | None = option(None, "x range of the volume (mm; default: the "
                                            "target's, docs/design.md#volumes)", metavar="MM")
    y_mm: tuple[float, ...] | None = option(None, "y range of the volume (mm)", metavar="MM")
    z_mm: tuple[float, ...] | None = option(None, "z range of the volume (mm)", metavar="MM")
    grid: tuple[int, ...] | None = option(None, "grid points along x, y, z (default 7 7 5 for a "
                                          "board, 5 5 5 for a rig)", metavar="N")
    orientations: str = option("axes", "sensor orientations at each point: down (sensor z along "
                               "-z), axes (+-x, +-y, +-z) or sphere (--n-orientations directions)",
                               choices=ORIENTATIONS)
    n_orientations: int = option(12, "directions of --orientations sphere")
    noise_sigma: float | None = option(None, "white noise standard deviation of each coupling "
                                       "(the couplings' units)")
    snr_db: float | None = option(None, "noise from an SNR (dB) against the RMS noise-free "
                                  "coupling over the volume (default 80 dB when no --noise-sigma)")
    target_mm: float = option(0.1, "report the fraction of the volume whose position bound is "
                              "below this (mm)")
    montecarlo: int = option(20, "sampled (point, orientation) pairs solved in Monte Carlo (0: "
                             "none)")
    montecarlo_noise: str = option("raw", "Monte Carlo on raw ADC samples through the signal "
                                   "simulator and demodulator, or white noise added to the "
                                   "couplings", choices=("raw", "coupling"))
    montecarlo_start: str = option("truth", "solve each Monte Carlo draw from the true pose, or "
                                   "cold (the solver's start with no prior pose)",
                                   choices=("truth", "cold"))
    trials: int = option(200, "noise draws per Monte Carlo point")
    seed: int = option(0, "seed of the Monte Carlo draws")
    output: str | None = option(None, "write a self-contained HTML page here",
                                flag=("-o", "--output"))

    def volume(self, default: Volume | None) -> Volume:
        ranges = []
        for name in ("x_mm", "y_mm", "z_mm"):
            v = getattr(self, name)
            if v is None and default is None:
                raise InputError("expected a volume (--x-mm, --y-mm, --z-mm) for this target "
                                 "(boards and the rig presets have a default one), got none")
            if v is None:
                ranges.append(getattr(default, name[0]))
                continue
            if len(v) != 2:
                raise InputError(f"expected two values (low high, mm) for --"
                                 f"{name.replace('_', '-')}, got {len(v)}")
            ranges.append((v[0] * 1e-3, v[1] * 1e-3))
        n = (default.n if default is not None else (5, 5, 5)) if self.grid is None else \
            tuple(int(k) for k in self.grid)
        if len(n) != 3:
            raise InputError(f"expected three grid sizes (nx ny nz), got {len(n)}")
        return Volume(*ranges, n)


class BoundMap:
    """Bounds at every (point, orientation): ``position_std`` and ``rotation_std``, both
    ``(n_points, n_orientations)`` (m, rad), at ``points (n_points, 3)`` with sensor
    rotations ``rotations (n_orientations, 3, 3)``."""

    def __init__(self, points, rotations, position_std, rotation_std):
        self.points = points
        self.rotations = rotations
        self.position_std = position_std
        self.rotation_std = rotation_std

    def point_rms(self, which: str = "position") -> np.ndarray:
        """Per point, the RMS over orientations of the bound (m or rad)."""
        a = self.position_std if which == "position" else self.rotation_std
        return np.sqrt(np.mean(a ** 2, axis=1))


def bound_map(model, points, rotations, noise_sigma: float) -> BoundMap:
    """The pose bound of ``model`` at every point and orientation."""
    P = map_poses(points, rotations)
    b = pose_bound(model, P, noise_sigma)
    shape = (len(points), len(rotations))
    return BoundMap(points, rotations, b.position_std.reshape(shape),
                    b.rotation_std.reshape(shape))


def noise_from_snr(model, points, rotations, snr_db: float) -> float:
    """The coupling noise of an SNR: RMS of the noise-free couplings over every point and
    orientation, over ``10**(snr_db / 20)``."""
    C = model.coupling(map_poses(points, rotations))
    return float(np.sqrt(np.mean(C ** 2)) / 10 ** (float(snr_db) / 20))


def map_summary(values, target=None) -> dict:
    """Median, 95th percentile and maximum of ``values`` (finite ones; ``n_singular``
    counts the rest), and the fraction at or below ``target``."""
    v = np.asarray(values, dtype=np.float64).ravel()
    fin = v[np.isfinite(v)]
    out = {"median": float(np.median(fin)) if fin.size else float("nan"),
           "p95": float(np.percentile(fin, 95)) if fin.size else float("nan"),
           "max": float(np.max(fin)) if fin.size else float("nan"),
           "n_singular": int(v.size - fin.size)}
    if target is not None:
        out["fraction_below_target"] = float(np.mean(v <= target))
    return out


def _scaled(d: dict, k: float) -> dict:
    return {key: (val * k if key in ("median", "p95", "max") else val)
            for key, val in d.items()}


@dataclass(frozen=True, eq=False)
class DesignMap(Result):
    """The result of :func:`design_map` (``to_dict()`` is ``openemt design map --json``)."""

    target: str
    kind: str
    dof: int
    n_source: int
    n_sensor: int
    volume: dict
    orientations: str
    n_orientations: int
    n_points: int
    noise_sigma: float
    noise: str
    position_mm: dict
    rotation_deg: dict
    target_mm: float
    montecarlo: dict
    montecarlo_ratio_median: float | None
    output: str | None
    bounds: BoundMap = None
    _not_in_dict = ("bounds",)

    def lines(self) -> list:
        """The human summary (``openemt design map`` on stderr)."""
        s, mc = self.position_mm, self.montecarlo
        return [f"{self.target}: position bound median {s['median']:.4f} mm, p95 "
                f"{s['p95']:.4f} mm, max {s['max']:.4f} mm (noise {self.noise_sigma:.3g})"] + (
            [f"Monte Carlo RMS / bound, median over {mc['n_points']} points: "
             f"{mc['ratio_median']:.3f}"] if mc else [])


def map_of(target, options: MapOptions, noise_sigma=None, rng_seed=None):
    """The map of a resolved target: (:class:`BoundMap`, volume, noise sigma, noise note)."""
    volume = options.volume(target.volume)
    rotations = orientation_set(options.orientations, options.n_orientations)
    points = volume.points()
    if noise_sigma is not None:
        sigma, note = float(noise_sigma), "given"
    elif options.noise_sigma is not None:
        if options.snr_db is not None:
            raise InputError("expected one of --noise-sigma and --snr-db, got both")
        sigma, note = float(options.noise_sigma), "noise_sigma"
        if not (np.isfinite(sigma) and sigma > 0):
            raise InputError(f"expected a positive --noise-sigma, got {options.noise_sigma}")
    elif target.tracker is not None and options.snr_db is None:
        from ..signal import RawSignalConfig
        from ._montecarlo import coupling_noise_rms
        from ._targets import carrier_plan

        layout, rate, window = carrier_plan(target)
        v = float(target.tracker.simulation.get("noise_rms", RawSignalConfig().noise_rms))
        sigma = coupling_noise_rms(layout, rate, window, v)
        note = (f"the tracker's ADC figures: {v:g} V rms sensor-channel noise, sensor gain "
                f"{layout.sensor_gain:g} V per coupling x A, 1 A drive, {rate:g} outputs/s "
                f"{window} window")
    else:
        snr = 80.0 if options.snr_db is None else float(options.snr_db)
        if not np.isfinite(snr):
            raise InputError(f"expected a finite --snr-db, got {options.snr_db}")
        sigma = noise_from_snr(target.model, points, rotations, snr)
        note = f"snr_db {snr:g} (RMS noise-free coupling over the volume)"
    return bound_map(target.model, points, rotations, sigma), volume, sigma, note


def montecarlo_plan(target, options):
    """The carrier plan of a raw-signal Monte Carlo (None: coupling-level noise)."""
    if options.montecarlo_noise not in ("raw", "coupling"):
        raise InputError(f"expected --montecarlo-noise raw or coupling, got "
                         f"{options.montecarlo_noise!r}")
    if options.montecarlo_noise == "coupling" or options.montecarlo <= 0:
        return None
    from ._targets import carrier_plan

    plan = carrier_plan(target)
    if plan is None:
        raise InputError(f"expected a target with a carrier plan for a raw-signal Monte Carlo "
                         f"(a tracker file, or {target.model.n_source} source and "
                         f"{target.model.n_sensor} sensor coils as a shipped tracker), got "
                         f"none: use --montecarlo-noise coupling")
    return plan


def design_map(options: MapOptions | None = None, **overrides) -> DesignMap:
    """The CRB map of a tracker over a volume, with Monte Carlo solves at sampled points.

    Examples
    --------
    >>> from openemt.design import design_map
    >>> m = design_map(target="anser", grid=(3, 3, 2), orientations="down", montecarlo=0)
    >>> m.dof, m.n_points, m.position_mm["median"] > 0
    (5, 18, True)
    """
    from dataclasses import replace

    from ._montecarlo import montecarlo

    opts = replace(options or MapOptions(), **overrides)
    target = resolve_target(opts.target)
    bm, volume, sigma, note = map_of(target, opts)
    mc = montecarlo(target.model, bm, sigma, n_points=opts.montecarlo, trials=opts.trials,
                    seed=opts.seed, plan=montecarlo_plan(target, opts),
                    start=opts.montecarlo_start)
    result = DesignMap(
        target=str(opts.target), kind=target.kind, dof=int(target.model.dof),
        n_source=int(target.model.n_source), n_sensor=int(target.model.n_sensor),
        volume=volume.to_dict(), orientations=opts.orientations,
        n_orientations=len(bm.rotations), n_points=len(bm.points), noise_sigma=sigma,
        noise=note, position_mm=_scaled(map_summary(bm.position_std, opts.target_mm * 1e-3),
                                        1e3),
        rotation_deg=_scaled(map_summary(bm.rotation_std), float(np.degrees(1.0))),
        target_mm=float(opts.target_mm), montecarlo=mc,
        montecarlo_ratio_median=mc.get("ratio_median"), output=opts.output, bounds=bm)
    if opts.output:
        from ._html import map_document

        map_document(result).write(opts.output)
    return result
