"""``openemt bench speed``: poses per second on one core for every solver.

Data: the ``dipole-approx`` preset's dipole model (three air coils with 45 mm offsets, MacLachlan et al. 2025
Table I / docs/ilemt-data.md#calibration-mat cal_9_24), a smooth sensor trajectory sampled at 1 kHz around
0.25 m from the source (0.05 m Lissajous amplitude, about 0.2 m/s and 1 rad/s), and white noise
at 80 dB SNR on the couplings.

- ``lm_tracking``: LM warm-started from the previous sample (``initial='track'``);
- ``lm_cold_trajectory``: the default cold LM (``initial='kim18'``, no concentric model: the
  invariant-table start of docs/solve.md#cold-start, start included) of each sample;
- ``lm_cold`` and ``cold_*`` (:func:`cold_quality`): the default cold LM on ``--cold-samples``
  noise-free random poses (80-380 mm, any orientation, +x hemisphere: a set that reaches the
  iteration tail a smooth trajectory does not), its iteration percentiles
  (``cold_iterations_p50/p90/p99/max``, per solver), and the previous default start (the
  offset-corrected Kim18 closed form, ``lm_cold_previous_start_*``) on the same couplings in the
  same process; ``cold_comparison`` counts the samples whose converged positions differ by more
  than 1e-9 m and which of the two has the lower residual there; ``lm_cold_ilemt_*``
  (:func:`cold_ilemt`, unless ``--no-ilemt``): the same on the bundled ILEMT data's rows of the
  home source fixture with a fitted calibration;
- ``svd``, ``kuipers``, ``kim18``: the closed forms on the same couplings with the preset's
  moments and the coil offsets dropped (the concentric approximation they need; their
  accuracy on this source is not the point here);
- ``svd_complex``, ``kuipers_complex``, ``kim18_complex``: the closed forms on the same
  couplings as complex phasors (quadrature noise at the same SNR added: ``sign(Re z) |z|`` and
  the complex spectral norm enter); ``closed_form_complex_ratios`` gives each one's
  real-input rate over its complex-input rate (the two timed in alternation, best of
  ``--repeats`` each), ``closed_form_complex_ratio`` the largest;
- baseline: ``scipy.optimize.least_squares`` (default 'trf', finite-difference Jacobian) called
  once per pose on the same model from the same Kim18 start, as the peer trackers do, with
  tolerances 1e-12 so that its answer can be compared at the 1e-9 m level.

All timings use one numba thread (``numba.set_num_threads(1)``), best of ``--repeats`` runs,
after a warm-up call that excludes compilation. The ``*_poses_per_s`` keys use the process CPU
time (the work of one core, insensitive to other processes on a shared machine); the
``*_wall_poses_per_s`` keys give the wall-clock rates of the same runs.
The closed forms include the evaluation of the model at their solution (the validity rule
judges every pose by its relative residual).
"""

from __future__ import annotations

import numpy as np

from .._compile_notice import serial_threads
from .._errors import InputError
from ._timing import best_time

__all__ = ["add_arguments", "cold_quality", "compare_cold", "random_poses", "run", "trajectory"]


def add_arguments(parser) -> None:
    parser.add_argument("--samples", type=int, default=200000,
                        help="samples for the compiled solvers (200000)")
    parser.add_argument("--baseline-samples", type=int, default=200,
                        help="poses solved by the per-pose scipy baseline (200)")
    parser.add_argument("--repeats", type=int, default=3, help="timing repeats (best taken)")
    parser.add_argument("--snr-db", type=float, default=80.0, help="coupling SNR (80 dB)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--cold-samples", type=int, default=None,
                        help="random poses of the cold-start benchmark (--samples, at most "
                             "100000)")
    parser.add_argument("--no-ilemt", dest="ilemt", action="store_false",
                        help="skip the cold solves of the bundled ILEMT data (they fit a "
                             "calibration first, about 20-30 s)")


