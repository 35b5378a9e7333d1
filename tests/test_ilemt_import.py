"""ILEMT importer on the real cal_9_15_premo_cmu folder (docs/ilemt-data.md, docs/paper-procedure.md#reproduction)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from openemt.geometry import ground_truth_poses, vector_from_pose
from openemt.io import (
    compensate_stage,
    file_sha256,
    import_ilemt_folder,
    parse_sign_options,
    read_calibration,
    read_ilemt_calibration,
    read_ilemt_dat,
)

ROWS = {"md": 142, "ld": 632, "sweep": 973, "source": 78, "mdtrans": 30, "ldtrans": 128}
FLIPPED = {"soZoutYup_seYoutZup_md.dat", "soZoutYup_seYoutZup_ld.dat", "soXoutZup_seYoutZup_md.dat"}


@pytest.fixture(scope="module")
def folder_ds(ilemt_dir):
    with warnings.catch_warnings():
        warnings.simplefilter("error")      # the real files pass the null-row drift check
        return import_ilemt_folder(ilemt_dir)


def test_row_counts_per_file(folder_ds, ilemt_dir):
    names = sorted(p.name for p in ilemt_dir.glob("so*_se*_*.dat"))
    assert list(folder_ds.files) == names
    assert len(names) == 21
    for i, name in enumerate(folder_ds.files):
        pattern = name.rsplit("_", 1)[1][:-4]
        rows = folder_ds.file_index == i
        assert rows.sum() == ROWS[pattern], name
        assert np.all(folder_ds.pattern[rows] == pattern)
        so, se = name.split("_")[0][2:], name.split("_")[1][2:]
        assert np.all(folder_ds.source_fixture[rows] == so)
        assert np.all(folder_ds.sensor_fixture[rows] == se)
    assert folder_ds.n_samples == sum(ROWS[n.rsplit("_", 1)[1][:-4]] for n in names)
    assert folder_ds.couplings.dtype == np.complex128
    assert folder_ds.extra["couplings_lr"].shape == folder_ds.couplings.shape


def test_sign_flips_follow_local_options(folder_ds, ilemt_dir):
    so, se = parse_sign_options(ilemt_dir / "local_cal_options.m")
    assert so == [("soZoutYup_seYoutZup_(md|ld).dat", (-1.0, -1.0, 1.0)),
                  ("soXoutZup_seYoutZup_md.dat", (-1.0, -1.0, 1.0))]
    assert se == []
    for i, name in enumerate(folder_ds.files):
        rows = folder_ds.file_index == i
        want = [-1, -1, 1] if name in FLIPPED else [1, 1, 1]
        np.testing.assert_array_equal(folder_ds.source_signs[rows], np.tile(want, (rows.sum(), 1)))
        np.testing.assert_array_equal(folder_ds.sensor_signs[rows], 1.0)
    # the flip multiplies source rows of the raw file values
    raw = import_ilemt_folder(ilemt_dir, patterns="md", source_signs=[], sensor_signs=[])
    name = "soZoutYup_seYoutZup_md.dat"
    a = folder_ds.couplings[folder_ds.file_index == folder_ds.files.index(name)]
    b = raw.couplings[raw.file_index == raw.files.index(name)]
    np.testing.assert_array_equal(a, b * np.array([-1, -1, 1])[None, :, None])


def test_provenance_and_names(folder_ds, ilemt_dir):
    assert folder_ds.meta["source"]["name"] == "CMU"
    assert folder_ds.meta["sensor"]["name"] == "premo"
    prov = folder_ds.meta["provenance"]
    assert prov["compensate_stage"] is True
    assert prov["signs_from"] == "local_cal_options.m"
    assert set(prov["inputs"]) == set(folder_ds.files)
    name = "soYoutZup_seZinXdown_md.dat"
    assert prov["inputs"][name] == file_sha256(ilemt_dir / name)
    assert len(prov["inputs"][name]) == 64


def test_patterns_filter_and_no_compensation(ilemt_dir):
    ds = import_ilemt_folder(ilemt_dir, patterns=["mdtrans", "ldtrans"], compensate_stage=False)
    assert ds.files == ("soYoutZup_seYoutZup_ldtrans.dat", "soYoutZup_seYoutZup_mdtrans.dat")
    assert ds.n_samples == 158
    np.testing.assert_array_equal(ds.stage, ds.stage_logged)
    assert np.all(ds.stage[:, 3:] == 0)            # trans files: no rotation at all
    with pytest.raises(ValueError, match="pattern"):
        import_ilemt_folder(ilemt_dir, patterns="nosuchpattern")


def test_worked_example_row(ilemt_dir):
    """docs/ilemt-data.md#worked-example: row 2 of soYoutZup_seZinXdown_md.dat, end to end."""
    ds = read_ilemt_dat(ilemt_dir / "soYoutZup_seZinXdown_md.dat")
    assert ds.n_samples == 142
    np.testing.assert_allclose(ds.stage_logged[1], [-0.05, -0.05, -0.0462, 0, 0, -np.pi / 2],
                               rtol=0, atol=1e-15)
    np.testing.assert_allclose(ds.stage[1, :3] * 1e3, [-50.15, -49.923933, -46.116], atol=5e-7)
    assert ds.stage[1, 5] == -np.pi / 2
    C = ds.couplings[1]
    expect = np.array([[-0.277755 - 0.000050j, 0.094483 + 0.000359j, -0.075956 + 0.000124j],
                       [-0.087723 + 0.000504j, 0.012281 - 0.000041j, 0.163084 - 0.001289j],
                       [0.121600 + 0.000552j, 0.169931 + 0.001728j, 0.032755 - 0.000004j]])
    np.testing.assert_allclose(C.real, expect.real, atol=6e-7)
    np.testing.assert_allclose(C.imag, expect.imag, atol=6e-7)
    assert C[0, 1] == complex(0.094482947, 0.000359092)    # file column 10, not 8
    signed = [[-0.277755, 0.094484, -0.075956], [-0.087725, 0.012281, 0.163089],
              [0.121601, 0.169939, 0.032755]]
    np.testing.assert_allclose(ds.signed_real()[1], signed, atol=6e-7)
    # first value of the lr block is lr C[0, 0] (docs/ilemt-data.md#worked-example)
    assert ds.extra["couplings_lr"][1, 0, 0] == complex(-0.007545182, 0.000000861)

    cal = read_ilemt_calibration(ilemt_dir / "output" / "XYZ_hr_cal.mat")
    P = ground_truth_poses(cal.source_fixture, cal.stage_fixture, cal.sensor_fixture,
                           ds.source_fixture[1:2], ds.stage[1:2], ds.sensor_fixture[1:2])[0]
    np.testing.assert_allclose(P[:3, 3], [0.191934, 0.038003, -0.044156], atol=5e-7)
    np.testing.assert_allclose(vector_from_pose(P)[3:], [0.038683, -2.262403, 2.159695], atol=5e-7)
    pred = cal.model.coupling(P[None])[0]
    np.testing.assert_allclose(pred, [[-0.277596, 0.094483, -0.075848],
                                      [-0.088092, 0.012846, 0.163578],
                                      [0.121062, 0.169763, 0.032187]], atol=5e-7)


