"""``--bands sheet``: a conducting sheet's eddy currents taken out of each sample from its two
bands, pose and sheet fitted together, with no calibration of the object
(:mod:`openemt.solve._sheet`)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from openemt._errors import InputError
from openemt.solve import BandStage, fit_sheet, sheet_couplings

#: band 0 fast (ILEMT's), band 1 slow
BANDS = np.array([[7500.0, 10500.0, 13500.0], [274.0, 334.0, 370.0]])


@pytest.fixture(scope="module")
def rig():
    from openemt.simulate import rig_volume, truth_calibration

    return truth_calibration("dipole-approx").model, rig_volume()


def _poses(n, lo, hi, seed):
    from scipy.spatial.transform import Rotation

    from openemt.geometry import pose_from_vector

    rng = np.random.default_rng(seed)
    return pose_from_vector(np.c_[rng.uniform(lo, hi, (n, 3)),
                                  Rotation.random(n, random_state=rng).as_rotvec()])


def _vector(P, sheet):
    from scipy.spatial.transform import Rotation

    return np.r_[P[:3, 3], Rotation.from_matrix(P[:3, :3]).as_rotvec(), sheet]


def _measure(model, scene, P, noise=0.0, seed=0):
    rng = np.random.default_rng(seed)
    C0 = model.coupling(P)
    B = np.stack([C0 + scene.induced_couplings(model, P, f) for f in BANDS], axis=1)
    s = noise * np.linalg.norm(C0, axis=(1, 2))[:, None, None, None]
    return B + s * (rng.standard_normal(B.shape) + 1j * rng.standard_normal(B.shape))


@pytest.mark.parametrize("material", ["stainless_steel", "titanium", "aluminium"])
def test_sheet_field_matches_the_simulators_slab_physics(rig, material):
    """Two independent computations of a 2 mm sheet 100 mm under the volume: the fit's
    thin-sheet receding image (complex depths, Gauss-Legendre in log u) and the simulator's
    image series fitted to the full slab reflection factor. They agree to 1 % of the clean
    coupling at both bands, where the sheet's part is 10-40 % of it."""
    from openemt.simulate import MetalObject, MetalScene, get_material

    model, (lo, hi) = rig
    z = lo[2] - 0.1
    scene = MetalScene((MetalObject("sheet", material, (0.0, 0.2, z), thickness=0.002),))
    P = _poses(6, lo, hi, 1)
    B = _measure(model, scene, P)
    S = get_material(material).conductivity * 0.002
    for i in range(len(P)):
        clean, part = sheet_couplings(model, _vector(P[i], [0.0, 0.0, -z, np.log(S)]), BANDS)
        np.testing.assert_allclose(clean, model.coupling(P[i:i + 1])[0], rtol=1e-12)
        norm = np.linalg.norm(clean)
        sim = B[i] - clean
        assert np.linalg.norm(sim[0]) > 0.1 * norm            # the sheet matters
        assert np.linalg.norm(part - sim, axis=(1, 2)).max() < 1e-2 * norm


def test_sheet_field_limits(rig):
    """A perfect conductor (S -> inf) is the mirror image of each source coil with moment
    ``m - 2 (m . n) n``, real; a vanishing conductance (S -> 0) leaves nothing."""
    from openemt.field import DipoleModel

    model, (lo, hi) = rig
    P = _poses(3, lo, hi, 2)
    n = np.array([0.0, 0.0, 1.0])
    d = 0.15
    Lm = model.L_so - 2.0 * (n @ model.L_so + d) * n[:, None]
    Mm = model.M_so - 2.0 * np.outer(n, n @ model.M_so)
    image = DipoleModel(Lm, Mm, model.L_se, model.M_se, model.gain)
    for i in range(len(P)):
        clean, big = sheet_couplings(model, _vector(P[i], [0.0, 0.0, d, np.log(1e12)]), BANDS)
        want = image.coupling(P[i:i + 1])[0]
        np.testing.assert_allclose(big.real, np.broadcast_to(want, big.shape),
                                   atol=1e-6 * np.abs(want).max())
        assert np.abs(big.imag).max() < 1e-6 * np.abs(want).max()
        _, small = sheet_couplings(model, _vector(P[i], [0.0, 0.0, d, np.log(1e-6)]), BANDS)
        assert np.abs(small).max() < 1e-6 * np.abs(clean).max()


def test_fit_takes_an_aluminium_sheet_out_of_every_sample(rig):
    """The bench's hard case: 2 mm of aluminium 100 mm under the volume, inductive at both
    bands (no relaxation can take it out), displaces poses by 100-200 mm; each sample's own
    fit finds the pose to under a millimetre and the sheet's plane and conductance, from a
    search that does not start at the true plane."""
    from openemt.evaluate import pose_error_magnitudes
    from openemt.simulate import get_material, metal_scene
    from openemt.solve import prepare

    model, (lo, hi) = rig
    scene = metal_scene("aluminium_sheet")
    P = _poses(8, lo, hi, 3)
    B = _measure(model, scene, P, noise=1e-4)
    solve = prepare(model, hemisphere="+y")
    start = solve(np.ascontiguousarray(B[:, 0].real)).poses
    before, _ = pose_error_magnitudes(start, P)
    assert before.min() > 0.05
    fit, last = fit_sheet(model, B, BANDS, start, solve=lambda C: solve(C).poses)
    assert fit.fitted.all() and (fit.relative_residual < 5e-3).all()
    after, rot = pose_error_magnitudes(fit.poses, P)
    assert after.max() < 1e-3 and np.degrees(rot).max() < 0.5, (after, rot)
    # the couplings handed to the solver give the same poses
    again, _ = pose_error_magnitudes(solve(fit.couplings).poses, P)
    assert again.max() < 1e-3
    # the sheet: plane z = -0.134 m in the source frame, S = sigma * 2 mm
    z = lo[2] - 0.1
    np.testing.assert_allclose(fit.normal, np.broadcast_to([0.0, 0.0, 1.0], fit.normal.shape),
                               atol=0.02)
    np.testing.assert_allclose(fit.offset, -z, atol=2e-3)
    S = get_material("aluminium").conductivity * 0.002
    np.testing.assert_allclose(fit.conductance, S, rtol=0.05)
    assert fit.starts[0] > 1 and (fit.starts[1:] <= 3).all()   # searched once, then warm
    assert last is not None and np.exp(last[3]) == pytest.approx(S, rel=0.05)


