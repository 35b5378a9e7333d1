"""``openemt bench hybrid``: correcting an EM tracker against an optical tracker end to end on
simulated data (docs/alignment.md#benchmark).

An EM sensor and an optical marker are rigidly joined (unknown X: marker -> sensor) and the
camera sits at an unknown place (Y: camera -> field generator). True sensor poses are uniform in
x 0.05-0.35 m, y and z +-0.15 m with random orientations. The EM tracker reports them with the
smooth field distortion of ``openemt bench correct`` scaled to about 3 mm and 0.75 deg RMS, plus
noise (0.1 mm and 0.03 deg per axis); the optical tracker reports ``Y^-1 A X`` with its own
noise (0.15 mm, 0.05 deg per axis). For each number of pose pairs (10, 30, 100, 300) the bench

1. solves ``A_i X = Y B_i`` (:func:`openemt.align.fit_axyb`) and reports the error of X and Y
   against the truth and against the large-sample limit (the same fit on 3000 noise-free
   pairs), the latter also in standard errors;
2. maps the optical poses onto the sensor (``Y B_i X^-1``) and fits ``--method auto``
   (:func:`openemt.correct.fit_auto_correction`): the held-out errors of the chosen method and
   of "none";
3. applies the correction to 2000 new EM poses and scores them against the noise-free optical
   poses mapped with the estimated X and Y (what a perfect reference tracker would give).

The distortion has a rigid part (a mean offset and tilt of the field) that no measurement can
tell apart from a different Y; the fit puts it into Y, so Y differs from the truth by that
part even with infinitely many pairs, and the correction then works in the field generator
frame that Y defines. The large-sample limit shows this bias; the estimation error is the
distance to the limit.

The noise-implied floor is what a perfect correction with perfect X and Y would leave: the
RMS of the EM and (mapped) optical noise against each other for the held-out figures, and the
EM noise alone for the test figures. ``auto_not_worse`` checks on the new poses that the
chosen correction is not worse than none.
"""

from __future__ import annotations

import time

import numpy as np

from .._errors import InputError
from ..simulate import (
    DISTORTION_SCALE,
    EM_NOISE,
    OPTICAL_NOISE,
    draw_xy,
    field_distortion,
    simulate_hybrid,
)

__all__ = ["PAIR_COUNTS", "add_arguments", "run", "simulate_hybrid"]

PAIR_COUNTS = (10, 30, 100, 300)
N_TEST = 2000


def add_arguments(parser) -> None:
    parser.add_argument("--pairs", default=",".join(map(str, PAIR_COUNTS)),
                        help="comma-separated numbers of pose pairs (10,30,100,300)")
    parser.add_argument("--folds", type=int, default=5, help="cross-validation folds (5)")
    parser.add_argument("--seed", type=int, default=0)


def _pose_diff(P, T):
    from ..evaluate import pose_error_magnitudes

    t, r = pose_error_magnitudes(P[None], T[None])
    return float(1e3 * t[0]), float(np.rad2deg(r[0]))


def _z(P, T, se):
    from scipy.spatial.transform import Rotation

    d = np.concatenate([P[:3, 3] - T[:3, 3],
                        Rotation.from_matrix(P[:3, :3] @ T[:3, :3].T).as_rotvec()])
    return float(np.max(np.abs(d / se)))


def _rms(t, r) -> dict:
    return {"trans_rms_mm": float(1e3 * np.sqrt(np.mean(t ** 2))),
            "rot_rms_deg": float(np.rad2deg(np.sqrt(np.mean(r ** 2))))}