def trajectory(n, rate_hz=1000.0):
    """Smooth pose vectors (n, 6): 0.05 m Lissajous around 0.25 m along (1, 1, 1)/sqrt(3)."""
    t = np.arange(n)[:, None] / rate_hz
    center = np.full(3, 0.25 / np.sqrt(3.0))
    pos = center + 0.05 * np.sin(2 * np.pi * np.array([0.5, 0.7, 0.9]) * t + [0.0, 1.0, 2.0])
    rot = np.array([0.3, -0.2, 0.5]) + 0.5 * np.sin(
        2 * np.pi * np.array([0.3, 0.23, 0.17]) * t + [0.5, 1.5, 2.5])
    return np.hstack([pos, rot])


def random_poses(n, rng, r_min=0.08, r_max=0.38):
    """Pose vectors (n, 6) of the cold-start benchmark: positions uniform in direction over the
    +x hemisphere and uniform in distance in [r_min, r_max] m, rotations uniform (random unit
    quaternions)."""
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    d[:, 0] = np.abs(d[:, 0])
    r = rng.uniform(r_min, r_max, n)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    q[q[:, 0] < 0] *= -1.0
    s = np.linalg.norm(q[:, 1:], axis=1)
    ang = 2.0 * np.arctan2(s, q[:, 0])
    with np.errstate(invalid="ignore", divide="ignore"):
        rv = q[:, 1:] * np.where(s > 0, ang / s, 0.0)[:, None]
    return np.hstack([d * r[:, None], rv])


def _percentiles(it) -> dict:
    return {"p50": float(np.percentile(it, 50)), "p90": float(np.percentile(it, 90)),
            "p99": float(np.percentile(it, 99)), "max": int(np.max(it))}


def compare_cold(new, old, tol=1e-9) -> dict:
    """Converged poses of two cold solves of the same couplings: the samples whose positions
    differ by more than ``tol`` m, and which of the two has the lower relative residual
    there."""
    dp = np.linalg.norm(new.pose_vectors[:, :3] - old.pose_vectors[:, :3], axis=1)
    differ = ~(dp <= tol)
    rn, ro = new.relative_residual[differ], old.relative_residual[differ]
    return {"samples": int(dp.size), "position_tolerance_m": tol,
            "differ": int(differ.sum()), "differ_fraction": float(differ.mean()),
            "new_lower_residual": int(np.sum(rn < ro)),
            "previous_lower_residual": int(np.sum(ro < rn)),
            "equal_residual": int(np.sum(rn == ro)),
            # a residual that is not finite on either side (e.g. the previous start's
            # INVALID_INPUT)
            "not_comparable": int(np.sum(~np.isfinite(rn) | ~np.isfinite(ro))),
            "max_position_diff_m": float(np.nanmax(dp)) if dp.size else 0.0}


def cold_runs(solver, C, starts_previous, repeats):
    """Time the default cold solve of ``solver`` (a prepared LM) and the previous start's
    (``starts_previous(C)``: the offset-corrected Kim18 start, then the same solver; timed
    once, the default best of ``repeats``) on couplings ``C``: ``(result, cpu s, wall s)`` of
    each."""
    solver(C[:50], "kim18")   # warm-up: compiles or loads the kernels, builds the table
    cpu, wall, new = best_time(lambda: solver(C, "kim18"), repeats)
    cpu_o, wall_o, old = best_time(lambda: solver(C, starts_previous(C)), 1)  # slow: once
    return (new, cpu, wall), (old, cpu_o, wall_o)


