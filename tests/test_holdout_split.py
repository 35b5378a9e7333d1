"""Held-out splits defined once (docs/calibration.md#held-out-splits)."""

import numpy as np
import pytest

from openemt._errors import InputError
from openemt.calibrate import checkerboard_split, fit_reference, holdout_split
from openemt.simulate import nominal_calibration, simulate_reference


def test_random_fraction_is_seeded_and_sized():
    a = holdout_split(0.25, 100, seed=3)
    assert a.sum() == 25 and np.array_equal(a, holdout_split(0.25, 100, seed=3))
    assert not np.array_equal(a, holdout_split(0.25, 100, seed=4))
    assert holdout_split(0.001, 50).sum() == 1          # a non-zero fraction holds one out
    assert holdout_split(0.0, 50).sum() == 0
    # the permutation's first rows, as the reference calibration has always drawn them
    perm = np.random.default_rng(7).permutation(40)
    assert set(np.flatnonzero(holdout_split(0.2, 40, seed=7))) == set(perm[:8])


def test_checkerboard_location_and_ld():
    g = np.linspace(-0.1, 0.1, 7)
    pts = np.array([[x, y, 0.07] for x in g for y in g])
    cb = holdout_split("checkerboard", len(pts), points=pts)
    np.testing.assert_array_equal(cb, ~checkerboard_split(pts))
    loc = holdout_split("location", len(pts), points=pts)
    # whole quadrants of the plane held out: two of four, each point's quadrant shared
    quad = (pts[:, 0] >= 0).astype(int) + (pts[:, 1] >= 0).astype(int)
    assert set(quad[loc] % 2) == {1} and set(quad[~loc] % 2) == {0}
    rng = np.random.default_rng(0)
    cloud = rng.uniform(-1, 1, (4000, 3))
    frac = holdout_split("location", 4000, points=cloud).mean()
    assert 0.45 < frac < 0.55
    pat = np.array(["md", "ld", "md", "ld", "ldtrans"])
    np.testing.assert_array_equal(holdout_split("ld", 5, patterns=pat),
                                  [False, True, False, True, False])


def test_bad_schemes_are_one_line():
    with pytest.raises(InputError, match=r"fraction in \[0, 1\) or a scheme"):
        holdout_split("half", 10)
    with pytest.raises(InputError, match=r"fraction in \[0, 1\)"):
        holdout_split(1.5, 10)
    with pytest.raises(InputError, match=r"positions \(10, 3\)"):
        holdout_split("location", 10)
    with pytest.raises(InputError, match="at least 9 training poses, got 5 of 10"):
        holdout_split(0.5, 10, min_train=9, what="poses")


def test_reference_calibration_held_out_by_location():
    ds = simulate_reference("concentric", "robot", 80, snr_db=80, seed=2)
    f = fit_reference(ds, nominal_calibration("concentric"), holdout="location", warn=False)
    t = ds.extra["reference_poses"][:, :3, 3]
    test = np.zeros(80, bool)
    test[f.test] = True
    np.testing.assert_array_equal(test, holdout_split("location", 80, points=t))
    assert f.holdout["n"] == test.sum() and f.holdout["n_not_converged"] == 0
    assert f.holdout["trans_rms_mm"] < 0.5
    assert f.calibration.provenance["holdout"] == "location"
