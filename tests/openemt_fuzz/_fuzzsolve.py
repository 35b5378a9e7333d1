"""Solver fuzzing: generated coupling matrices, each solver's status checked against a reference.

Couplings are drawn in classes, from exact model couplings to matrices no pose can produce:

``clean``      the model's couplings at a random pose, with relative noise 1e-6;
``noisy``      the same with 1 % relative noise;
``scaled``     clean couplings multiplied by ``10**u``, ``u`` uniform in [-150, 150] (the units
               of the data are unknown to the solver; a pose exists only for some scales);
``random``     Gaussian matrices with a random overall scale;
``rank1``      outer products (no pose gives them);
``sign``       clean couplings with one sensor column negated (a wrong sign convention);
``nonfinite``  clean couplings with one entry NaN or inf;
``zero``       all-zero matrices.

A sample reported ``converged`` must pass the reference check, computed independently of the
solver (the couplings of the returned pose from :func:`openemt.field.coupling`):

* the pose is finite and within :data:`openemt.solve._validity.MAX_RANGE_M` of the origin;
* the couplings it predicts match the input to the solver's relative-residual rule (times
  :data:`REFERENCE_SLACK`);
* for ``clean`` samples, it is the true pose (within 0.1 mm and 0.01 deg; the sign ambiguity of
  dipole fields is removed by solving in the true hemisphere).

``wrong_converged`` counts the samples that break this; ``crashes`` counts exceptions.
"""

from __future__ import annotations

import numpy as np

__all__ = ["CLASSES", "REFERENCE_SLACK", "fuzz_solvers"]

CLASSES = ("clean", "noisy", "scaled", "random", "rank1", "sign", "nonfinite", "zero")

#: tolerance factor of the reference check on the solvers' own relative-residual threshold
REFERENCE_SLACK = 1.5


