"""How the improved model is fitted: the compressed least-squares problem handed to MINPACK and
warm starts from another fit (openemt.calibrate._lsq, fit_improved(initial=...))."""

from __future__ import annotations

import numpy as np
from test_calibrate import F_SE, F_SO, F_ST, synthetic_dataset, truth_model

from openemt.calibrate import (
    MODES,
    ImprovedProblem,
    ParameterLayout,
    RigOptions,
    carry_parameters,
    fit_improved,
    perturb_calibration,
)
from openemt.calibrate._lsq import _compressed, fit_free_parameters
from openemt.io import Calibration, Dataset

OPTIONS = RigOptions(octupole_sensor=True, stage_linear=("xy",), gain_nonlinear=True)
FREEZE = MODES["XYZ"].freeze + ("z_se_fix",)


def _data(seed, n_per=30, noise=1e-3):
    rng = np.random.default_rng(seed)
    cal = Calibration(model=truth_model(rng), source_fixture=F_SO, stage_fixture=F_ST,
                      sensor_fixture=F_SE)
    ds = synthetic_dataset(rng, cal, n_per=n_per)
    C = ds.couplings * (1 + noise * rng.normal(size=ds.couplings.shape))
    return cal, Dataset(couplings=C, stage=ds.stage, source_fixture=ds.source_fixture,
                        sensor_fixture=ds.sensor_fixture, pattern=ds.pattern,
                        file_index=ds.file_index)


def test_compressed_problem_keeps_the_normal_equations_and_the_norm():
    rng = np.random.default_rng(0)
    # columns of very different scales (metres, radians, m^2), as the calibration's
    J = rng.normal(size=(500, 7)) * np.array([1e-3, 1.0, 1e3, 1e-6, 1.0, 10.0, 1e2])
    r = rng.normal(size=500)
    free = np.array([0, 2, 3, 5, 6])
    rc, Jc = _compressed(r, J, free)
    Jf = J[:, free]
    assert rc.shape == (6,) and Jc.shape == (6, 5)
    np.testing.assert_allclose(Jc.T @ Jc, Jf.T @ Jf, rtol=1e-12,
                               atol=1e-13 * np.abs(Jf.T @ Jf).max())
    np.testing.assert_allclose(Jc.T @ rc, Jf.T @ r, rtol=1e-10,
                               atol=1e-12 * np.abs(Jf.T @ r).max())
    assert abs(rc @ rc - r @ r) < 1e-12 * (r @ r)
    # the predicted norm |r + J p| of any step is kept
    p = rng.normal(size=5) / np.linalg.norm(Jf, axis=0)
    assert abs(np.linalg.norm(rc + Jc @ p) - np.linalg.norm(r + Jf @ p)) < 1e-10 * np.linalg.norm(r)
    # a column without effect: the Gram matrix is singular, a Householder QR stands in
    J0 = J.copy()
    J0[:, 3] = 0.0
    rc, Jc = _compressed(r, J0, free)
    np.testing.assert_allclose(Jc.T @ rc, J0[:, free].T @ r, rtol=1e-10,
                               atol=1e-12 * np.abs(J0[:, free].T @ r).max())
    assert abs(rc @ rc - r @ r) < 1e-12 * (r @ r)


def _start(cal, seed):
    return perturb_calibration(cal, np.random.default_rng(seed), mode="XYZ")


def test_compressed_fit_takes_the_same_steps():
    cal, data = _data(1)
    lay = ParameterLayout(3, 3)
    prob = ImprovedProblem(data, lay, cal.model.gain, OPTIONS)
    x0 = np.zeros(prob.size)
    x0[:lay.size] = lay.pack_calibration(_start(cal, 11))
    free = np.r_[lay.free_indices(MODES["XYZ"].optimize, FREEZE),
                 np.arange(lay.size, prob.size)]
    xa, ra = fit_free_parameters(prob, x0, free, tol=1e-12, max_nfev=200)
    xb, rb = fit_free_parameters(prob, x0, free, tol=1e-12, max_nfev=200, compress=True)
    assert ra.nfev > 4 and ra.status > 0 and rb.status > 0
    # the same iteration: the same evaluations but for a last step at rounding level
    assert abs(ra.nfev - rb.nfev) <= 1
    scale = np.maximum(np.abs(xa), 1e-3 * np.abs(xa).max())
    np.testing.assert_allclose(xb / scale, xa / scale, rtol=0, atol=1e-9)
    assert abs(rb.cost - ra.cost) <= 1e-9 * ra.cost


def test_warm_start_reaches_the_cold_fit_in_fewer_steps():
    cal, data = _data(2)
    kw = dict(optimize=MODES["XYZ"].optimize, freeze=FREEZE)
    start = _start(cal, 12)
    cold = fit_improved(data, start, OPTIONS, **kw)
    # from the fit of the model without the gain term, on half of the rows
    half = data.select(np.arange(len(data)) % 2 == 0)
    smaller = fit_improved(half, start,
                           RigOptions(octupole_sensor=True, stage_linear=("xy",)), **kw)
    warm = fit_improved(data, start, OPTIONS, initial=smaller, **kw)
    assert warm.result.nfev < cold.result.nfev
    assert abs(warm.result.cost - cold.result.cost) <= 1e-9 * cold.result.cost
    scale = np.maximum(np.abs(cold.x), 1e-3 * np.abs(cold.x).max())
    np.testing.assert_allclose(warm.x / scale, cold.x / scale, rtol=0, atol=1e-7)
    # the carried start: the shared parameters of the smaller fit, zero for the new gain term
    prob, x0 = carry_parameters(smaller.problem, smaller.x, data, OPTIONS)
    assert prob.size == cold.problem.size
    np.testing.assert_array_equal(x0[prob.extra["gain"]], 0.0)
    np.testing.assert_array_equal(x0[prob.extra["stage_linear"]],
                                  smaller.x[smaller.problem.extra["stage_linear"]])
