"""The LM's cold start for a source with coil offsets (docs/solve.md#cold-start): the invariant
table's candidates, the restart rule, and the bench keys that report them."""

import numpy as np
import pytest

from openemt.bench._speed import cold_quality, compare_cold, random_poses
from openemt.geometry import pose_from_vector
from openemt.simulate import get_preset
from openemt.solve import Status, closed_form_start, prepare, solve_lm
from openemt.solve._cold_start import table_for


@pytest.fixture(scope="module")
def random_set():
    model = get_preset("dipole-approx").dipole
    truth = random_poses(400, np.random.default_rng(3))
    C = model.coupling(pose_from_vector(truth))
    conc = model.replace(L_so=np.zeros((3, 3)), L_se=np.zeros((3, 3)))
    new = solve_lm(C, model, hemisphere="+x")
    # the previous default: the offset-corrected Kim18 start, then the same solve
    old = solve_lm(C, model, hemisphere="+x",
                   initial=closed_form_start(C, model, conc, "kim18", "+x", False))
    return model, truth, C, new, old


def test_new_start_keeps_every_converged_answer_or_lowers_its_residual(random_set):
    _, truth, _, new, old = random_set
    dp = np.linalg.norm(new.pose_vectors[:, :3] - old.pose_vectors[:, :3], axis=1)
    differ = dp > 1e-9
    assert np.all(new.relative_residual[differ] < old.relative_residual[differ])
    assert np.count_nonzero(new.status == Status.CONVERGED) >= np.count_nonzero(
        old.status == Status.CONVERGED)
    # noise-free couplings: the answers are the true poses
    err = np.linalg.norm(new.pose_vectors[:, :3] - truth[:, :3], axis=1)
    assert np.count_nonzero(err > 1e-6) <= np.count_nonzero(
        np.linalg.norm(old.pose_vectors[:, :3] - truth[:, :3], axis=1) > 1e-6)


def test_new_start_shortens_the_iteration_tail(random_set):
    _, _, _, new, old = random_set
    for q in (90, 99):
        assert np.percentile(new.iterations, q) < np.percentile(old.iterations, q)
    assert np.percentile(new.iterations, 99) <= 15
    assert new.iterations.mean() < 0.5 * old.iterations.mean()


def test_samples_are_solved_independently(random_set):
    model, _, C, new, _ = random_set
    for k in (0, 123, 399):
        one = solve_lm(C[k:k + 1], model, hemisphere="+x")
        np.testing.assert_array_equal(one.pose_vectors[0], new.pose_vectors[k])
        assert one.iterations[0] == new.iterations[k]


def test_table_candidates_lie_in_the_hemisphere_and_are_per_sample(random_set):
    model, truth, C, _, _ = random_set
    table = table_for(model)
    nvec = np.tile([1.0, 0.0, 0.0], (C.shape[0], 1))
    extra = np.zeros((C.shape[0], 6))
    extra[:, 0] = 0.2
    a = table.candidates(C, nvec, extra)
    assert a.shape == (C.shape[0], 5, 6)
    assert np.all(a[:, :, 0] >= 0.0)
    np.testing.assert_array_equal(table.candidates(C[7:8], nvec[7:8], extra[7:8])[0], a[7])
    # the best candidate is near the true pose for most samples (a start, not a solution)
    err = np.linalg.norm(a[:, 0, :3] - truth[:, :3], axis=1)
    assert np.median(err) < 0.02


def test_concentric_model_given_keeps_the_closed_form_start(random_set):
    model, _, C, _, _ = random_set
    conc = model.replace(L_so=np.zeros((3, 3)), L_se=np.zeros((3, 3)))
    solver = prepare(model, hemisphere="+x", concentric_model=conc)
    assert not solver._use_table()
    assert prepare(model, hemisphere="+x")._use_table()
    assert not prepare(conc, hemisphere="+x")._use_table()
    assert not prepare(model, hemisphere="+x", retry_resnorm=1e-5)._use_table()


def test_bench_cold_keys():
    model = get_preset("dipole-approx").dipole
    out = cold_quality(model, 200, 1, 0)
    for key in ("lm_cold_poses_per_s", "lm_cold_previous_start_poses_per_s",
                "lm_cold_mean_iterations"):
        assert np.isfinite(out[key]) and out[key] > 0
    for p in ("p50", "p90", "p99", "max"):
        its = out[f"cold_iterations_{p}"]
        assert set(its) == {"lm_cold", "lm_cold_previous_start"}
        assert all(v >= 1 for v in its.values())
    cmp = out["cold_comparison"]
    assert cmp["samples"] == 200
    assert cmp["differ"] == (cmp["new_lower_residual"] + cmp["previous_lower_residual"]
                             + cmp["equal_residual"] + cmp["not_comparable"])
    assert out["lm_cold_status_counts"]["converged"] == 200


def test_compare_cold_counts_differences(random_set):
    _, _, _, new, old = random_set
    moved = new.replace(pose_vectors=new.pose_vectors + np.array([1e-6, 0, 0, 0, 0, 0]))
    cmp = compare_cold(moved, new)
    assert cmp["differ"] == new.pose_vectors.shape[0]
    assert cmp["equal_residual"] == cmp["differ"]
    assert compare_cold(new, new)["differ"] == 0
