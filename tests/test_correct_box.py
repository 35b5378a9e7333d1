"""Corrections know the box they were fitted on: poses outside it are flagged and passed
through (or corrected within an explicit margin), degenerate correction files are refused when
read, non-finite rows are counted (issue: correct apply outside the fitted box)."""

import json

import numpy as np
import pytest
from openemt_fuzz._fuzzcorrect import box_pairs

from openemt._errors import InputError
from openemt.cli import main
from openemt.correct import (
    MAX_RBF_CENTRES,
    STATUS,
    fit_correction,
    read_correction,
    write_correction,
)
from openemt.io import read_pose_dataset, read_poses_csv, write_poses_csv

CODE = {v: k for k, v in STATUS.items()}


@pytest.fixture(scope="module")
def pairs():
    """Pairs in a 0.1 m box around (0, 0, 0.2) m with a smooth mm-level distortion."""
    return box_pairs(120)


@pytest.fixture(scope="module")
def fitted(pairs, tmp_path_factory):
    meas, ref = pairs
    out = {}
    for method in ("poly", "dlt", "rbf"):
        path = tmp_path_factory.mktemp("c") / f"{method}.json"
        write_correction(fit_correction(meas, ref, method, cross_validate=False), path)
        out[method] = read_correction(path)
    return out


def _far(dists):
    P = np.tile(np.eye(4), (len(dists) + 1, 1, 1))
    P[:, :3, 3] = [0.05, 0.0, 0.2]
    P[:-1, 0, 3] += dists
    P[-1, 0, 3] = np.nan
    return P


@pytest.mark.parametrize("method", ["poly", "dlt", "rbf"])
def test_poses_far_outside_are_flagged_and_passed_through(fitted, method):
    corr = fitted[method]
    P = _far([0.0, 1.0, 10.0, 1e6, 1e300])
    with np.errstate(all="raise"):
        res = corr.correct(P)
    assert res.status.tolist() == [CODE["corrected"]] + [CODE["outside_box"]] * 4 \
        + [CODE["nonfinite_input"]]
    assert res.counts["outside_box"] == 4 and res.counts["nonfinite_input"] == 1
    np.testing.assert_array_equal(res.values[1:5], P[1:5])
    assert np.isnan(res.values[5]).any()
    assert 0 < np.linalg.norm(res.values[0, :3, 3] - P[0, :3, 3]) < 5e-3
    # with a margin of 20 m: corrected where the result is a correction, else rejected;
    # never moved by more than the box's diagonal, never non-finite
    res = corr.correct(P, extrapolate_margin=20.0)
    assert res.status[3] == res.status[4] == CODE["outside_box"]
    assert set(res.status[1:3]) <= {CODE["extrapolated"], CODE["rejected"]}
    shift = np.linalg.norm(res.values[:5, :3, 3] - P[:5, :3, 3], axis=1)
    assert np.all(np.isfinite(res.values[:5])) and shift.max() <= corr.box.diagonal
    assert np.all(shift[res.status[:5] == CODE["rejected"]] == 0)


@pytest.mark.parametrize("change, match", [
    (lambda d: d["params"].__setitem__("matrix", [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0],
                                                  [0, 0, 1, -0.2]]), "vanishes inside the box"),
    (lambda d: d["params"].__setitem__("matrix", [[0, 0, 0, 1], [0, 1, 0, 0], [0, 0, 1, 0],
                                                  [1, 0, 0, 0]]), "vanishes inside the box"),
    (lambda d: d["params"]["matrix"][3].__setitem__(3, 1e-3), "moves positions of its box"),
    # w equal to x over a box at x > 0: one sign, but every position is divided by x
    (lambda d: (d["params"].__setitem__("matrix", [[1, 0, 0, 0.1], [0, 1, 0, 0], [0, 0, 1, 0],
                                                   [1, 0, 0, 0.0]]),
                d["box"].__setitem__("lower_m", [0.05, -0.05, 0.15]),
                d["box"].__setitem__("upper_m", [0.15, 0.05, 0.25])), "moves positions"),
    (lambda d: d["params"]["matrix"][0].__setitem__(0, float("nan")), "finite"),
])
def test_degenerate_dlt_files_are_refused(fitted, tmp_path, change, match):
    doc = fitted["dlt"].to_dict()
    doc["box"] = {"lower_m": [-0.05, -0.05, 0.15], "upper_m": [0.05, 0.05, 0.25]}
    change(doc)
    path = tmp_path / "c.json"
    path.write_text(json.dumps(doc).replace("NaN", "NaN"))
    with pytest.raises(InputError, match="correction file c.json: expected.*" + match):
        read_correction(path)


