"""The 'openemt solve' command and the chunked runner."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from openemt._errors import InputError
from openemt.cli import _solve
from openemt.field import DipoleModel
from openemt.geometry import pose_from_vector
from openemt.io import Calibration, Dataset, write_calibration, write_dataset
from openemt.solve import Status, read_poses, solve, solve_chunks


def _parser():
    p = argparse.ArgumentParser()
    sub = p.add_subparsers()
    _solve.register(sub)
    return p


def _dataset(rng, n, model):
    v = np.hstack([rng.uniform(-0.05, 0.05, (n, 3)) + [0.25, 0, 0], rng.normal(size=(n, 3))])
    P = pose_from_vector(v)
    C = model.coupling(P)
    C[3] = np.nan
    ds = Dataset(couplings=C.astype(complex), stage=np.zeros((n, 6)), source_fixture="YoutZup",
                 sensor_fixture="YoutZup", pattern="sim", file_index=np.zeros(n, int),
                 files=("sim",), poses=P)
    return ds, P


@pytest.fixture()
def files(tmp_path):
    rng = np.random.default_rng(20)
    model = DipoleModel.concentric(np.eye(3) * 0.9, np.eye(3) * 0.4)
    ds, P = _dataset(rng, 50, model)
    write_dataset(ds, tmp_path / "data.h5")
    L = np.eye(4)
    L[:3, 3] = [0.001, -0.002, 0.0005]
    write_calibration(Calibration(model, linear_correction=L), tmp_path / "cal.json")
    return tmp_path, P, L


@pytest.mark.parametrize("solver", ["lm", "svd", "kuipers", "kim18"])
def test_solve_command_writes_poses_and_counts(files, solver, capsys):
    tmp, P, L = files
    args = _parser().parse_args(["solve", str(tmp / "data.h5"), "--calibration",
                                 str(tmp / "cal.json"), "--solver", solver, "-o",
                                 str(tmp / "poses.h5"), "--hemisphere", "+x", "--json",
                                 "--chunk-rows", "16"])
    assert args.func(args) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["status_counts"]["invalid_input"] == 1
    assert summary["status_counts"]["converged"] == 49
    assert summary["correction_applied"] is True
    res = read_poses(tmp / "poses.h5")
    ok = np.arange(50) != 3
    assert res.status[3] == Status.INVALID_INPUT and np.all(np.isnan(res.poses[3]))
    # the output correction is a pure translation here
    np.testing.assert_allclose(res.poses[ok, :3, 3], P[ok, :3, 3] + L[:3, 3], atol=1e-10)
    np.testing.assert_allclose(res.poses[ok, :3, :3], P[ok, :3, :3], atol=1e-10)
    np.testing.assert_allclose(res.pose_vectors[ok, :3], res.poses[ok, :3, 3])


@pytest.mark.parametrize("solver", ["lm", "kim18"])
def test_solve_command_validity_options(files, solver, capsys):
    tmp, _, _ = files
    base = ["solve", str(tmp / "data.h5"), "--calibration", str(tmp / "cal.json"), "--solver",
            solver, "-o", str(tmp / "poses.h5"), "--json"]
    for extra, key in ((["--max-relative-residual", "1e-300"], "not_converged"),
                       (["--max-range", "0.1"], "out_of_volume")):
        args = _parser().parse_args(base + extra)
        assert args.func(args) == 0
        counts = json.loads(capsys.readouterr().out)["status_counts"]
        assert counts[key] == 49 and counts["converged"] == 0
    assert np.all(read_poses(tmp / "poses.h5").relative_residual[np.arange(50) != 3] < 1e-9)


def test_solve_command_bad_input_leaves_no_file(files):
    tmp, _, _ = files
    bad = tmp / "not_a_dataset.h5"
    bad.write_text("hello")
    args = _parser().parse_args(["solve", str(bad), "--calibration", str(tmp / "cal.json"),
                                 "-o", str(tmp / "out.h5")])
    with pytest.raises(ValueError, match="expected"):
        args.func(args)
    assert not (tmp / "out.h5").exists()
    args = _parser().parse_args(["solve", str(tmp / "data.h5"), "--calibration",
                                 str(tmp / "cal.json"), "-o", str(tmp / "out.h5"),
                                 "--solver", "svd", "--bounds", "0.4"])
    with pytest.raises(ValueError, match="expected"):
        args.func(args)
    assert not (tmp / "out.h5").exists()


def test_solve_chunks_equals_one_batch():
    rng = np.random.default_rng(21)
    model = DipoleModel.concentric()
    _, P = _dataset(rng, 40, model)
    C = model.coupling(P)
    cal = Calibration(model)
    whole = solve(C, cal, solver="lm", hemisphere="+x")
    parts = list(solve_chunks(C, cal, chunk_rows=7, solver="lm", hemisphere="+x"))
    assert [s for s, _ in parts] == list(range(0, 40, 7))
    joined = np.concatenate([r.poses for _, r in parts])
    np.testing.assert_array_equal(joined, whole.poses)


def test_solve_command_on_a_dask_cluster(files, capsys):
    distributed = pytest.importorskip("dask.distributed")
    tmp, P, L = files
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster:
        args = _parser().parse_args(["solve", str(tmp / "data.h5"), "--calibration",
                                     str(tmp / "cal.json"), "-o", str(tmp / "dist.h5"),
                                     "--hemisphere", "+x", "--chunk-rows", "20", "--json",
                                     "--scheduler", cluster.scheduler_address])
        assert args.func(args) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["status_counts"]["converged"] == 49
    res = read_poses(tmp / "dist.h5")
    ok = np.arange(50) != 3
    np.testing.assert_allclose(res.poses[ok, :3, 3], P[ok, :3, 3] + L[:3, 3], atol=1e-10)


def test_solve_file_workflow_is_what_the_command_prints(files, capsys):
    """The library workflow, called directly, gives the command's JSON and file; the file it
    writes is described by openemt.report.describe."""
    from openemt.report import describe
    from openemt.solve import SolveFileOptions, SolveFileResult, solve_file

    tmp, P, L = files
    opts = SolveFileOptions(dataset=tmp / "data.h5", calibration=tmp / "cal.json",
                            output=tmp / "lib.h5", hemisphere="+x", chunk_rows=16)
    res = solve_file(opts)
    assert isinstance(res, SolveFileResult)
    args = _parser().parse_args(["solve", str(tmp / "data.h5"), "-c", str(tmp / "cal.json"),
                                 "-o", str(tmp / "cli.h5"), "--hemisphere", "+x", "--json",
                                 "--chunk-rows", "16", "--quiet"])
    assert args.func(args) == 0
    cli = json.loads(capsys.readouterr().out)
    lib = res.to_dict()
    for key in ("elapsed_s", "poses_per_s", "output"):
        cli.pop(key), lib.pop(key)
    assert json.loads(json.dumps(lib)) == cli
    np.testing.assert_array_equal(read_poses(tmp / "lib.h5").poses,
                                  read_poses(tmp / "cli.h5").poses)
    info = describe(tmp / "lib.h5")
    assert info.kind == "poses" and info.details["n_samples"] == 50
    assert info.details["status_counts"]["converged"] == 49
    with pytest.raises(InputError, match="finite positive `max_relative_residual`"):
        solve_file(SolveFileOptions(dataset=tmp / "data.h5", calibration=tmp / "cal.json",
                                    output=tmp / "x.h5", max_relative_residual=float("inf")))
    assert not (tmp / "x.h5").exists()