def test_compensation_worked_example():
    out = compensate_stage([-50.0, -50.0, -46.2, 0.0, 0.0, -90.0])
    np.testing.assert_allclose(out, [-50.15, -49.923933, -46.116, 0, 0, -90], atol=5e-7)


def _sum_squared_residue(cal, ds, norm_of):
    P = ground_truth_poses(cal.source_fixture, cal.stage_fixture, cal.sensor_fixture,
                           ds.source_fixture, ds.stage, ds.sensor_fixture)
    Cm = ds.signed_real()
    nrm = np.linalg.norm(Cm if norm_of == "signed_real" else ds.couplings, ord=2, axis=(1, 2))
    r = (Cm - cal.model.coupling(P)) / nrm[:, None, None]
    return float(np.sum(r ** 2))


@pytest.mark.parametrize("name", ["XYZ_hr_cal.mat", "XYZ_concentric_hr_cal.mat"])
def test_calibration_residual_reproduced(ilemt_dir, name):
    """docs/paper-procedure.md#reproduction: the objective (docs/paper-procedure.md#calibration-objective) with the stored calibration on its 426 md rows.

    The spectral norm must be taken of the *signed-real* matrix: it reproduces the stored sums
    to ~1e-14 relative, while the norm of the complex matrix is off by ~1e-6 relative.
    """
    ds = import_ilemt_folder(ilemt_dir, patterns="md")
    ds = ds.select(ds.source_fixture == "YoutZup")
    assert ds.n_samples == 426
    cal = read_calibration(ilemt_dir / "output" / name)
    stored = cal.stats["sum_squared_residue"]
    if name == "XYZ_hr_cal.mat":
        assert stored == pytest.approx(0.01000859278, rel=1e-9)
    got = _sum_squared_residue(cal, ds, "signed_real")
    assert got == pytest.approx(stored, rel=1e-8)
    if name == "XYZ_hr_cal.mat":
        assert got == pytest.approx(0.01000859278, rel=1e-8)
    assert abs(_sum_squared_residue(cal, ds, "complex") / stored - 1) > 1e-7
    # without stage compensation the residual is clearly worse (compensation matters)
    raw = import_ilemt_folder(ilemt_dir, patterns="md", compensate_stage=False)
    raw = raw.select(raw.source_fixture == "YoutZup")
    assert _sum_squared_residue(cal, raw, "signed_real") > 1.05 * stored


def test_ilemt_calibration_contents(ilemt_dir):
    cal = read_ilemt_calibration(ilemt_dir / "base_calibration.mat")
    # rounded values printed in docs/ilemt-data.md#calibration-mat
    np.testing.assert_allclose(cal.model.M_so, [[0.819596, -0.015444, 0], [0, 0.897652, 0],
                                                [0.001551, 0.001455, 1]], atol=6e-7)
    np.testing.assert_allclose(cal.stage_fixture, [0.012645, 0.242396, 0.008604, -0.015018,
                                                   0.001146, 0.012816], atol=6e-7)
    assert cal.linear_correction is None and cal.stats == {}
    assert cal.model.gain == 1 / 250
    hr = read_ilemt_calibration(ilemt_dir / "output" / "XYZ_hr_cal.mat")
    assert hr.mode == "XYZ" and hr.linear_correction.shape == (4, 4)
    assert hr.free == ("d_so_pos", "d_so_mo", "d_se_pos", "d_se_mo", "st_fix", "se_fix")
    assert hr.frozen == ("d_so_z_gain", "d_so_y_co", "d_se_y_co")
    assert hr.stats["num_points"] == 426 and hr.stats["num_invalid"] == 0
    opts = hr.provenance["ilemt_options"]
    assert opts["in_files"] == ["soYoutZup_seYoutZup_md.dat", "soYoutZup_seZinYup_md.dat",
                                "soYoutZup_seZinXdown_md.dat"]
    assert opts["source_signs"][0] == ["soZoutYup_seYoutZup_(md|ld).dat", [-1, -1, 1]]
    assert hr.extra["quadrupole"]["q_source_distance"] == pytest.approx(0.004)
    conc = read_ilemt_calibration(ilemt_dir / "output" / "XYZ_concentric_hr_cal.mat")
    assert conc.mode == "XYZ_concentric" and conc.model.is_concentric