def _one(n, X, Y, limit, rng, folds, seed) -> dict:
    from ..align import fit_axyb, reference_in_measured_frame
    from ..correct import fit_auto_correction, held_out_score_mm
    from ..evaluate import pose_error_magnitudes
    from ..geometry import invert

    sim = simulate_hybrid(n, X, Y, rng)
    he = fit_axyb(sim["em"], sim["optical"], folds=min(folds, max(2, n // 3)), seed=seed)
    ref = reference_in_measured_frame(sim["optical"], he.X, he.Y)
    keep = he.inlier
    k = min(folds, int(keep.sum()) // 2)
    corr = fit_auto_correction(sim["em"][keep], ref[keep], k=k, seed=seed)
    st = corr.stats
    floor_pairs = _rms(*pose_error_magnitudes(
        sim["em_undistorted"], reference_in_measured_frame(sim["optical"], X, Y)))
    test = simulate_hybrid(N_TEST, X, Y, rng)
    # the noise-free optical poses, mapped with the estimated X and Y
    test_ref = reference_in_measured_frame(invert(Y) @ test["truth"] @ X, he.X, he.Y)
    unc = _rms(*pose_error_magnitudes(test["em"], test_ref))
    cor = _rms(*pose_error_magnitudes(corr.apply(test["em"]), test_ref))
    floor_test = _rms(*pose_error_magnitudes(test["em_undistorted"], test["truth"]))
    align = {}
    for name, est, se, true, lim in (("X", he.X, he.X_se, X, limit[0]),
                                     ("Y", he.Y, he.Y_se, Y, limit[1])):
        t, r = _pose_diff(est, true)
        tl, rl = _pose_diff(est, lim)
        align.update({f"{name}_error_mm": t, f"{name}_error_deg": r,
                      f"{name}_error_vs_limit_mm": tl, f"{name}_error_vs_limit_deg": rl,
                      f"{name}_max_abs_z_vs_limit": _z(est, lim, se)})
    align.update({"n_outliers": int((~keep).sum()),
                  "residual_trans_rms_mm": he.summary()["residual_trans_rms_mm"]})
    return {
        "pairs": n, "align": align, "chosen": corr.method,
        "held_out": {"none": _brief(st["held_out"]["uncorrected"]),
                     "chosen": _brief(st["held_out"]["corrected"]),
                     "floor": floor_pairs, "folds": st["held_out"]["n_folds"]},
        "test": {"uncorrected": unc, "corrected": cor, "floor": floor_test},
        "auto_not_worse": bool(held_out_score_mm(cor) <= held_out_score_mm(unc) + 1e-9),
        "warnings": st["warnings"],
    }


def _brief(summary) -> dict:
    return {k: summary[k] for k in ("trans_rms_mm", "rot_rms_deg") if k in summary}


def _limit(X, Y, rng):
    """X, Y fitted to many noise-free pairs: where the estimate goes as pairs grow."""
    from scipy.spatial.transform import Rotation

    from ..align import fit_axyb
    from ..geometry import invert, pose_from_rt

    n = 3000
    p = rng.uniform([0.05, -0.15, -0.15], [0.35, 0.15, 0.15], (n, 3))
    truth = pose_from_rt(Rotation.random(n, random_state=rng).as_matrix(), p)
    dp, rho = field_distortion(p, DISTORTION_SCALE)
    em = pose_from_rt(Rotation.from_rotvec(rho).as_matrix() @ truth[:, :3, :3], p + dp)
    he = fit_axyb(em, invert(Y) @ truth @ X, robust=False, folds=0)
    return he.X, he.Y


def run(args) -> dict:
    try:
        counts = [int(v) for v in str(args.pairs).split(",") if v.strip()]
    except ValueError:
        raise InputError(f"expected --pairs like 10,30,100,300, got {args.pairs!r}") from None
    if not counts or min(counts) < 8:
        raise InputError(f"expected pair counts >= 8, got {args.pairs!r}")
    rng = np.random.default_rng(args.seed)
    X, Y = draw_xy(rng)
    limit = _limit(X, Y, np.random.default_rng(args.seed + 1))
    lt, lr = _pose_diff(limit[1], Y)
    rows, seconds = [], {}
    for n in counts:
        t0 = time.perf_counter()
        rows.append(_one(n, X, Y, limit, rng, int(args.folds), int(args.seed)))
        seconds[str(n)] = time.perf_counter() - t0
    return {"seed": args.seed, "folds": args.folds,
            "setup": {"distortion_scale": DISTORTION_SCALE,
                      "em_noise_per_axis": {"mm": 1e3 * EM_NOISE[0],
                                            "deg": float(np.rad2deg(EM_NOISE[1]))},
                      "optical_noise_per_axis": {"mm": 1e3 * OPTICAL_NOISE[0],
                                                 "deg": float(np.rad2deg(OPTICAL_NOISE[1]))},
                      "n_test": N_TEST,
                      "Y_limit_vs_truth": {"mm": lt, "deg": lr}},
            "rows": rows, "all_auto_not_worse": all(r["auto_not_worse"] for r in rows),
            "seconds": seconds}