def cold_quality(model, n, repeats, seed) -> dict:
    """The ``lm_cold_*`` and ``cold_*`` keys: cold solves of ``n`` noise-free random poses of
    ``model`` (:func:`random_poses`), the default start against the previous one (the
    offset-corrected Kim18 closed form, ``closed_form_start``) in the same process."""
    from ..geometry import pose_from_vector
    from ..solve import closed_form_start, prepare

    if n < 10:
        raise InputError(f"expected --cold-samples >= 10, got {n}")
    truth = random_poses(n, np.random.default_rng(seed))
    C = model.coupling(pose_from_vector(truth))
    solver = prepare(model, hemisphere="+x")
    conc = model.replace(L_so=np.zeros((3, 3)), L_se=np.zeros((3, 3)))
    (new, cpu, wall), (old, cpu_o, wall_o) = cold_runs(
        solver, C, lambda c: closed_form_start(c, model, conc, "kim18", "+x", False), repeats)
    out = {"cold_samples": n,
           "cold_set": "noise-free couplings of the preset's dipole model at random poses: "
                       "80-380 mm, direction uniform over the +x hemisphere, rotation uniform; "
                       "hemisphere '+x'",
           "lm_cold_poses_per_s": n / cpu, "lm_cold_wall_poses_per_s": n / wall,
           "lm_cold_previous_start_poses_per_s": n / cpu_o,
           "lm_cold_previous_start_wall_poses_per_s": n / wall_o,
           "lm_cold_status_counts": new.status_counts(),
           "lm_cold_previous_start_status_counts": old.status_counts(),
           "lm_cold_mean_iterations": float(new.iterations.mean()),
           "lm_cold_previous_start_mean_iterations": float(old.iterations.mean())}
    for name, res in (("lm_cold", new), ("lm_cold_previous_start", old)):
        err = np.linalg.norm(res.pose_vectors[:, :3] - truth[:, :3], axis=1)
        out[f"{name}_position_error_above_1um"] = int(np.sum(~(err <= 1e-6)))
    its = {"lm_cold": _percentiles(new.iterations),
           "lm_cold_previous_start": _percentiles(old.iterations)}
    for p in ("p50", "p90", "p99", "max"):
        out[f"cold_iterations_{p}"] = {name: v[p] for name, v in its.items()}
    out["cold_comparison"] = compare_cold(new, old)
    return out


def cold_ilemt(summary, repeats) -> None:
    """Add the ``lm_cold_ilemt_*`` keys (and the ``lm_cold_ilemt*`` entries of the
    ``cold_iterations_*`` keys) to ``summary``: cold solves of the bundled ILEMT folder's rows
    of the home source fixture with the calibration of the paper's ``XYZ`` step (fitted here,
    without output corrections), hemisphere ``+x`` (every such row is, docs/paper-procedure.md),
    the default start against the previous one."""
    import warnings

    from .. import datasets
    from ..paper import load_paper_run
    from ..solve import closed_form_start, prepare

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run = load_paper_run(datasets.path("cal_9_15_premo_cmu"), steps=["XYZ"],
                             correction=False)
    model = run.calibration("XYZ").model
    ds = run.dataset
    C = np.ascontiguousarray(ds.signed_real()[np.asarray(ds.source_fixture) == "YoutZup"])
    conc = model.replace(L_so=np.zeros((3, 3)), L_se=np.zeros((3, 3)))
    (new, cpu, wall), (old, cpu_o, _) = cold_runs(
        prepare(model, hemisphere="+x"), C,
        lambda c: closed_form_start(c, model, conc, "kim18", "+x", False), repeats)
    n = C.shape[0]
    summary.update({
        "lm_cold_ilemt_samples": n,
        "lm_cold_ilemt_set": "bundled cal_9_15_premo_cmu rows of the home source fixture "
                             "(YoutZup), calibration of the paper's XYZ step, hemisphere '+x'",
        "lm_cold_ilemt_poses_per_s": n / cpu, "lm_cold_ilemt_wall_poses_per_s": n / wall,
        "lm_cold_ilemt_previous_start_poses_per_s": n / cpu_o,
        "lm_cold_ilemt_status_counts": new.status_counts(),
        "lm_cold_ilemt_previous_start_status_counts": old.status_counts(),
        "cold_comparison_ilemt": compare_cold(new, old)})
    for name, res in (("lm_cold_ilemt", new), ("lm_cold_ilemt_previous_start", old)):
        for p, v in _percentiles(res.iterations).items():
            summary[f"cold_iterations_{p}"][name] = v


