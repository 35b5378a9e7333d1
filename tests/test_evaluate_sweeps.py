"""Sweep linearity (Table IV): direct/cross error and Savitzky-Golay nonlinearity."""

import numpy as np
import pytest

from openemt.evaluate import find_sweeps, sweep_linearity
from openemt.geometry import pose_from_vector, stage_transform


def _sweep_stage():
    """An ILEMT-like sweep pattern (mm/deg): null, X, null, Y, null, Z (clipped), null,
    one Rx row, null, one Ry row, null, Rz, null."""
    s = np.arange(-50, 50.001, 0.5)
    rows = [np.zeros((1, 6))]
    for a in range(3):
        b = np.zeros((len(s), 6))
        b[:, a] = np.maximum(s, -46.2) if a == 2 else s
        rows += [b, np.zeros((1, 6))]
    rows += [np.zeros((1, 6))] * 4
    r = np.zeros((361, 6))
    r[:, 5] = np.arange(-90, 90.001, 0.5)
    rows += [r, np.zeros((1, 6))]
    S = np.vstack(rows)
    return np.hstack([S[:, :3] * 1e-3, np.deg2rad(S[:, 3:])])


# known error fields (mm, deg) as functions of the swept coordinate s (mm or deg)
K, Q, C = 0.004, 2e-5, 0.003   # direct slope 0.4 %, curvature, cross deg/mm


def _errors(S):
    e = np.zeros((len(S), 6))
    for a in range(3):
        s = S[:, a] * 1e3
        e[:, a] += K * s + Q * s ** 2          # mm
        e[:, 3 + (a + 1) % 3] += C * s         # deg
    th = np.rad2deg(S[:, 5])
    e[:, 5] += 2 * K * th                      # deg, direct 0.8 %
    e[:, 0] += 0.5 * C * th + 1e-5 * th ** 2   # mm, cross
    return np.hstack([e[:, :3] * 1e-3, np.deg2rad(e[:, 3:])])


def test_find_sweeps_on_ilemt_like_pattern():
    S = _sweep_stage()
    found = {ax: rows for _, ax, rows in find_sweeps(S)}
    assert sorted(found) == ["rz", "x", "y", "z"]  # single Rx/Ry rows are not sweeps
    assert len(np.unique(S[found["x"], 0])) == 201
    assert len(np.unique(S[found["z"], 2])) == 194  # clipped below -46.2 mm
    assert len(np.unique(S[found["rz"], 5])) == 361
    # a 0.3 mm offset on another axis excludes the row
    S2 = S.copy()
    S2[found["x"][:50], 1] = 0.3e-3
    rows2 = {ax: r for _, ax, r in find_sweeps(S2)}["x"]
    assert len(rows2) == len(found["x"]) - 50


def test_sweep_linearity_recovers_known_slopes():
    S = _sweep_stage()
    D = stage_transform(S)
    e = _errors(S)
    M = D @ np.linalg.inv(pose_from_vector(e))  # inv(M) @ D = pose(e) exactly
    an = sweep_linearity(M, D, S, labels=np.full(len(S), "f1"))
    curves = {c.axis: c for c in an.curves}
    assert sorted(curves) == ["rz", "x", "y", "z"]
    x = curves["x"]
    s = x.motion
    # direct: |d e_t/ds| = |K + 2 Q s| exactly (a quadratic is exact for SG order 2), in %
    np.testing.assert_allclose(x.nonlin_direct, 100 * np.abs(K + 2 * Q * s), rtol=1e-6,
                               atol=1e-9)
    np.testing.assert_allclose(x.nonlin_cross, C, rtol=1e-6)
    np.testing.assert_allclose(x.abs_direct, np.abs(K * s + Q * s ** 2), rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(x.abs_cross, np.abs(C * s), rtol=1e-6, atol=1e-12)
    z = curves["z"]  # irregular first step after clipping (-46.2 -> -46.0 mm)
    want = 100 * np.abs(K + 2 * Q * z.motion)
    np.testing.assert_allclose(z.nonlin_direct[11:], want[11:], rtol=1e-6)  # beyond half a window
    np.testing.assert_allclose(z.nonlin_direct[:11], want[:11], rtol=1e-2)  # chain rule, approx.
    rz = curves["rz"]
    assert rz.is_rotation
    np.testing.assert_allclose(rz.nonlin_direct, 100 * 2 * K, rtol=1e-6)
    np.testing.assert_allclose(rz.nonlin_cross, np.abs(0.5 * C + 2e-5 * rz.motion), rtol=1e-6,
                               atol=1e-12)
    t = an.table
    assert t["n_curves"] == {"xyz": 3, "rot": 1}
    # combined by max over the driving axes
    assert t["direct"]["xyz_nonlin_max_percent"] == pytest.approx(100 * (K + 2 * Q * 50), rel=1e-6)
    assert t["direct"]["xyz_abs_max_mm"] == pytest.approx(K * 50 + Q * 2500, rel=1e-6)
    assert t["cross"]["xyz_nonlin_rms_deg_per_mm"] == pytest.approx(C, rel=1e-6)
    assert t["direct"]["rot_nonlin_rms_percent"] == pytest.approx(200 * K, rel=1e-6)
    assert t["cross"]["rot_abs_max_mm"] == pytest.approx(0.5 * C * 90 + 1e-5 * 8100, rel=1e-6)
    assert set(t["cross"]) == {"xyz_abs_rms_deg", "xyz_abs_max_deg", "xyz_nonlin_rms_deg_per_mm",
                               "xyz_nonlin_max_deg_per_mm", "rot_abs_rms_mm", "rot_abs_max_mm",
                               "rot_nonlin_rms_mm_per_deg", "rot_nonlin_max_mm_per_deg"}
    assert an.to_dict()["curves"][0]["n"] == 201


def test_sweep_noise_is_smoothed_and_labels_split_curves():
    rng = np.random.default_rng(40)
    S = np.vstack([_sweep_stage()] * 2)
    lab = np.repeat(["a", "b"], len(S) // 2)
    D = stage_transform(S)
    e = _errors(S)
    e[:, :3] += 1e-6 * rng.standard_normal((len(S), 3))  # 1 um noise
    M = D @ np.linalg.inv(pose_from_vector(e))
    M[10] = np.nan
    an = sweep_linearity(M, D, S, labels=lab)
    assert len(an.curves) == 8
    x = next(c for c in an.curves if c.axis == "x")
    # the SG derivative keeps the noise-induced slope error small vs the 0.4 % slope
    assert np.median(np.abs(x.nonlin_direct - 100 * np.abs(K + 2 * Q * x.motion))) < 0.05
    with pytest.raises(ValueError, match="window"):
        sweep_linearity(M, D, S, window=20)


def test_real_sweep_file_has_four_sweeps(ilemt_dir):
    from openemt.io import read_ilemt_dat
    ds = read_ilemt_dat(ilemt_dir / "soYoutZup_seZinYup_sweep.dat")
    found = {ax: rows for _, ax, rows in find_sweeps(ds.stage_logged)}
    assert sorted(found) == ["rz", "x", "y", "z"]
    assert len(np.unique(ds.stage_logged[found["rz"], 5])) == 361
    assert len(np.unique(ds.stage_logged[found["z"], 2])) == 194
