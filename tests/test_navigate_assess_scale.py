"""The grid assessment at scale: nearest matching on a k-d tree, distance statistics over every
pair in blocks (equal to the all-pairs figures), a bounded number of stored pairs, and a
stated point limit."""

import time

import numpy as np
import pytest

from openemt.navigate import (
    MAX_ASSESS_POINTS,
    MAX_STORED_PAIRS,
    assess_grid,
    regular_grid,
    simulate_grid_points,
)


def test_block_statistics_equal_the_all_pairs_figures():
    rng = np.random.default_rng(0)
    nominal = regular_grid(0.05, (10, 10, 7))                 # 700 points: 244,650 pairs
    pts, _ = simulate_grid_points(nominal, rng, noise=3e-4)
    d = assess_grid(pts, nominal).to_dict()
    i, j = np.triu_indices(len(pts), k=1)
    dn = np.linalg.norm(nominal[i] - nominal[j], axis=1)
    e = 1e3 * (np.linalg.norm(pts[i] - pts[j], axis=1) - dn)
    assert d["n_distances"] == len(e) > MAX_STORED_PAIRS
    assert d["distance_error_rms_mm"] == pytest.approx(np.sqrt(np.mean(e ** 2)), rel=1e-9)
    assert d["distance_error_mean_mm"] == pytest.approx(np.mean(np.abs(e)), rel=1e-9)
    assert d["distance_error_std_mm"] == pytest.approx(np.std(e, ddof=1), rel=1e-6)
    assert d["distance_error_max_mm"] == pytest.approx(np.abs(e).max(), rel=1e-12)
    sel = np.abs(dn - 0.15) <= 0.5e-3
    c = d["distance_classes"]["150"]
    assert c["n"] == sel.sum() and c["bias_mm"] == pytest.approx(np.mean(e[sel]), rel=1e-9)
    res = assess_grid(pts, nominal)
    assert len(res.distance_error) <= MAX_STORED_PAIRS
    k = res.pair_index
    np.testing.assert_allclose(1e3 * res.distance_error, 1e3 * (
        np.linalg.norm(pts[k[:, 0]] - pts[k[:, 1]], axis=1)
        - np.linalg.norm(nominal[k[:, 0]] - nominal[k[:, 1]], axis=1)), atol=1e-9)


def test_nearest_matching_of_2500_points_in_seconds():
    rng = np.random.default_rng(1)
    nominal = regular_grid(0.01, (25, 10, 10))
    pts, _ = simulate_grid_points(nominal, rng, noise=2e-4)
    perm = rng.permutation(len(pts))
    t0 = time.perf_counter()
    res = assess_grid(pts[perm], nominal, match="nearest")
    assert time.perf_counter() - t0 < 30          # 1.3 s on the loaded 2-core machine
    np.testing.assert_array_equal(res.nominal_index, perm)


def test_point_limit_is_stated():
    pts = np.zeros((MAX_ASSESS_POINTS + 1, 3))
    pts[:, 0] = np.arange(len(pts))
    with pytest.raises(ValueError, match=f"at most {MAX_ASSESS_POINTS} measured points"):
        assess_grid(pts, pts[:3] + [0, 1, 0])