def run(args) -> dict:
    import numba
    from scipy.optimize import least_squares

    from ..geometry import pose_from_vector
    from ..simulate import get_preset
    from ..solve import prepare, solve_kim18

    n = int(args.samples)
    nb = int(args.baseline_samples)
    if n < 10 or nb < 1:
        raise InputError(f"expected --samples >= 10 and --baseline-samples >= 1, got {n}, {nb}")
    with serial_threads():
        rng = np.random.default_rng(args.seed)
        model = get_preset("dipole-approx").dipole
        conc = model.replace(L_so=np.zeros((3, 3)), L_se=np.zeros((3, 3)))
        truth = trajectory(n)
        C = model.coupling(pose_from_vector(truth))
        sigma = np.sqrt(np.mean(C ** 2, axis=(1, 2))) * 10 ** (-args.snr_db / 20)
        C = C + sigma[:, None, None] * rng.normal(size=C.shape)

        # the solvers of the one factory (openemt.solve.prepare), prepared once
        lm = prepare(model, hemisphere="+x", concentric_model=conc)
        lm_default = prepare(model, hemisphere="+x")   # the default cold start (no conc model)
        closed = {s: prepare(conc, solver=s, hemisphere="+x") for s in ("svd", "kuipers", "kim18")}
        runs = {
            "lm_tracking": lambda c: lm(c, "track"),
            "lm_cold_trajectory": lambda c: lm_default(c, "kim18"),
            "svd": closed["svd"],
            "kuipers": closed["kuipers"],
            "kim18": closed["kim18"],
        }
        summary: dict = {"samples": n, "preset": "dipole-approx", "snr_db": args.snr_db,
                         "numba_threads": numba.get_num_threads(),
                         "timing": "process CPU time of the single-threaded run (best of "
                                   "repeats); *_wall_poses_per_s give wall-clock rates, which "
                                   "other load on the machine lowers"}
        results = {}
        for name, f in runs.items():
            f(C[:50])  # warm-up (loads or compiles the kernels)
            dt, wall, res = best_time(lambda f=f: f(C), args.repeats)
            results[name] = res
            summary[f"{name}_poses_per_s"] = n / dt
            summary[f"{name}_wall_poses_per_s"] = n / wall
            summary[f"{name}_status_counts"] = res.status_counts()
            summary[f"{name}_mean_iterations"] = float(res.iterations.mean())
        # the closed forms on complex couplings (measured phasors, as ILEMT data are): the
        # same couplings with quadrature noise at the same SNR
        Cc = C + 1j * sigma[:, None, None] * rng.normal(size=C.shape)
        ratios = {}
        for name in ("svd", "kuipers", "kim18"):
            f = closed[name]
            f(Cc[:50])
            # real and complex input timed in alternation, so that both see the machine in
            # the same state (timed minutes apart, one slow phase decided the ratio)
            real_cpu, cpu, wall, res = np.inf, np.inf, np.inf, None
            for _ in range(max(1, args.repeats)):
                real_cpu = min(real_cpu, best_time(lambda f=f: f(C), 1)[0])
                dt_r, wall_r, out = best_time(lambda f=f: f(Cc), 1)
                cpu = min(cpu, dt_r)
                if wall_r < wall:
                    wall, res = wall_r, out
            summary[f"{name}_complex_poses_per_s"] = n / cpu
            summary[f"{name}_complex_wall_poses_per_s"] = n / wall
            summary[f"{name}_complex_status_counts"] = res.status_counts()
            ratios[name] = cpu / real_cpu
        summary["closed_form_complex_ratios"] = ratios
        summary["closed_form_complex_ratio"] = max(ratios.values())
        for name in ("lm_tracking", "lm_cold_trajectory"):
            err = results[name].pose_vectors[:, :3] - truth[:, :3]
            summary[f"{name}_position_rms_error_m"] = float(np.sqrt(np.mean(err ** 2) * 3))

        # per-pose scipy baseline on the first nb samples, from the same Kim18 start
        init = solve_kim18(C[:nb], conc, hemisphere="+x").pose_vectors

        def baseline(tol=1e-12):
            out = np.empty((nb, 6))
            for k in range(nb):
                ck = C[k]

                def fun(x, ck=ck):
                    return (model.coupling(pose_from_vector(x[None]))[0] - ck).ravel()

                out[k] = least_squares(fun, init[k], xtol=tol, ftol=tol, gtol=tol).x
            return out

        # scipy's default tolerances (1e-8) too: faster, but its answers are less exact
        dt_d, _, base_d = best_time(lambda: baseline(1e-8), 1)
        summary["scipy_default_tol_poses_per_s"] = nb / dt_d
        summary["lm_vs_scipy_default_tol_ratio"] = summary["lm_tracking_poses_per_s"] / (nb / dt_d)
        summary["max_position_diff_default_tol_m"] = float(
            np.abs(results["lm_tracking"].pose_vectors[:nb, :3] - base_d[:, :3]).max())
        dt_b, wall_b, base = best_time(baseline, 1)
        summary["scipy_per_pose_poses_per_s"] = nb / dt_b
        summary["scipy_per_pose_wall_poses_per_s"] = nb / wall_b
        summary["scipy_baseline"] = ("scipy.optimize.least_squares per pose, method='trf', "
                                     "2-point finite differences, xtol=ftol=gtol=1e-12")
        summary["lm_vs_scipy_ratio"] = summary["lm_tracking_poses_per_s"] / (nb / dt_b)
        summary["lm_cold_trajectory_vs_scipy_ratio"] = (summary["lm_cold_trajectory_poses_per_s"]
                                                        / (nb / dt_b))
        for name in ("svd", "kuipers", "kim18"):
            summary[f"{name}_vs_scipy_ratio"] = summary[f"{name}_poses_per_s"] / (nb / dt_b)
        diffs = [np.abs(results[name].pose_vectors[:nb, :3] - base[:, :3]).max()
                 for name in ("lm_tracking", "lm_cold_trajectory")]
        summary["max_position_diff_m"] = float(max(diffs))
        summary["targets"] = {
            "lm_tracking_poses_per_s >= 200000": summary["lm_tracking_poses_per_s"] >= 2e5,
            "lm_vs_scipy_ratio >= 300": summary["lm_vs_scipy_ratio"] >= 300,
            "closed forms >= 2000000": all(summary[f"{s}_poses_per_s"] >= 2e6
                                           for s in ("svd", "kuipers", "kim18")),
            "max_position_diff_m <= 1e-9": summary["max_position_diff_m"] <= 1e-9,
            "closed_form_complex_ratio <= 1.3": summary["closed_form_complex_ratio"] <= 1.3,
        }
        n_cold = getattr(args, "cold_samples", None) or min(n, 100000)
        summary.update(cold_quality(model, int(n_cold), args.repeats, args.seed))
        if getattr(args, "ilemt", False):
            cold_ilemt(summary, args.repeats)
        summary["lm_cold_vs_scipy_ratio"] = summary["lm_cold_poses_per_s"] / (nb / dt_b)
        summary["targets"]["lm_cold_poses_per_s >= 50000"] = summary["lm_cold_poses_per_s"] >= 5e4
        summary["targets"]["cold_iterations_p99 <= 15"] = (
            summary["cold_iterations_p99"]["lm_cold"] <= 15)
        summary["targets"]["cold: no converged pose changed, or the new one lower"] = (
            summary["cold_comparison"]["previous_lower_residual"] == 0)
        from ._planar_speed import planar_speed  # the planar_* keys (its own docstring)

        summary.update(planar_speed(samples=min(n, 20000), baseline_samples=min(nb, 30),
                                    repeats=args.repeats, snr_db=args.snr_db, seed=args.seed))
    return summary