def _random_poses(rng, n, r_min=0.08, r_max=0.6):
    from scipy.spatial.transform import Rotation

    from openemt.geometry import pose_from_rt

    d = rng.standard_normal((n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d[:, 0] = np.abs(d[:, 0]) + 0.05  # the +x hemisphere, away from its boundary
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    r = r_min + (r_max - r_min) * rng.random(n) ** 0.5
    return pose_from_rt(Rotation.random(n, random_state=rng).as_matrix(), d * r[:, None])


def make_samples(model, n, rng):
    """``(couplings, truth_poses, class_index)`` for ``n`` samples of all classes."""
    from openemt.field import coupling

    P = _random_poses(rng, n)
    C0 = coupling(model, P)
    cls = rng.integers(0, len(CLASSES), n)
    C = C0.copy()
    norm = np.linalg.norm(C0, axis=(1, 2), keepdims=True)
    for k, name in enumerate(CLASSES):
        m = cls == k
        nm = int(m.sum())
        if not nm:
            continue
        if name == "clean":
            C[m] += 1e-6 * norm[m] / 3 * rng.standard_normal((nm,) + C.shape[1:])
        elif name == "noisy":
            C[m] += 1e-2 * norm[m] / 3 * rng.standard_normal((nm,) + C.shape[1:])
        elif name == "scaled":
            C[m] *= 10.0 ** rng.uniform(-150, 150, (nm, 1, 1))
        elif name == "random":
            C[m] = rng.standard_normal((nm,) + C.shape[1:]) * 10.0 ** rng.uniform(-10, 10,
                                                                                  (nm, 1, 1))
        elif name == "rank1":
            a = rng.standard_normal((nm, C.shape[1], 1))
            b = rng.standard_normal((nm, 1, C.shape[2]))
            C[m] = a * b
        elif name == "sign":
            C[m, :, 0] *= -1
        elif name == "nonfinite":
            idx = np.flatnonzero(m)
            i = rng.integers(0, C.shape[1], nm)
            j = rng.integers(0, C.shape[2], nm)
            C[idx, i, j] = rng.choice([np.nan, np.inf, -np.inf], nm)
        elif name == "zero":
            C[m] = 0.0
    return C, P, cls


def _concentric(model):
    """The model with every coil moved to its frame origin (what the closed forms assume)."""
    from openemt.field import DipoleModel

    return DipoleModel(L_so=np.zeros_like(model.L_so), M_so=model.M_so,
                       L_se=np.zeros_like(model.L_se), M_se=model.M_se, gain=model.gain)


def _solvers(model):
    from openemt import solve

    out = {"lm": lambda C: solve.solve_lm(C, model=model, hemisphere="+x")}
    if model.is_concentric:
        out["kim18"] = lambda C: solve.solve_kim18(C, model=model, hemisphere="+x")
        out["svd"] = lambda C: solve.solve_svd(C, model=model, hemisphere="+x")
        out["kuipers"] = lambda C: solve.solve_kuipers(C, model=model, hemisphere="+x")
    return out


def _threshold() -> float:
    from openemt.solve import _validity

    return float(_validity.MAX_RELATIVE_RESIDUAL)


def reference_check(model, C, poses, truth, cls) -> np.ndarray:
    """Boolean per sample: does the returned pose pass the reference check (module docstring)?"""
    from openemt.evaluate import pose_error_magnitudes
    from openemt.field import coupling
    from openemt.solve._validity import MAX_RANGE_M

    ok = np.all(np.isfinite(poses), axis=(1, 2))
    ok &= np.linalg.norm(np.where(ok[:, None], poses[:, :3, 3], np.inf), axis=1) <= MAX_RANGE_M
    if not ok.any():
        return ok
    idx = np.flatnonzero(ok)
    pred = coupling(model, poses[idx])
    with np.errstate(all="ignore"):
        rel = (np.linalg.norm(pred - C[idx], axis=(1, 2))
               / np.linalg.norm(C[idx], axis=(1, 2)))
    ok[idx] = np.isfinite(rel) & (rel <= REFERENCE_SLACK * _threshold())
    clean = ok & (cls == CLASSES.index("clean"))
    if clean.any():
        c = np.flatnonzero(clean)
        dt, dr = pose_error_magnitudes(poses[c], truth[c])
        ok[c] = (dt <= 1e-4) & (dr <= np.deg2rad(0.01))
    return ok


def fuzz_solvers(n_samples: int, seed: int = 0, *, batch: int = 5000) -> dict:
    """Run every solver on ``n_samples`` generated samples per model; counts per solver, model
    and class: ``n``, ``converged``, ``wrong_converged``; plus ``crashes`` and examples."""
    from openemt.simulate import truth_calibration
    from openemt.solve import Status

    rng = np.random.default_rng(seed)
    models = {"concentric": _concentric(truth_calibration("concentric").model),
              "dipole-approx": truth_calibration("dipole-approx").model}
    out = {"n_samples": 0, "converged": 0, "wrong_converged": 0, "crashes": 0,
           "by_solver": {}, "examples": []}
    per_model = max(1, n_samples // len(models))
    for mname, model in models.items():
        solvers = _solvers(model)
        done = 0
        while done < per_model:
            n = min(batch, per_model - done)
            C, P, cls = make_samples(model, n, rng)
            for sname, fn in solvers.items():
                key = f"{sname}/{mname}"
                rec = out["by_solver"].setdefault(key, {c: {"n": 0, "converged": 0,
                                                            "wrong_converged": 0}
                                                        for c in CLASSES})
                try:
                    res = fn(C)
                except Exception as exc:  # noqa: BLE001 - counted, that is the point
                    out["crashes"] += n
                    if len(out["examples"]) < 20:
                        out["examples"].append({"solver": key, "crash": f"{type(exc).__name__}:"
                                                f" {exc}"[:200]})
                    continue
                conv = np.asarray(res.status) == Status.CONVERGED
                good = reference_check(model, C, res.poses, P, cls)
                wrong = conv & ~good
                for k, c in enumerate(CLASSES):
                    m = cls == k
                    rec[c]["n"] += int(m.sum())
                    rec[c]["converged"] += int((conv & m).sum())
                    rec[c]["wrong_converged"] += int((wrong & m).sum())
                out["converged"] += int(conv.sum())
                out["wrong_converged"] += int(wrong.sum())
                for i in np.flatnonzero(wrong)[:3]:
                    if len(out["examples"]) < 20:
                        out["examples"].append({
                            "solver": key, "class": CLASSES[cls[i]],
                            "position_m": res.poses[i, :3, 3].tolist(),
                            "truth_m": P[i, :3, 3].tolist(),
                            "residual": float(res.residual[i])})
            out["n_samples"] += n
            done += n
    return out
