"""``openemt bench reference``: the reference calibration's held-out error against the
simulation's truth, for each row weighting (docs/reference-calibration.md#errors-in-variables).

For each case ``PRESET/REFERENCE`` and seed: ``openemt simulate --preset PRESET --reference
REFERENCE --n-poses N --seed S`` (in process: :func:`openemt.simulate.simulate_reference`),
then ``openemt calibrate --mode reference --holdout H --seed 0`` with ``--weighting ordinary``
and ``--weighting errors-in-variables`` (:func:`openemt.calibrate.fit_reference`). The held-out
poses are scored as the calibration scores them (solved with the fitted model, compared with
``Y B_i X^-1`` of the fitted X and Y), and the same poses with the simulation's truth
calibration (the preset's model with the true X and Y, ``--truth-calibration``): the truth's
error is what the reference noise alone gives.

Keys, per case
--------------
truth_trans_rms_mm, truth_rot_rms_deg, truth_trans_se_mm, truth_rot_se_deg
    Held-out RMS of the truth calibration and the standard error of that RMS over the held-out
    poses (``std(e^2) / (2 rms sqrt(n))``), averaged over the seeds.
<weighting>.trans_rms_mm, <weighting>.rot_rms_deg
    Held-out RMS of the fitted calibration, averaged over the seeds.
<weighting>.z_trans, <weighting>.z_rot
    Per seed, ``(fitted RMS - truth RMS) / truth SE``; issue target: within 3.
<weighting>.fit_s
    Mean time of ``fit_reference`` (s), its held-out scoring included.
<weighting>.reference_residual_mm, <weighting>.reference_residual_deg
    Mean of the fit's own estimate of the reference noise (:func:`openemt.calibrate.
    reference_residuals`), to compare with ``stated_noise_mm`` / ``stated_noise_deg``.

The truth of a finite-coil preset (``concentric``) is its dipole-equivalent model, which the
fit beats; the comparison with the truth is meaningful for presets whose model is exact
(``anser-6dof``, the board model).
"""

from __future__ import annotations

import time

import numpy as np

__all__ = ["add_arguments", "run"]

_CASES = ("anser-6dof/robot", "concentric/robot", "concentric/optical")


def add_arguments(parser) -> None:
    parser.add_argument("--cases", default=",".join(_CASES),
                        help=f"PRESET/REFERENCE cases, comma-separated (default "
                             f"{','.join(_CASES)})")
    parser.add_argument("--seeds", default="1,2,3", help="simulation seeds (default 1,2,3)")
    parser.add_argument("--n-poses", type=int, default=300, help="poses (default 300)")
    parser.add_argument("--holdout", type=float, default=0.2,
                        help="held-out fraction (default 0.2)")
    parser.add_argument("--snr-db", type=float, default=None,
                        help="coupling noise (default: none for anser-6dof, 80 dB otherwise, "
                             "as in the README)")


def _rms_se(e) -> tuple[float, float]:
    e2 = np.asarray(e, dtype=np.float64) ** 2
    r = float(np.sqrt(e2.mean()))
    return r, float(e2.std(ddof=1) / np.sqrt(e2.size) / (2 * r)) if r > 0 else 0.0


def _held_out_errors(cal, C, B) -> tuple[np.ndarray, np.ndarray]:
    from ..calibrate import reference_errors

    t, r, _ = reference_errors(cal, C, B)
    return 1e3 * t, np.rad2deg(r)


def _case(preset, reference, seeds, args) -> dict:
    from ..calibrate import fit_reference
    from ..simulate import nominal_calibration, reference_truth_calibration, simulate_reference

    snr = args.snr_db if args.snr_db is not None else (None if preset == "anser-6dof" else 80.0)
    out = {"preset": preset, "reference": reference, "snr_db": snr, "seeds": seeds,
           "n_poses": args.n_poses, "holdout": args.holdout}
    truth = {"trans": [], "rot": [], "trans_se": [], "rot_se": []}
    fits = {w: {"trans": [], "rot": [], "z_trans": [], "z_rot": [], "fit_s": [], "ref_t": [],
                "ref_r": []} for w in ("ordinary", "errors-in-variables")}
    for seed in seeds:
        ds = simulate_reference(preset, reference, args.n_poses, snr_db=snr, seed=seed)
        info = ds.meta["reference"]
        out["stated_noise_mm"] = 1e3 * info["noise_trans_m"]
        out["stated_noise_deg"] = float(np.rad2deg(info["noise_rot_rad"]))
        B = ds.extra["reference_poses"]
        true_cal = reference_truth_calibration(preset, ds.meta["truth"]["X"],
                                               ds.meta["truth"]["Y"])
        start = nominal_calibration(preset)
        test = None
        for w, acc in fits.items():
            f = fit_reference(ds, start, holdout=args.holdout, seed=0, weighting=w,
                              warn=False)
            if test is None:
                test = f.test
                tt, tr = _held_out_errors(true_cal, ds.couplings[test], B[test])
                (rt, st), (rr, sr) = _rms_se(tt), _rms_se(tr)
                truth["trans"].append(rt)
                truth["rot"].append(rr)
                truth["trans_se"].append(st)
                truth["rot_se"].append(sr)
            elif not np.array_equal(test, f.test):
                raise RuntimeError("the weightings held out different poses")
            acc["fit_s"].append(f.seconds)
            # the fit's own held-out score (score_reference on the same poses)
            a, b = f.holdout["trans_rms_mm"], f.holdout["rot_rms_deg"]
            acc["trans"].append(a)
            acc["rot"].append(b)
            acc["z_trans"].append((a - truth["trans"][-1]) / truth["trans_se"][-1])
            acc["z_rot"].append((b - truth["rot"][-1]) / truth["rot_se"][-1])
            acc["ref_t"].append(1e3 * f.weighting["reference_residual_trans_m"])
            acc["ref_r"].append(float(np.rad2deg(f.weighting["reference_residual_rot_rad"])))
    out.update(truth_trans_rms_mm=float(np.mean(truth["trans"])),
               truth_rot_rms_deg=float(np.mean(truth["rot"])),
               truth_trans_se_mm=float(np.mean(truth["trans_se"])),
               truth_rot_se_deg=float(np.mean(truth["rot_se"])))
    for w, acc in fits.items():
        out[w] = {"trans_rms_mm": float(np.mean(acc["trans"])),
                  "rot_rms_deg": float(np.mean(acc["rot"])),
                  "z_trans": [round(z, 3) for z in acc["z_trans"]],
                  "z_rot": [round(z, 3) for z in acc["z_rot"]],
                  "fit_s": float(np.mean(acc["fit_s"])),
                  "reference_residual_mm": float(np.mean(acc["ref_t"])),
                  "reference_residual_deg": float(np.mean(acc["ref_r"]))}
    return out


def run(args) -> dict:
    from .._errors import InputError

    seeds = [int(s) for s in str(args.seeds).split(",") if s.strip()]
    cases = [c.strip() for c in str(args.cases).split(",") if c.strip()]
    if not seeds or not cases:
        raise InputError(f"expected --seeds and --cases lists, got {args.seeds!r}, "
                         f"{args.cases!r}")
    out = {"cases": {}}
    t0 = time.perf_counter()
    for c in cases:
        preset, _, reference = c.partition("/")
        if not reference:
            raise InputError(f"expected a case PRESET/REFERENCE, got {c!r}")
        out["cases"][c] = _case(preset, reference, seeds, args)
    out["seconds"] = time.perf_counter() - t0
    return out
