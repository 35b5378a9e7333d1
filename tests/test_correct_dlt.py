"""DLT position correction (docs/paper-procedure.md#output-correction) on synthetic projective distortions."""

import numpy as np
import pytest

from openemt.correct import apply_linear_correction, fit_dlt, linear_correction_rms


def _workspace(rng, n):
    return rng.uniform([0.1, -0.15, -0.15], [0.35, 0.15, 0.15], size=(n, 3))


def _distortion(rng):
    L = np.eye(4)
    L[:3, :3] += 0.05 * rng.standard_normal((3, 3))
    L[:3, 3] = 0.01 * rng.standard_normal(3)
    L[3, :3] = 0.3 * rng.standard_normal(3)  # perspective terms (1/m)
    return L


def test_apply_matches_homogeneous_product_and_keeps_rank():
    rng = np.random.default_rng(1)
    L = _distortion(rng)
    x = _workspace(rng, 7)
    out = apply_linear_correction(L, x)
    loop = []
    for p in x:
        q = L @ np.append(p, 1.0)
        loop.append(q[:3] / q[3])
    np.testing.assert_allclose(out, loop, rtol=0, atol=1e-15)
    assert apply_linear_correction(L, x[0]).shape == (3,)
    # homogeneous: any scale gives the same action
    np.testing.assert_allclose(apply_linear_correction(-3.7 * L, x), out, atol=1e-15)


def test_recovers_known_projective_distortion_exactly():
    rng = np.random.default_rng(2)
    L_true = _distortion(rng)
    d = _workspace(rng, 60)
    m = apply_linear_correction(np.linalg.inv(L_true), d)  # measured = distorted truth
    fit = fit_dlt(m, d)
    assert fit.method == "dlt"
    assert fit.rms_uncorrected > 1e-3
    assert fit.rms_corrected < 1e-10
    assert fit.candidates["dlt"] < 1e-10
    # the matrix is L_true up to scale
    Ln = fit.matrix / fit.matrix[3, 3]
    np.testing.assert_allclose(Ln, L_true / L_true[3, 3], atol=1e-8)
    np.testing.assert_allclose(fit.apply(m), d, atol=1e-11)
    assert linear_correction_rms(fit.matrix, m, d) == pytest.approx(fit.rms_corrected, abs=1e-15)


def test_affine_distortion_pinv_exact_and_noise_reduces_error():
    rng = np.random.default_rng(3)
    A = np.eye(4)
    A[:3, :3] += 0.03 * rng.standard_normal((3, 3))
    A[:3, 3] = [0.002, -0.001, 0.003]
    d = _workspace(rng, 80)
    m = apply_linear_correction(np.linalg.inv(A), d)
    fit = fit_dlt(m, d)
    assert fit.candidates["pinv"] < 1e-12
    assert fit.rms_corrected < 1e-12
    # with noise the correction is no worse than any candidate and beats the identity
    L_true = _distortion(rng)
    m2 = apply_linear_correction(np.linalg.inv(L_true), d) + 1e-4 * rng.standard_normal(d.shape)
    fit2 = fit_dlt(m2, d)
    assert fit2.rms_corrected <= min(fit2.candidates[k] for k in ("none", "pinv", "dlt")) + 1e-15
    assert fit2.rms_corrected < 0.2 * fit2.rms_uncorrected
    assert fit2.rms_corrected > 0.5e-4  # cannot beat the noise floor (~1.7e-4 RMS in 3-D)


def test_identity_when_no_distortion():
    rng = np.random.default_rng(4)
    d = _workspace(rng, 20)
    fit = fit_dlt(d, d)
    assert fit.rms_uncorrected == 0.0
    assert fit.rms_corrected == 0.0
    np.testing.assert_allclose(fit.apply(d), d, atol=1e-15)


@pytest.mark.parametrize("m,d,exc", [
    (np.zeros((4, 3)), np.zeros((4, 3)), ValueError),
    (np.zeros((10, 2)), np.zeros((10, 2)), ValueError),
    (np.zeros((10, 3)), np.zeros((9, 3)), ValueError),
    (np.full((10, 3), np.nan), np.zeros((10, 3)), ValueError),
    (np.zeros((10, 3), dtype=complex), np.zeros((10, 3)), TypeError),
])
def test_bad_input(m, d, exc):
    with pytest.raises(exc):
        fit_dlt(m, d)


def test_bad_matrix():
    with pytest.raises(ValueError, match=r"\(4, 4\)"):
        apply_linear_correction(np.eye(3), np.zeros((2, 3)))


def test_real_data_refit_matches_stored_statistics(ilemt_dir):
    """docs/paper-procedure.md#output-correction: re-fitting the correction of output/XYZ_hr_cal.mat on its own 3 md
    files (solved from the true pose) matches the stored uncorrected/corrected RMS to 4 digits."""
    from openemt.geometry import ground_truth_poses, vector_from_pose
    from openemt.io import import_ilemt_folder, read_ilemt_calibration
    from openemt.solve import solve_lm

    ds = import_ilemt_folder(ilemt_dir, patterns=["md"])
    ds = ds.select(np.flatnonzero(ds.source_fixture == "YoutZup"))
    assert ds.n_samples == 426
    cal = read_ilemt_calibration(ilemt_dir / "output" / "XYZ_hr_cal.mat")
    P = ground_truth_poses(cal.source_fixture, cal.stage_fixture, cal.sensor_fixture,
                           ds.source_fixture, ds.stage, ds.sensor_fixture)
    i = np.argmax(np.abs(P[:, :3, 3]), axis=1)
    s = np.sign(P[np.arange(len(P)), i, 3])
    hem = np.array([("+" if si > 0 else "-") + "xyz"[ii] for ii, si in zip(i, s)])
    res = solve_lm(ds.couplings, cal.model, initial=vector_from_pose(P), hemisphere=hem)
    v = res.valid
    assert v.mean() >= 0.75
    fit = fit_dlt(res.poses[v, :3, 3], P[v, :3, 3])
    assert fit.rms_uncorrected == pytest.approx(cal.stats["uncorrected"], rel=2e-4)
    assert fit.rms_corrected == pytest.approx(cal.stats["corrected"], rel=2e-4)
    assert fit.method == "dlt"
    # same action as the stored matrix (homogeneous: compare normalised)
    np.testing.assert_allclose(fit.matrix / fit.matrix[3, 3],
                               cal.linear_correction / cal.linear_correction[3, 3], atol=2e-5)
