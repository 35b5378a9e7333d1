"""'openemt solve' picks the hemisphere per source fixture and explains every class of failed
rows (simulated rig: the truth says where each fixture puts the sensor)."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

from openemt.cli import main
from openemt.geometry import pose_from_vector
from openemt.io import pose_dataset, write_calibration, write_dataset
from openemt.simulate import simulate, truth_calibration
from openemt.solve import (
    RowFixtures,
    Status,
    failure_reasons,
    hemisphere_from_positions,
    read_poses,
    rig_hemispheres,
)


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("rig")
    ds = simulate("dipole-approx", "md", source_fixtures="all", sensor_fixtures=["YoutZup"],
                  snr_db=80, seed=1)
    cal = truth_calibration("dipole-approx")
    write_dataset(ds, tmp / "rig.h5")
    write_calibration(cal, tmp / "cal.json")
    return tmp, ds, cal


def _solve(tmp, capsys, *extra):
    out = tmp / f"poses{len(extra)}.h5"
    rc = main(["solve", str(tmp / "rig.h5"), "-c", str(tmp / "cal.json"), "-o", str(out),
               "--json", *extra])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    return json.loads(cap.out), cap.err, read_poses(out)


def test_rig_hemispheres_match_where_each_fixture_puts_the_sensor(rig):
    _, ds, cal = rig
    codes = sorted(set(ds.source_fixture.tolist()))
    home = rig_hemispheres(cal.source_fixture, cal.stage_fixture, cal.sensor_fixture, codes,
                           ["YoutZup"] * len(codes))
    for code, h in zip(codes, home):
        true = ds.poses[ds.source_fixture == code, :3, 3]
        # every row lies deep in the hemisphere of the fixture's home direction
        assert np.min(true @ (h / np.linalg.norm(h))) > 0.1, code
    # the four fixtures of this rig put the sensor in three different hemispheres
    assert len(set(hemisphere_from_positions(home).tolist())) >= 3


def test_solve_auto_hemisphere_per_source_fixture(rig, capsys):
    tmp, ds, _ = rig
    summary, err, res = _solve(tmp, capsys)
    assert summary["hemisphere"] == "per source fixture"
    axes = {k.split("/")[0]: v["axis"] for k, v in summary["hemispheres"].items()}
    for code, axis in axes.items():
        true = ds.poses[ds.source_fixture == code, :3, 3]
        assert hemisphere_from_positions(true.mean(axis=0)[None])[0] == axis
    assert sum(v["rows"] for v in summary["hemispheres"].values()) == ds.n_samples
    assert summary["status_counts"]["converged"] == ds.n_samples
    assert summary["failed"] == []
    ok = res.status == 0
    assert np.max(np.linalg.norm(res.poses[ok, :3, 3] - ds.poses[ok, :3, 3], axis=1)) < 1e-3
    assert "hemisphere per source fixture" in err


def test_solve_one_hemisphere_explains_the_fixtures_outside_it(rig, capsys):
    tmp, ds, _ = rig
    summary, err, _ = _solve(tmp, capsys, "--hemisphere", "+z")
    assert summary["hemisphere"] == "+z"
    counts = summary["status_counts"]
    failed = summary["failed"]
    assert counts["converged"] < ds.n_samples
    # every failed row belongs to a class with a reason, and the classes add up
    assert sum(f["rows"] for f in failed) == ds.n_samples - counts["converged"]
    for f in failed:
        assert f["reason"] and f["status"] in counts
        assert sum(f["source_fixtures"].values()) == f["rows"]
    # the fixtures whose sensor lies more than 60 deg from +z (by the truth) are named as such
    def angle(code):
        p = ds.poses[ds.source_fixture == code, :3, 3].mean(axis=0)
        return np.degrees(np.arccos(p[2] / np.linalg.norm(p)))

    outside = {c for c in set(ds.source_fixture.tolist()) if angle(c) > 60}
    assert outside and outside != set(ds.source_fixture.tolist())
    hemi = [f for f in failed if "--hemisphere auto" in f["reason"]]
    assert hemi and set().union(*(f["source_fixtures"] for f in hemi)) <= outside
    assert all(code in hemi[0]["reason"] for code in outside)
    for f in failed:
        assert f"  {f['status']} {f['rows']}: {f['reason']}" in err


def test_rows_without_fixture_codes_get_the_generic_reasons(tmp_path):
    # a pose dataset records no fixtures: no rig hemispheres, the generic reason per status
    rng = np.random.default_rng(0)
    P = pose_from_vector(np.hstack([rng.uniform(0.2, 0.3, (20, 3)), rng.normal(size=(20, 3))]))
    write_dataset(pose_dataset(P, file_index=np.zeros(20, int), files=("x",)), tmp_path / "p.h5")
    with h5py.File(tmp_path / "p.h5") as f:
        fx = RowFixtures.read(f, 20, 7, truth_calibration("dipole-approx"))
    assert fx is not None and not fx.usable
    counts = np.zeros(len(Status), int)
    counts[Status.OUT_OF_VOLUME] = 3
    args = type("A", (), {"max_range": 1.5, "bounds": None, "max_iter": 100,
                          "max_relative_residual": 0.01})()
    (entry,) = failure_reasons(counts, args, None, "+x")
    assert entry == {"status": "out_of_volume", "rows": 3,
                     "reason": "the solution is farther than --max-range 1.5 m from the source "
                               "or not finite"}


def test_solve_chunks_takes_one_hemisphere_per_row_lazily(rig):
    from openemt.solve import solve, solve_chunks

    _, ds, cal = rig
    C = ds.signed_real()
    home = rig_hemispheres(cal.source_fixture, cal.stage_fixture, cal.sensor_fixture,
                           ds.source_fixture, ds.sensor_fixture)

    class Lazy:  # row-sliceable, never iterated or converted as a whole
        shape = home.shape

        def __init__(self):
            self.sliced = []

        def __getitem__(self, key):
            assert isinstance(key, slice)
            self.sliced.append(key)
            return home[key]

        def __iter__(self):
            raise AssertionError("iterated")

        def __array__(self, *a, **k):
            raise AssertionError("converted")

    whole = solve(C, cal, hemisphere=home)
    lazy = Lazy()
    parts = list(solve_chunks(C, cal, chunk_rows=100, hemisphere=lazy))
    assert [s for s, _ in parts] == list(range(0, len(C), 100)) == [k.start for k in lazy.sliced]
    np.testing.assert_array_equal(np.concatenate([r.status for _, r in parts]), whole.status)
    np.testing.assert_allclose(np.concatenate([r.poses for _, r in parts]), whole.poses,
                               atol=1e-12)
    assert np.all(whole.status == Status.CONVERGED)
    with pytest.raises(ValueError, match=r"one per row, shape \(568, 3\)"):
        list(solve_chunks(C, cal, hemisphere=home[:10]))
