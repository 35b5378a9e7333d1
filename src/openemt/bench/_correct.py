"""``openemt bench correct``: every output-correction method on one simulated distortion,
held-out error next to the in-sample error so overfitting is visible (Kindratenko's comparison).

Poses uniform in x 0.05-0.35 m, y and z +-0.15 m with random orientations; the measured poses
carry a smooth position distortion (quadratic, cubic and sine terms, about 1 mm RMS) and a
rotation distortion (about 0.25 deg RMS), plus noise of 0.1 mm and 0.03 deg per axis (noise
floor 0.173 mm / 0.052 deg). Held-out errors are k-fold by location with the order/smoothing
chosen again inside every fold (nested cross-validation, :func:`openemt.correct.fit_correction`).
Two forced overfits (an RBF with no smoothing and a fine grid) show what the held-out column
catches.
"""

from __future__ import annotations

import time

import numpy as np

from .._errors import InputError

__all__ = ["add_arguments", "distorted_poses", "distortion", "run"]

METHODS = ("dlt", "poly", "grid", "rbf")


def add_arguments(parser) -> None:
    parser.add_argument("--samples", type=int, default=600, help="pose pairs (600)")
    parser.add_argument("--folds", type=int, default=5, help="cross-validation folds (5)")
    parser.add_argument("--seed", type=int, default=0)


def distortion(p, scale: float = 1.0):
    """The smooth distortion at true positions ``p`` (N, 3): position offsets (m) and rotation
    offsets (rotation vectors, rad), about 1 mm and 0.25 deg RMS at ``scale`` 1 over the
    volume described above (:func:`openemt.simulate.field_distortion`)."""
    from ..simulate._hybrid import field_distortion

    return field_distortion(p, scale)


def distorted_poses(n: int, rng):
    """(measured, reference) poses (n, 4, 4) with the smooth distortion described above."""
    from scipy.spatial.transform import Rotation

    from ..geometry import pose_from_rt

    p = rng.uniform([0.05, -0.15, -0.15], [0.35, 0.15, 0.15], (n, 3))
    ref = pose_from_rt(Rotation.random(n, random_state=rng).as_matrix(), p)
    dp, rho = distortion(p)
    dp += 1e-4 * rng.standard_normal(dp.shape)
    rho += np.deg2rad(0.03) * rng.standard_normal(rho.shape)
    meas = pose_from_rt(Rotation.from_rotvec(rho).as_matrix() @ ref[:, :3, :3], p + dp)
    return meas, ref


def _row(stats):
    keys = ("trans_rms_mm", "rot_rms_deg")
    return {"in_sample": {k: stats["in_sample"]["corrected"][k] for k in keys},
            "held_out": {k: stats["held_out"]["corrected"][k] for k in keys}}


def run(args) -> dict:
    from ..correct import fit_correction

    n = int(args.samples)
    if n < 50:
        raise InputError(f"expected --samples >= 50, got {n}")
    rng = np.random.default_rng(args.seed)
    meas, ref = distorted_poses(n, rng)
    methods, seconds = {}, {}
    uncorrected = None
    for method in METHODS:
        t0 = time.perf_counter()
        st = fit_correction(meas, ref, method, k=args.folds, seed=args.seed).stats
        seconds[method] = time.perf_counter() - t0
        methods[method] = _row(st)
        if uncorrected is None:
            u = st["in_sample"]["uncorrected"]
            uncorrected = {"trans_rms_mm": u["trans_rms_mm"], "rot_rms_deg": u["rot_rms_deg"]}
    overfit = {}
    for name, method, opts in (("rbf_no_smoothing", "rbf", {"smoothing": 1e-8}),
                               ("grid_10_fine", "grid", {"shape": (10, 10, 10),
                                                         "smoothing": 1e-4})):
        st = fit_correction(meas, ref, method, k=args.folds, seed=args.seed, **opts).stats
        overfit[name] = _row(st)
    return {"samples": n, "folds": args.folds, "seed": args.seed,
            "noise_floor": {"trans_rms_mm": 0.1 * np.sqrt(3), "rot_rms_deg": 0.03 * np.sqrt(3)},
            "uncorrected": uncorrected, "methods": methods, "forced_overfit": overfit,
            "seconds": seconds}
