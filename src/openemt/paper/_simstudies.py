"""Calibration against simulated truth: parameter recovery and the cost of the dipole approximation.

Two studies on data from :func:`openemt.simulate.simulate`:

* :func:`parameter_recovery` -- the simulated coils are exactly dipoles (the model is exact):
  the calibration should recover every free parameter within a few standard errors;
* :func:`dipole_cost` -- the simulated coils are finite (the presets' windings): the accuracy
  lost by the dipole model, and what the octupole terms give back, on held-out ld poses at
  source-sensor distances of 4-6 coil diameters.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from .._result import Result
from ..calibrate import (
    MODES,
    RigOptions,
    fit,
    fit_improved,
    perturb_calibration,
)
from ..evaluate import ACCURACY_KEYS, error_summary, pose_error_magnitudes
from ..geometry import SOURCE_FIXTURES
from ..simulate import STAGE_SIGMA, get_preset, simulate, truth_calibration

__all__ = ["DipoleCost", "ParameterRecovery", "dipole_cost", "parameter_recovery"]


@dataclass(frozen=True, eq=False)
class ParameterRecovery(Result):
    """Fitted parameters against the simulated truth, in standard errors.

    Attributes
    ----------
    z : ndarray, shape (n_free,)
        ``(estimate - truth) / standard error`` per free parameter.
    labels : list of str
        Parameter names, in the order of ``z``.
    max_abs_z : float
    fraction_within_3 : float
        Fraction of ``|z| < 3``.
    rms_residue : float
    n_rows : int
    rank, n_free : int
        Jacobian rank and free parameters.
    """

    z: np.ndarray
    labels: list
    max_abs_z: float
    fraction_within_3: float
    rms_residue: float
    n_rows: int
    rank: int
    n_free: int


@dataclass(frozen=True)
class DipoleCost(Result):
    """Accuracy lost by the dipole model on finite coils, and regained by octupole terms.

    Attributes
    ----------
    preset : str
    coil_size_m : float
        Largest source coil extent.
    r_over_d : list of float
        Smallest and largest source-sensor distance over ``coil_size_m`` in the test rows.
    dipole_equivalent_no_fit, dipole_calibrated, octupole_calibrated : dict
        ``trans_rms_mm``, ``trans_max_mm``, ``rot_rms_deg``, ``rot_max_deg`` on the held-out
        ld rows.
    rms_residue : dict
        ``dipole`` and ``octupole`` calibration residues.
    octupole_k_so, octupole_k_se : list of float
        Fitted octupole coefficients.
    n_calibration, n_test : int
    seconds : float
    """

    preset: str
    coil_size_m: float
    r_over_d: list
    dipole_equivalent_no_fit: dict
    dipole_calibrated: dict
    octupole_calibrated: dict
    rms_residue: dict
    octupole_k_so: list
    octupole_k_se: list
    n_calibration: int
    n_test: int
    seconds: float


def parameter_recovery(preset="concentric", *, mode="XYZ_all", snr_db=60.0, seed=0
                       ) -> ParameterRecovery:
    """Fit simulated exact-dipole data and compare with the truth in standard errors.

    The preset's coils are replaced by their dipole equivalents (so the model is exact), stage
    errors are off (they are not part of the model), measurement noise is on.

    Returns
    -------
    ParameterRecovery
    """

    p = get_preset(preset)
    exact = replace(p, model=p.dipole)
    ds = simulate(exact, "md", snr_db=snr_db, stage_sigma=0.0, seed=seed)
    truth = truth_calibration(preset)
    start = perturb_calibration(truth, np.random.default_rng(seed), mode=mode)
    f = fit(ds, start, mode)
    lay = f.layout
    x_true = lay.pack_calibration(truth)
    se = f.identifiability.standard_errors
    z = (f.x[f.free] - x_true[f.free]) / se
    return ParameterRecovery(
        z=z, labels=[lay.label(int(i)) for i in f.free], max_abs_z=float(np.max(np.abs(z))),
        fraction_within_3=float(np.mean(np.abs(z) < 3.0)),
        rms_residue=f.calibration.stats["rms_residue"], n_rows=len(f.problem.C_meas),
        rank=f.identifiability.rank, n_free=int(f.free.size))


def _score(cal_like, model, test, refine=None):
    """Solve the test rows from the truth (no start-up ambiguity) and score against the true
    poses in the sensor-fixture ("stage") frame."""
    from ..geometry import pose_from_vector, vector_from_pose
    from ..solve import hemisphere_from_positions, solve_lm

    P = test.poses
    hemi = hemisphere_from_positions(P[:, :3, 3])
    res = solve_lm(test.couplings, model, initial=vector_from_pose(P), hemisphere=hemi)
    v = res.pose_vectors
    if refine is not None:
        from ..solve import refine_poses

        v, _ = refine_poses(refine, test.couplings, v)
    trans, rot = pose_error_magnitudes(pose_from_vector(v), P,
                                       sensor_fixture=cal_like.sensor_fixture)
    s = error_summary(trans, rot)
    return {k: s[k] for k in ACCURACY_KEYS}


def dipole_cost(preset="concentric", *, snr_db=70.0, stage_sigma=None, seed=0) -> DipoleCost:
    """Accuracy cost of the dipole approximation for finite coils, on held-out ld poses.

    Calibrates (mode ``XYZ_all`` on md rows of every fixture) the dipole model and the dipole +
    octupole model on simulated finite-coil data, and tests both on the ld rows of the home
    source fixture. Also reports the error of the exact dipole-equivalent model (no fit), and
    the range of source-sensor distance over coil size ``r/d``.
    """

    t0 = time.perf_counter()
    p = get_preset(preset)
    sigma = STAGE_SIGMA if stage_sigma is None else stage_sigma
    md = simulate(p, "md", snr_db=snr_db, stage_sigma=sigma, seed=seed)
    test = simulate(p, "ld", source_fixtures=SOURCE_FIXTURES[0], snr_db=snr_db,
                    stage_sigma=sigma, seed=seed + 1)
    truth = truth_calibration(p)
    start = perturb_calibration(truth, np.random.default_rng(seed))
    f = fit(md, start, "XYZ_all", warn=False)
    opts = RigOptions(sensor_code_fix=False, rz_poly=0, rz_tilt=False, octupole_source=True,
                      octupole_sensor=True)
    fitted = fit_improved(md, f.calibration, opts, optimize=MODES["XYZ_all"].optimize,
                          freeze=MODES["XYZ_all"].freeze)
    prob, x = fitted.problem, fitted.x
    r = prob.residuals(x)
    oct_model = prob.model(x)
    F = prob.layout.fixtures(x)
    oct_cal = f.calibration.replace(sensor_fixture=F[2])
    size = _coil_size(p)
    dist = np.linalg.norm(test.poses[:, :3, 3], axis=1)
    return DipoleCost(
        preset=p.name, coil_size_m=size,
        r_over_d=[float(dist.min() / size), float(dist.max() / size)],
        dipole_equivalent_no_fit=_score(truth, p.dipole, test),
        dipole_calibrated=_score(f.calibration, f.calibration.model, test),
        octupole_calibrated=_score(oct_cal, oct_model.dipole, test, refine=oct_model),
        rms_residue={"dipole": f.calibration.stats["rms_residue"],
                     "octupole": float(np.sqrt(r @ r / prob.base.n_rows))},
        octupole_k_so=np.asarray(x[prob.extra["k_so"]]).tolist(),
        octupole_k_se=np.asarray(x[prob.extra["k_se"]]).tolist(),
        n_calibration=len(md), n_test=len(test), seconds=time.perf_counter() - t0)


def _coil_size(p) -> float:
    """Largest source coil extent (m) of a preset, from its description."""
    src = p.source or {}
    for key in ("side_m", "radius_m"):
        if key in src:
            v = float(np.max(src[key]))
            return v if key == "side_m" else 2.0 * v
    return float("nan")
