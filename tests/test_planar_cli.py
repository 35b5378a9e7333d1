"""Planar boards end to end: grid fit with held-out accuracy, the calibration file, `openemt
info` and `openemt solve` on it, and refusals of millimetre input."""

import json

import numpy as np
import pytest

from openemt._errors import InputError
from openemt.board import BoardModel
from openemt.calibrate import GridData, write_grid_csv
from openemt.calibrate._planar import checkerboard_split, fit_planar
from openemt.cli import main
from openemt.io import load_board, read_calibration, write_board
from openemt.simulate import stage_pattern
from openemt.solve import Status
from openemt.solve._planar import solve_planar

HEIGHT = 0.072


def _grid(heights=(HEIGHT,)):
    base = stage_pattern("grid")[:, :3]
    pts = np.vstack([base + [0.0, 0.0, h] for h in heights])
    return pts, np.tile([0.0, 0.0, -1.0], (len(pts), 1))


@pytest.fixture(scope="module")
def truth():
    rng = np.random.default_rng(7)
    offsets = rng.normal(0.0, 2e-3, (8, 3))             # a few mm per coil
    gains = rng.uniform(0.9, 1.1, 8)                     # tesla-scale couplings for 1 A
    return BoardModel.from_board("anser", gains=gains, offsets=offsets)


def _noisy(model, pts, u, sigma, seed):
    C = model.coupling_points(pts, u)
    return C + np.random.default_rng(seed).normal(0.0, sigma, C.shape)


def test_checkerboard_split_alternates():
    pts, _ = _grid()
    m = checkerboard_split(pts)
    assert m.sum() == 25 and (~m).sum() == 24
    # neighbours along x and along y differ
    order = np.lexsort((pts[:, 0], pts[:, 1]))
    grid = m[order].reshape(7, 7)
    assert np.all(grid[:, 1:] != grid[:, :-1]) and np.all(grid[1:] != grid[:-1])


def test_grid_fit_recovers_offsets_and_holds_out_at_noise_level(truth):
    pts, u = _grid()
    C0 = truth.coupling_points(pts, u)
    sigma = 2e-4 * np.abs(C0).max()                      # ~1e-9 T on ~5e-6 T peaks
    C = _noisy(truth, pts, u, sigma, 1)
    mask = checkerboard_split(pts)
    fit = fit_planar(GridData(pts[mask], u[mask], C[mask]))
    assert fit.status == "converged"
    z = (fit.model.offsets - truth.offsets) / fit.offsets_se
    assert np.abs(z).max() < 3.0
    assert np.abs(fit.model.gains / truth.gains - 1).max() < 3 * np.max(fit.gains_se / truth.gains)
    # held-out points: the fitted model solves them about as well as the truth model does
    held = C[~mask]
    fitted = solve_planar(held, fit.model, initial="grid")
    ideal = solve_planar(held, truth, initial="grid")
    assert np.all(fitted.status == Status.CONVERGED) and np.all(ideal.status == Status.CONVERGED)
    e_fit = np.linalg.norm(fitted.poses[:, :3, 3] - pts[~mask], axis=1)
    e_ideal = np.linalg.norm(ideal.poses[:, :3, 3] - pts[~mask], axis=1)
    rms_fit, rms_ideal = np.sqrt(np.mean(e_fit ** 2)), np.sqrt(np.mean(e_ideal ** 2))
    assert rms_ideal < 1e-3                              # the noise level: sub-mm
    assert rms_fit < 2.0 * rms_ideal + 50e-6


def test_fit_with_tilt_and_iteration_limit(truth):
    pts, u = _grid((0.05, 0.09, 0.15))
    w = np.zeros((8, 3))
    w[:, :2] = np.random.default_rng(2).normal(0, 0.01, (8, 2))
    tilted = truth.replace(tilts=w)
    C = tilted.coupling_points(pts, u)
    fit = fit_planar(GridData(pts, u, C), fit_tilt=True)
    assert fit.status == "converged"
    assert np.abs(fit.model.tilts - w).max() < 1e-9
    assert np.abs(fit.model.offsets - truth.offsets).max() < 1e-10
    short = fit_planar(GridData(pts, u, C), fit_tilt=True, max_iter=1)
    assert short.status == "max_iterations"


def _run(argv, capsys):
    rc = main(argv)
    out = capsys.readouterr()
    return rc, out.out, out.err


