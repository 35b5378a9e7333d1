"""``openemt bench correct``: every output-correction method on two simulated distortions,
held-out error next to the in-sample error so overfitting is visible (Kindratenko's comparison).

Poses uniform in x 0.05-0.35 m, y and z +-0.15 m with random orientations, noise of 0.1 mm and
0.03 deg per axis (noise floor 0.173 mm / 0.052 deg). Two distortions of the measured poses:

* ``smooth`` (the top-level ``methods``): quadratic, cubic and sine position terms, about 1 mm
  RMS, and a rotation distortion of about 0.25 deg RMS
  (:func:`openemt.simulate.field_distortion` at scale 1);
* ``tensor`` (``tensor_distortion``): low-order terms plus ``P2(x) P2(y) P2(z)`` (``P2`` the
  Legendre polynomial of degree 2, on coordinates scaled into [-1, 1]), about 1 mm RMS in
  all, 0.7 mm of it from the product: of degree 2 per axis but total degree 6, orthogonal over the volume to every polynomial
  of total degree <= 5, so the total-degree ``poly`` cannot reduce that part at any order it
  tries, while the tensor-product ``bernstein`` of degree 2 holds it exactly
  (:func:`tensor_distortion`). This block is scored with ``auto``: every method's held-out
  error on the same folds, and its choice.

Held-out errors are k-fold by location with the order/smoothing/degree chosen again inside
every fold (nested cross-validation, :func:`openemt.correct.fit_correction`); each method's
``held_out_over_noise`` is its held-out translation RMS over the noise floor. Two forced
overfits (an RBF with no smoothing and a fine grid) show what the held-out column catches.
"""

from __future__ import annotations

import time

import numpy as np

from .._errors import InputError

__all__ = ["add_arguments", "distorted_poses", "run", "tensor_distortion"]

METHODS = ("dlt", "poly", "bernstein", "grid", "rbf")
NOISE_M, NOISE_RAD = 1e-4, np.deg2rad(0.03)


def add_arguments(parser) -> None:
    parser.add_argument("--samples", type=int, default=600, help="pose pairs (600)")
    parser.add_argument("--folds", type=int, default=5, help="cross-validation folds (5)")
    parser.add_argument("--seed", type=int, default=0)


def tensor_distortion(p):
    """The distortion of degree 2 per axis but total degree 6 at true positions ``p`` (N, 3):
    position offsets (m) and rotation offsets (rad), see the module docstring."""
    q = (np.asarray(p) - [0.2, 0.0, 0.0]) / 0.15
    L = np.prod((3 * q ** 2 - 1) / 2, axis=1)
    dp = 1e-3 * np.stack([1.5 * q[:, 0] ** 2 - 0.8 * q[:, 1] * q[:, 2] + 6.0 * L,
                          0.7 * q[:, 0] * q[:, 1] - 4.5 * L,
                          -0.9 * q[:, 2] * q[:, 0] + 0.6 * q[:, 1] ** 2 + 3.0 * L], axis=1)
    rho = np.deg2rad(0.5) * np.stack([q[:, 1] * q[:, 0], 0.6 * q[:, 2] ** 2 - 0.3,
                                      0.8 * q[:, 0] * q[:, 2] + 0.2 * q[:, 1]], axis=1)
    return dp, rho


def distorted_poses(n: int, rng, kind: str = "smooth"):
    """(measured, reference) poses (n, 4, 4) with the ``smooth`` or ``tensor`` distortion
    described above and the noise.

    The smooth offsets are a function of the true positions; the tensor offsets a function of
    the noise-free measured positions (the form a correction fits: reference = measured -
    offset), so that their form is exactly the tensor product the module docstring describes.
    """
    from scipy.spatial.transform import Rotation

    from ..geometry import pose_from_rt
    from ..simulate import field_distortion

    p = rng.uniform([0.05, -0.15, -0.15], [0.35, 0.15, 0.15], (n, 3))
    R = Rotation.random(n, random_state=rng).as_matrix()
    if kind == "tensor":
        dp, rho = tensor_distortion(p)
        ref = pose_from_rt(Rotation.from_rotvec(-rho).as_matrix() @ R, p - dp)
        meas = pose_from_rt(Rotation.from_rotvec(NOISE_RAD * rng.standard_normal((n, 3)))
                            .as_matrix() @ R, p + NOISE_M * rng.standard_normal((n, 3)))
        return meas, ref
    ref = pose_from_rt(R, p)
    dp, rho = field_distortion(p)
    dp += NOISE_M * rng.standard_normal(dp.shape)
    rho += NOISE_RAD * rng.standard_normal(rho.shape)
    meas = pose_from_rt(Rotation.from_rotvec(rho).as_matrix() @ ref[:, :3, :3], p + dp)
    return meas, ref


_FLOOR = {"trans_rms_mm": 1e3 * NOISE_M * np.sqrt(3),
          "rot_rms_deg": float(np.rad2deg(NOISE_RAD) * np.sqrt(3))}


def _pick(errors) -> dict:
    return {k: errors[k] for k in ("trans_rms_mm", "rot_rms_deg")}


def _row(in_sample, held_out) -> dict:
    """In-sample and held-out errors of a fit, and the held-out error over the noise floor."""
    return {"in_sample": _pick(in_sample), "held_out": _pick(held_out),
            "held_out_over_noise": held_out["trans_rms_mm"] / _FLOOR["trans_rms_mm"]}


def _tensor_block(n, folds, seed) -> dict:
    """Every method, and auto's choice, on the tensor distortion (same folds for all)."""
    from ..correct import fit_auto_correction

    meas, ref = distorted_poses(n, np.random.default_rng(seed + 1), "tensor")
    t0 = time.perf_counter()
    corr = fit_auto_correction(meas, ref, k=folds, seed=seed)
    seconds = time.perf_counter() - t0
    st = corr.stats
    methods = {}
    for m, c in st["auto"]["candidates"].items():
        if m == "none":
            continue
        methods[m] = ({"skipped": c["skipped"]} if "skipped" in c
                      else _row(c["in_sample"], c["held_out"]))
    return {"samples": n, "uncorrected": _pick(st["held_out"]["uncorrected"]),
            "noise_floor": _FLOOR,
            "methods": methods, "auto_chosen": corr.method,
            "auto_selected": corr.params.get("pos_degree") if corr.method == "bernstein"
            else None, "seconds": seconds}


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
        methods[method] = _row(st["in_sample"]["corrected"], st["held_out"]["corrected"])
        if uncorrected is None:
            uncorrected = _pick(st["in_sample"]["uncorrected"])
    overfit = {}
    for name, method, opts in (("rbf_no_smoothing", "rbf", {"smoothing": 1e-8}),
                               ("grid_10_fine", "grid", {"shape": (10, 10, 10),
                                                         "smoothing": 1e-4})):
        st = fit_correction(meas, ref, method, k=args.folds, seed=args.seed, **opts).stats
        overfit[name] = _row(st["in_sample"]["corrected"], st["held_out"]["corrected"])
    return {"samples": n, "folds": args.folds, "seed": args.seed,
            "noise_floor": _FLOOR,
            "uncorrected": uncorrected, "methods": methods, "forced_overfit": overfit,
            "tensor_distortion": _tensor_block(n, args.folds, args.seed),
            "seconds": seconds}