@pytest.mark.parametrize("change, match", [
    (lambda d: d["params"].__setitem__("scale", 1e-300), "scaled coordinates up to"),
    (lambda d: d["params"]["pos_coef"][1].__setitem__(0, 1e300), "overflows|moves positions|finite over its box"),
    (lambda d: d["params"]["pos_coef"][0].__setitem__(0, 2.0), "moves positions of its box"),
])
def test_degenerate_poly_files_are_refused(fitted, tmp_path, change, match):
    doc = fitted["poly"].to_dict()
    change(doc)
    path = tmp_path / "c.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(InputError, match=match):
        read_correction(path)


def test_rbf_centre_limit_is_stated_before_allocation(fitted, tmp_path):
    doc = fitted["rbf"].to_dict()
    n = 100_000
    doc["params"]["points"] = np.zeros((n, 3)).tolist()
    doc["params"]["values"] = np.zeros((n, 6)).tolist()
    path = tmp_path / "big.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(InputError, match=f"at most MAX_RBF_CENTRES = {MAX_RBF_CENTRES} RBF "
                                         f"centres.*got {n}"):
        read_correction(path)
    dup = fitted["rbf"].to_dict()  # duplicated centres without smoothing: a singular system
    dup["params"]["points"] = [dup["params"]["points"][0]] * len(dup["params"]["points"])
    dup["params"]["smoothing"] = 0.0
    path.write_text(json.dumps(dup))
    with pytest.raises(InputError, match="rbf correction"):
        read_correction(path)


def test_rbf_fit_subsamples_its_centres(pairs):
    meas, ref = pairs
    corr = fit_correction(meas, ref, "rbf", cross_validate=False, max_centres=50)
    assert len(corr.params["points"]) == 50
    assert any("random subsample of 50" in w for w in corr.stats["warnings"])


def test_version_1_files(fitted, tmp_path):
    P = _far([0.0, 1.0])
    for method, box_known in (("dlt", False), ("rbf", True)):
        doc = fitted[method].to_dict()
        doc["version"] = 1
        del doc["box"]
        path = tmp_path / f"{method}.json"
        path.write_text(json.dumps(doc))
        corr = read_correction(path)
        assert (corr.box is not None) == box_known
        if box_known:  # the RBF's centres give its box
            np.testing.assert_allclose(corr.box.lower, fitted[method].box.lower, atol=1e-12)
            assert corr.correct(P).counts["outside_box"] == 1
            continue
        with pytest.raises(InputError, match="version-1 dlt file without one.*--allow-unknown"):
            corr.correct(P)
        assert corr.correct(P, allow_unknown_box=True).counts["unchecked"] == 2


def test_cli_apply_writes_status_per_row_and_counts(fitted, pairs, tmp_path, capsys):
    meas, ref = pairs
    write_correction(fitted["poly"], tmp_path / "c.json")
    P = np.concatenate([meas[:10], _far([1.0, 1e6])])
    R = np.concatenate([ref[:10], _far([1.0, 1e6])])
    write_poses_csv(tmp_path / "in.csv", P, R)
    for out in ("out.csv", "out.h5"):
        rc = main(["correct", "apply", str(tmp_path / "c.json"), str(tmp_path / "in.csv"),
                   "-o", str(tmp_path / out), "--json"])
        cap = capsys.readouterr()
        assert rc == 0, cap.err
        s = json.loads(cap.out)
        assert s["counts"]["corrected"] == 10 and s["counts"]["outside_box"] == 2
        assert s["counts"]["nonfinite_input"] == 1 and s["max_outside_mm"] > 0.99e9
        assert "outside the correction's fitted box" in cap.err
        assert s["errors"]["n"] == 12
        assert s["errors"]["corrected"]["trans_rms_mm"] < s["errors"]["uncorrected"]["trans_rms_mm"]
    rows = (tmp_path / "out.csv").read_text().splitlines()
    assert rows[0].endswith(",correction") and rows[11].endswith(",outside_box")
    assert rows[13].endswith(",nonfinite_input")
    np.testing.assert_array_equal(read_poses_csv(tmp_path / "out.csv").poses[10:12], P[10:12])
    ds = read_pose_dataset(tmp_path / "out.h5")
    assert ds.extra["correction_status"].tolist() == [0] * 10 + [2, 2, 3]
    assert ds.meta["correction_status_codes"]["2"] == "outside_box"
    rc = main(["correct", "apply", str(tmp_path / "c.json"), str(tmp_path / "in.csv"),
               "-o", str(tmp_path / "m.csv"), "--extrapolate-margin", "-1"])
    assert rc == 2 and "margin" in capsys.readouterr().err and not (tmp_path / "m.csv").exists()


def test_cli_is_thin():
    from pathlib import Path

    import openemt.cli._correct as mod

    text = Path(mod.__file__).read_text()
    assert len(text.splitlines()) <= 80
    assert "from .." not in text.replace("from ..correct import", "")
    assert "._" not in "".join(ln for ln in text.splitlines() if ln.startswith("from ..correct"))