def test_calibrate_info_solve_end_to_end(truth, tmp_path, capsys):
    from openemt.io import Dataset, write_dataset

    pts, u = _grid()
    C0 = truth.coupling_points(pts, u)
    C = _noisy(truth, pts, u, 1e-4 * np.abs(C0).max(), 3)
    grid = tmp_path / "grid.csv"
    write_grid_csv(GridData(pts, u, C), grid)
    cal_path = tmp_path / "cal.json"
    rc, out, err = _run(["calibrate", str(grid), "--mode", "planar", "--holdout", "checkerboard",
                         "-o", str(cal_path), "--json"], capsys)
    assert rc == 0, err
    s = json.loads(out)
    for key in ("insample", "holdout"):
        block = s[key]
        assert set(block) >= {"position_rms_mm", "position_max_mm", "axis_rms_deg", "n",
                              "coil_residual_percent"}
        assert len(block["coil_residual_percent"]) == 8
    assert s["insample"]["n"] == 25 and s["holdout"]["n"] == 24
    assert s["holdout"]["position_rms_mm"] < 1.0
    assert s["status"] == "converged" and s["warnings"] == []
    doc = json.loads(cal_path.read_text())
    assert doc["schema"] == "openemt.calibration" and doc["model"]["kind"] == "finite"
    assert doc["model"]["board"]["coils"][0]["turns_per_layer"] == 12.5
    cal = read_calibration(cal_path)
    assert cal.kind == "finite" and cal.model.gains.tolist() == s["gains"]
    assert "holdout" in cal.stats and cal.provenance["grid_file"] == str(grid)
    # one calibration type: the board model is a coupling model (8 coils into one sensor coil,
    # 5-DOF) with the fixtures of every calibration (zero: a board calibration has none)
    assert (cal.model.n_source, cal.model.n_sensor, cal.model.dof) == (8, 1, 5)
    assert not np.any(cal.source_fixture) and not np.any(cal.sensor_fixture)
    # where a dipole model is needed, a board calibration is bad input, not a crash
    with pytest.raises(InputError, match="dipole-model calibration"):
        _ = cal.model.M_so
    from openemt.datasets import path as dataset_path

    rc, _, err = _run(["calibrate", str(dataset_path("cal_9_15_premo_cmu")), "--from",
                       str(cal_path), "--mode", "XYZ"], capsys)
    assert rc == 2 and "finite-coil board calibration" in err and err.count("\n") == 1

    rc, out, err = _run(["info", str(cal_path), "--json"], capsys)
    assert rc == 0, err
    info = json.loads(out)
    assert info["model_kind"] == "finite" and info["n_source"] == 8 and info["n_sensor"] == 1

    # a tracking run over the board, solved with the calibration
    n = 200
    s_ = np.linspace(0, 1, n)
    P = np.column_stack([0.06 * np.cos(5 * s_), 0.06 * np.sin(5 * s_), 0.07 + 0.08 * s_])
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, 3] = P
    poses[:, :3, :3] = np.diag([1.0, -1.0, -1.0])       # sensor axis -z
    ds = Dataset(couplings=cal.model.coupling(poses), stage=np.zeros((n, 6)),
                 source_fixture=["YoutZup"] * n, sensor_fixture=["YoutZup"] * n,
                 pattern=["track"] * n, file_index=np.full(n, -1), poses=poses)
    h5 = tmp_path / "track.h5"
    write_dataset(ds, h5)
    out_h5 = tmp_path / "poses.h5"
    rc, out, err = _run(["solve", str(h5), "-c", str(cal_path), "-o", str(out_h5), "--json"],
                        capsys)
    assert rc == 0, err
    res = json.loads(out)
    assert res["status_counts"]["converged"] == n
    from openemt.solve import read_poses

    got = read_poses(out_h5)
    assert np.abs(got.poses[:, :3, 3] - P).max() < 1e-8
    assert np.abs(got.poses[:, :3, 2] - poses[:, :3, 2]).max() < 1e-7

    # --from starts from the previous fit: converges at once to the same answer
    cal2 = tmp_path / "cal2.json"
    rc, out, err = _run(["calibrate", str(grid), "--mode", "planar", "--from", str(cal_path),
                         "--holdout", "checkerboard", "-o", str(cal2), "--json"], capsys)
    assert rc == 0, err
    s2 = json.loads(out)
    assert s2["iterations"] <= 2
    np.testing.assert_allclose(s2["offsets_mm"], s["offsets_mm"], atol=1e-9)


def test_custom_board_and_unit_errors(tmp_path, capsys):
    board = load_board("anser")
    bfile = write_board(board, tmp_path / "my.toml")
    pts, u = _grid()
    C = BoardModel.from_board(load_board(bfile)).coupling_points(pts, u)
    grid = tmp_path / "grid.csv"
    write_grid_csv(GridData(pts, u, C), grid)
    rc, out, err = _run(["calibrate", str(grid), "--mode", "planar", "--board", str(bfile),
                         "--json"], capsys)
    assert rc == 0, err
    assert np.abs(json.loads(out)["offsets_mm"]).max() < 1e-6

    mm = tmp_path / "mm.csv"
    write_grid_csv(GridData(pts * 1e3, u, C), mm)
    rc, out, err = _run(["calibrate", str(mm), "--mode", "planar", "--json"], capsys)
    assert rc == 2 and "millimetres" in err and err.count("\n") == 1
    rc, out, err = _run(["calibrate", str(grid), "--mode", "planar", "--sensor-length", "8"],
                        capsys)
    assert rc == 2 and "sensor length in m" in err and err.count("\n") == 1
    d = board.to_dict()
    d["coils"][2]["center"] = [93.5, 93.5, 0.0]
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(d))
    rc, out, err = _run(["calibrate", str(grid), "--mode", "planar", "--board", str(bad)], capsys)
    assert rc == 2 and "expected center in m" in err


