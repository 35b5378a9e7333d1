"""Tensor-product Bernstein correction: at the noise floor on the distortion of degree 2 per axis
that the total-degree polynomial cannot represent, refusal outside its box, the correction file,
and ``auto`` (which considers it) never worse than no correction."""

import json

import numpy as np
import pytest

from openemt._errors import InputError
from openemt.bench._correct import NOISE_M, distorted_poses, tensor_distortion
from openemt.cli import main
from openemt.correct import (
    bernstein_basis,
    fit_auto_correction,
    fit_correction,
    read_correction,
    write_correction,
)
from openemt.io import read_poses_csv, write_poses_csv

FLOOR_MM = 1e3 * NOISE_M * np.sqrt(3)


@pytest.fixture(scope="module")
def tensor_pairs():
    return distorted_poses(400, np.random.default_rng(0), "tensor")


def test_basis_is_a_partition_of_unity_and_holds_the_tensor_term():
    u = np.random.default_rng(1).uniform(0, 1, (50, 3))
    for d in (1, 2, 5):
        B = bernstein_basis(u, d)
        assert B.shape == (50, (d + 1) ** 3) and np.all(B >= 0)
        np.testing.assert_allclose(B.sum(axis=1), 1.0)
    # x^2 y^2 z^2 lies in the degree-2 span
    B = bernstein_basis(u, 2)
    target = np.prod(u ** 2, axis=1)
    coef = np.linalg.lstsq(B, target, rcond=None)[0]
    np.testing.assert_allclose(B @ coef, target, atol=1e-12)


def test_bernstein_reaches_the_noise_floor_where_poly_cannot(tensor_pairs):
    meas, ref = tensor_pairs
    b = fit_correction(meas, ref, "bernstein")
    # the total-degree polynomial at the highest order auto tries (its order selection prefers
    # lower orders here, held out); P2(x) P2(y) P2(z) is orthogonal to all of them
    p = fit_correction(meas, ref, "poly", order=5, rot_order=2)
    ho_b = b.stats["held_out"]["corrected"]["trans_rms_mm"]
    ho_p = p.stats["held_out"]["corrected"]["trans_rms_mm"]
    unc = b.stats["held_out"]["uncorrected"]["trans_rms_mm"]
    assert unc > 5 * FLOOR_MM
    assert ho_b < 1.1 * FLOOR_MM
    assert ho_p > 3 * FLOOR_MM
    assert b.params["pos_degree"] == 2
    assert b.corrects_orientation
    assert b.stats["held_out"]["corrected"]["rot_rms_deg"] < 1.15 * 0.03 * np.sqrt(3)


def test_box_refusal_and_file_round_trip(tmp_path, tensor_pairs):
    meas, ref = tensor_pairs
    corr = fit_correction(meas[:, :3, 3], ref[:, :3, 3], "bernstein", degree=2,
                          cross_validate=False)
    lo, hi = corr.params["lower"], corr.params["upper"]
    span = meas[:, :3, 3].max(0) - meas[:, :3, 3].min(0)
    np.testing.assert_allclose(hi - lo, 1.1 * span)  # 5 % margin on each side
    path = tmp_path / "bern.json"
    write_correction(corr, path)
    back = read_correction(path)
    x = meas[:20, :3, 3]
    np.testing.assert_array_equal(back.apply(x), corr.apply(x))
    outside = x.copy()
    outside[3, 0] = hi[0] + 0.01
    # the model itself refuses positions outside its basis box; a Correction passes them
    # through, flagged (like every method outside its fitted box), even within a margin
    with pytest.raises(InputError, match="inside the bernstein correction's box.*1 outside.*"
                                         "row 3.*not extrapolated"):
        corr.model.predict(outside)
    res = corr.correct(outside, extrapolate_margin=1.0)
    assert res.status[3] == 2 and np.array_equal(res.values[3], outside[3])
    np.testing.assert_allclose(np.delete(res.values, 3, 0), np.delete(corr.apply(x), 3, 0),
                               rtol=0, atol=1e-15)
    doc = json.loads(path.read_text())
    doc["params"]["pos_coef"] = doc["params"]["pos_coef"][:-1]
    path.write_text(json.dumps(doc))
    with pytest.raises(InputError, match="pos_coef"):
        read_correction(path)


def test_auto_considers_bernstein_and_is_never_worse_than_none():
    rng = np.random.default_rng(3)
    cases = [distorted_poses(200, rng, "tensor"),  # bernstein wins
             distorted_poses(40, rng, "tensor")]   # few pairs
    # no distortion at all: only noise
    m, r = distorted_poses(80, rng, "tensor")
    p = r[:, :3, 3]
    dp, _ = tensor_distortion(p)
    m[:, :3, 3] = p + NOISE_M * rng.standard_normal(p.shape)
    m[:, :3, :3] = r[:, :3, :3]
    cases.append((m, r))
    chosen = []
    for meas, ref in cases:
        c = fit_auto_correction(meas, ref, k=3)
        cand = c.stats["auto"]["candidates"]
        assert "bernstein" in cand
        none = cand["none"]["score_mm"]
        assert cand[c.method]["score_mm"] <= none
        ho = c.stats["held_out"]
        assert ho["corrected"]["trans_rms_mm"] <= ho["uncorrected"]["trans_rms_mm"] * 1.02
        chosen.append(c.method)
    assert chosen[0] == "bernstein"


def test_correct_fit_cli_bernstein(tmp_path, capsys, tensor_pairs):
    meas, ref = tensor_pairs
    write_poses_csv(tmp_path / "pairs.csv", meas[:200], ref[:200])
    rc = main(["correct", "fit", str(tmp_path / "pairs.csv"), "--method", "bernstein",
               "--degree", "2", "--rot-degree", "2", "-o", str(tmp_path / "c.json"), "--json"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    s = json.loads(cap.out)
    assert s["method"] == "bernstein" and s["selected"]["pos_degree"] == 2
    assert s["requirements"]["parameters_per_coordinate"] == 27
    far = meas[:5].copy()
    far[:, 0, 3] += 1.0
    write_poses_csv(tmp_path / "far.csv", far)
    rc = main(["correct", "apply", str(tmp_path / "c.json"), str(tmp_path / "far.csv"), "-o",
               str(tmp_path / "out.csv"), "--json"])
    cap = capsys.readouterr()
    # 1 m outside the box: passed through uncorrected and flagged, never extrapolated
    assert rc == 0 and "outside the correction's fitted box" in cap.err
    assert json.loads(cap.out)["counts"]["outside_box"] == 5
    out = read_poses_csv(tmp_path / "out.csv")
    np.testing.assert_allclose(out.poses, far, atol=1e-12)
    assert (tmp_path / "out.csv").read_text().count("outside_box") == 5