def test_band_stage_sheet_corrects_flagged_samples_only(rig):
    """In a clean workspace no sample is flagged and the couplings are the fast band's as
    they are; a sample that no sheet explains (no fit tried here: ``max_searches`` 0 and no
    warm start) keeps the eddy-free couplings."""
    from openemt.simulate import MetalScene, metal_scene
    from openemt.solve import eddy_free_couplings

    model, (lo, hi) = rig
    P = _poses(5, lo, hi, 4)
    stage = BandStage("sheet", BANDS, model=model, hemisphere="+y")
    B = _measure(model, MetalScene(()), P)
    out, state = stage(B)
    np.testing.assert_array_equal(out, B[:, 0].real)
    assert state is None and stage.last_sheet is None
    B = _measure(model, metal_scene("titanium_disk"), P)
    fit, _ = fit_sheet(model, B, BANDS, np.full((5, 4, 4), np.nan), max_searches=0)
    assert not fit.fitted.any() and np.isnan(fit.poses).all()
    np.testing.assert_array_equal(fit.couplings, B[:, 0].real)
    assert not np.isfinite(fit.relative_residual).any()
    ef = eddy_free_couplings(B, BANDS)
    assert np.isfinite(ef).all()


def test_sheet_needs_a_dipole_calibration_and_is_not_live():
    from openemt.board import BoardModel

    board = BoardModel.from_board("anser")
    with pytest.raises(InputError, match="dipole calibration"):
        BandStage("sheet", BANDS, model=board)
    with pytest.raises(InputError, match="dipole calibration"):
        fit_sheet(board, np.zeros((1, 2, 8, 1), complex), BANDS, np.eye(4)[None])


def test_solve_command_with_bands_sheet(tmp_path, capsys):
    """``openemt solve --bands sheet`` on a simulated rig dataset over the aluminium sheet:
    the poses come back within a millimetre where the fast band is 100 mm off."""
    import json

    from openemt.cli import main
    from openemt.evaluate import pose_error_magnitudes
    from openemt.io import write_calibration, write_dataset
    from openemt.simulate import simulate, truth_calibration
    from openemt.solve import read_poses

    data = simulate("dipole-approx", "mdtrans", source_fixtures="YoutZup",
                    sensor_fixtures="YoutZup", stage_sigma=0, bands=BANDS.tolist(),
                    metal="aluminium_sheet")
    write_dataset(data, tmp_path / "data.h5")
    write_calibration(truth_calibration("dipole-approx"), tmp_path / "cal.json")
    err = {}
    for bands in ("fast", "sheet"):
        out = tmp_path / f"{bands}.h5"
        assert main(["solve", str(tmp_path / "data.h5"), "-c", str(tmp_path / "cal.json"),
                     "-o", str(out), "--bands", bands, "--max-relative-residual", "0.5",
                     "--json", "--quiet"]) == 0
        assert json.loads(capsys.readouterr().out)["bands"] == bands
        poses = read_poses(out)
        t, _ = pose_error_magnitudes(poses.poses, data.poses)
        err[bands] = float(np.sqrt(np.mean(t ** 2)))
    assert err["fast"] > 0.02 and err["sheet"] < 1e-3, err


_values = st.one_of(st.floats(-1e3, 1e3, width=64), st.sampled_from(
    [0.0, 1e-300, -1e-300, 1e300, -1e300, float("nan"), float("inf"), -float("inf")]))


@settings(max_examples=15, deadline=None)
@given(re=arrays(np.float64, (3, 2, 3, 3), elements=_values),
       im=arrays(np.float64, (3, 2, 3, 3), elements=_values),
       scale=st.sampled_from([1e-9, 1e-3, 1.0, 1e6]))
def test_sheet_stage_on_any_input(rig, re, im, scale):
    """Whatever the band couplings (garbage, extremes, non-finite), the sheet stage returns
    couplings of the right shape, finite where the sample is finite and unflagged, never
    raising; a sample it did not fit keeps the eddy-free couplings (the warm start given, no
    search: a few least-squares runs a sample)."""
    from openemt.solve import eddy_free_couplings

    model, _ = rig
    with np.errstate(all="ignore"):
        B = (re + 1j * im) * scale
    stage = BandStage("sheet", BANDS, model=model, hemisphere="+y", sheet_searches=0)
    out, state = stage(B, np.array([0.0, 0.0, 0.13, np.log(5e4)]))
    assert out.shape == (3, 3, 3) and out.dtype == np.float64
    fits = stage.last_sheet
    if fits is None:
        return
    fit, rows = fits
    for k, i in enumerate(rows):
        if not fit.fitted[k]:
            np.testing.assert_array_equal(out[i], eddy_free_couplings(B[i:i + 1], BANDS)[0])
        else:
            assert np.isfinite(out[i]).all() and fit.relative_residual[k] < 5e-3