def test_simulate_with_board_file(tmp_path, capsys):
    from openemt.io import read_dataset

    bfile = write_board(load_board("anser"), tmp_path / "b.toml")
    common = ["--preset", "anser", "--source-fixtures", "YoutZup", "--sensor-fixtures",
              "YoutZup", "--stage-sigma", "0"]
    assert main(["simulate", *common, "-o", str(tmp_path / "a.h5"), "--quiet"]) == 0
    assert main(["simulate", *common, "--board", str(bfile), "-o", str(tmp_path / "b.h5"),
                 "--quiet"]) == 0
    a, b = read_dataset(tmp_path / "a.h5"), read_dataset(tmp_path / "b.h5")
    assert a.couplings.shape == (49, 8, 1)
    np.testing.assert_array_equal(a.couplings, b.couplings)
    # the simulator's truth (magpylib traces, a finite sensor) calibrated with the compiled model
    rc, out, err = _run(["calibrate", str(tmp_path / "b.h5"), "--mode", "planar", "--holdout",
                         "checkerboard", "--json"], capsys)
    assert rc == 0, err
    s = json.loads(out)
    assert s["status"] == "converged"
    assert (s["insample"]["n"], s["holdout"]["n"]) == (25, 24)
    assert s["holdout"]["position_rms_mm"] < 1e-4          # the same traces: exact
    rc, _, err = _run(["simulate", "--preset", "concentric", "--board", str(bfile), "-o",
                       str(tmp_path / "c.h5")], capsys)
    assert rc == 2 and "--board only with --preset anser" in err
    assert not (tmp_path / "c.h5").exists()


def test_fit_reports_singular_normal_equations():
    pts = np.tile([[0.0, 0.0, 0.08]], (10, 1))            # one point repeated: 8 x 4 unknowns
    u = np.tile([0.0, 0.0, -1.0], (10, 1))
    C = BoardModel.from_board("anser").coupling_points(pts, u)
    fit = fit_planar(GridData(pts, u, C))
    assert fit.status == "singular"


def test_library_fits_refuse_millimetres():
    from openemt.calibrate._planar import check_grid_units

    pts, u = _grid()
    C = BoardModel.from_board("anser").coupling_points(pts, u)
    with pytest.raises(InputError, match="millimetres"):
        fit_planar(GridData(pts * 1e3, u, C))
    with pytest.raises(InputError, match="sensor length in m"):
        check_grid_units(GridData(pts, u, C), sensor_length=8.0)


def test_holdout_scheme_is_checked(tmp_path, capsys):
    pts, u = _grid()
    grid = tmp_path / "grid.csv"
    write_grid_csv(GridData(pts, u, BoardModel.from_board("anser").coupling_points(pts, u)), grid)
    rc, _, err = _run(["calibrate", str(grid), "--mode", "planar", "--holdout", "0.3"], capsys)
    assert rc == 2 and "--holdout checkerboard" in err


@pytest.mark.parametrize("environment", ["auto", "none"])
def test_planar_calibrate_announces_the_induced_dipoles_kernel(environment, truth, tmp_path,
                                                               capsys, monkeypatch):
    """The environment terms' cross-validation tries induced dipoles, whose fields come from
    the dipole model's Jacobian kernel: the compile notice names it (it compiled after the
    notice before); without environment terms it is not compiled."""
    import openemt._compile_notice as notice

    pts, u = _grid()
    C0 = truth.coupling_points(pts, u)
    write_grid_csv(GridData(pts, u, _noisy(truth, pts, u, 1e-4 * np.abs(C0).max(), 3)),
                   tmp_path / "grid.csv")
    calls = []
    real = notice.announce_compile
    monkeypatch.setattr(notice, "announce_compile", lambda out, what, *, kernels, **kw: (
        calls.append(tuple(kernels)), real(out, what, kernels=kernels, **kw))[1])
    rc, _, err = _run(["calibrate", str(tmp_path / "grid.csv"), "--mode", "planar",
                       "--environment", environment, "-o", str(tmp_path / "c.json")], capsys)
    assert rc == 0, err
    extra = notice.INDUCED_DIPOLE_KERNELS if environment == "auto" else ()
    assert calls == [notice.PLANAR_KERNELS + extra]
