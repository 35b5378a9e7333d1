"""A short run of the generated correction cases of ``openemt bench fuzz`` (the long run is the
bench), and proof that its checks see what they are for."""

from types import SimpleNamespace

import numpy as np
from openemt_fuzz import _fuzzcorrect as F


def test_a_few_generated_correction_cases_hold():
    out = F.fuzz_corrections(12, seed=3)
    assert out["cases"] == 12 and out["findings"] == 0, out["examples"]
    assert all(c["cases"] == 3 for c in out["by_kind"].values())
    assert out["max_seconds_per_case"] < 30


def test_the_checks_catch_garbage():
    corr = F._seed_corrections()["poly"]
    rng = np.random.default_rng(0)
    P = F._poses(rng, corr.box, 40)
    good = corr.correct(P)
    assert F._check_applied(corr, P, good, 0.0) is None
    outside = np.flatnonzero(good.status == 2)
    far = outside[np.argmin(corr.box.distance(P[outside, :3, 3]))]
    moved = good.values.copy()
    moved[far, 0, 3] += 1e-3  # a pose outside the box changed
    assert "changed" in F._check_applied(corr, P, SimpleNamespace(
        values=moved, status=good.status, counts=good.counts), 0.0)
    st = good.status.copy()
    st[far] = 0  # ... or flagged corrected
    assert "beyond the margin" in F._check_applied(corr, P, SimpleNamespace(
        values=moved, status=st, counts=good.counts), 0.0)
    nan = np.flatnonzero(~np.all(np.isfinite(P), axis=(1, 2)))[0]
    st = good.status.copy()
    st[nan] = 2
    assert "non-finite" in F._check_applied(corr, P, SimpleNamespace(
        values=good.values, status=st, counts=good.counts), 0.0)
