"""Recordings solved as a time series (warm start, cold retry) and block-parallel solving into
one poses file: the same file in process and on 1 or 2 Dask worker processes."""

from __future__ import annotations

import argparse
import json
import os

import numpy as np
import pytest

from openemt.bench._batch import simulated_recording
from openemt.cli import _solve
from openemt.geometry import pose_from_vector
from openemt.io import open_dataset_couplings, write_calibration
from openemt.solve import Status, prepare, read_poses, solve, solve_series, solve_to_file

_FIELDS = ("poses", "pose_vectors", "status", "residual", "iterations", "relative_residual")


def _parser():
    p = argparse.ArgumentParser()
    sub = p.add_subparsers()
    _solve.register(sub)
    return p


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """A simulated 1500 samples/s recording (80 dB) written as a dataset marked as one."""
    tmp = tmp_path_factory.mktemp("rec")
    cal, truth = simulated_recording(tmp / "rec.h5", 3000, 1500.0, 80.0, 0)
    write_calibration(cal, tmp / "cal.json")
    with open_dataset_couplings(tmp / "rec.h5", real=True) as r:
        C = r[:]
    return tmp, cal, truth, C


def _same(a, b):
    for name in _FIELDS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_recording_warm_start_gives_the_cold_poses(recording):
    _, cal, truth, C = recording
    warm = solve(C, cal, hemisphere="+x", initial="track")
    cold = solve(C, cal, hemisphere="+x", initial="kim18")
    assert warm.status_counts()["converged"] == len(C) == cold.status_counts()["converged"]
    np.testing.assert_allclose(warm.pose_vectors[:, :3], cold.pose_vectors[:, :3], rtol=0,
                               atol=1e-8)
    assert np.abs(warm.pose_vectors[:, :3] - truth[:, :3]).max() < 1e-3
    # warm starts need fewer iterations: the point of solving a recording as a series. Each
    # row takes one step from its predecessor and the step that confirms convergence; the cold
    # start (issue 19's table start) needs about 4 on this recording
    assert warm.iterations.mean() <= 2.1 and warm.iterations.mean() < cold.iterations.mean()


def test_cold_retry_of_an_injected_bad_sample(recording):
    """A jump to a far pose with a small iteration limit: the warm start from the previous
    sample ends at the limit; the series solves that sample again cold and converges."""
    _, cal, _, C = recording
    jump = np.array([0.12, -0.1, 0.05, 3.1, 0.0, 0.0])
    Cj = C.copy()
    Cj[1000] = cal.model.coupling(pose_from_vector(jump[None]))[0]
    solver = prepare(cal, hemisphere="+x", max_iter=5)
    tracked = solver(Cj, "track")
    assert tracked.status[1000] == Status.MAX_ITERATIONS          # what the retry is for
    res, retried = solve_series(solver, Cj)
    assert retried >= 1
    assert res.status[1000] == Status.CONVERGED
    np.testing.assert_allclose(res.pose_vectors[1000, :3], jump[:3], atol=1e-9)
    # rows the tracked solve converged are kept as they were
    ok = tracked.status == Status.CONVERGED
    np.testing.assert_array_equal(res.pose_vectors[ok], tracked.pose_vectors[ok])
    # every retried row is the better of its tracked and cold answers, never worse
    assert (res.status == Status.CONVERGED).sum() >= ok.sum()


def test_suspicious_converged_sample_is_retried(recording):
    """A converged sample whose relative residual is above the exploration level (a distorted
    coupling) is solved again cold; a clean recording has no retry."""
    _, cal, _, C = recording
    solver = prepare(cal, hemisphere="+x")
    assert solve_series(solver, C[:500])[1] == 0
    Cd = C[:500].copy()
    Cd[250] *= 1 + 5e-3 * np.random.default_rng(1).normal(size=Cd[250].shape)
    tracked = solver(Cd, "track")
    assert tracked.relative_residual[250] > solver.options.explore_above
    res, retried = solve_series(solver, Cd)
    assert retried == 1
    cold = solver(Cd[250:251], "kim18")
    assert res.relative_residual[250] == min(tracked.relative_residual[250],
                                             cold.relative_residual[0])


def _run(tmp, out, *extra, capsys, err=None):
    args = _parser().parse_args(["solve", str(tmp / "rec.h5"), "--calibration",
                                 str(tmp / "cal.json"), "-o", str(tmp / out), "--hemisphere",
                                 "+x", "--chunk-rows", "700", "--json", *extra])
    assert args.func(args) == 0
    captured = capsys.readouterr()
    if err is not None:
        err.append(captured.err)
    return json.loads(captured.out)


def test_solve_command_tracks_a_recording_and_initial_kim18_forces_independent_rows(
        recording, capsys):
    tmp, cal, _, C = recording
    summary = _run(tmp, "warm.h5", capsys=capsys)
    assert summary["recording"] is True and summary["initial"] == "track"
    assert summary["status_counts"]["converged"] == len(C)
    warm = read_poses(tmp / "warm.h5")
    summary = _run(tmp, "cold.h5", "--initial", "kim18", capsys=capsys)
    assert summary["initial"] == "kim18" and summary["cold_retries"] == 0
    cold = read_poses(tmp / "cold.h5")
    # independent rows: each row as if solved alone, whatever the blocks
    _same(cold, solve(C, cal, hemisphere="+x", initial="kim18"))
    # tracked rows start from the previous pose: fewer iterations, the same poses
    assert warm.iterations.mean() <= 2.1 and warm.iterations.sum() < cold.iterations.sum()
    np.testing.assert_allclose(warm.pose_vectors[:, :3], cold.pose_vectors[:, :3], atol=1e-8)


def test_progress_lines_show_rows_rate_and_time_left(recording, capsys):
    tmp, _, _, C = recording
    args = _parser().parse_args(["solve", str(tmp / "rec.h5"), "--calibration",
                                 str(tmp / "cal.json"), "-o", str(tmp / "p.h5"),
                                 "--hemisphere", "+x", "--chunk-rows", "1000", "--progress"])
    assert args.func(args) == 0
    err = capsys.readouterr().err
    last = [line for line in err.splitlines() if line.startswith("solve: ")][-1]
    assert last.startswith(f"solve: {len(C)}/{len(C)} rows (100.0 %), ")
    assert "rows/s" in last and last.endswith("0.0 s left")


def test_same_file_in_process_and_on_one_and_two_worker_processes(recording, capsys):
    distributed = pytest.importorskip("distributed")
    tmp, _, _, _ = recording
    _run(tmp, "local.h5", capsys=capsys)
    local = read_poses(tmp / "local.h5")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                  dashboard_address=None,
                                  env={"NUMBA_NUM_THREADS": "1"}) as cluster, \
            distributed.Client(cluster) as client:
        for k in (1, 2):
            cluster.scale(k)
            client.wait_for_workers(k, timeout=60)
            assert len(client.scheduler_info()["workers"]) == k
            err = []
            summary = _run(tmp, f"dist{k}.h5", "--scheduler", cluster.scheduler_address,
                           "--progress", capsys=capsys, err=err)
            assert summary["status_counts"]["converged"] == len(local)
            _same(read_poses(tmp / f"dist{k}.h5"), local)
            # the rows of every worker's blocks are counted as they finish
            done = [line for line in err[0].splitlines() if line.startswith("solve: ")]
            assert done[-1].startswith(f"solve: {len(local)}/{len(local)} rows (100.0 %)")


class _FailingRows:
    """Rows of an array whose second block cannot be read."""

    def __init__(self, C):
        self.C, self.shape = C, C.shape

    def __len__(self):
        return len(self.C)

    def __getitem__(self, key):
        if key.start and key.start > 0:
            raise OSError(5, "Input/output error")
        return self.C[key]


def test_a_failed_block_leaves_no_output_and_no_temporary(recording):
    tmp, cal, _, C = recording
    folder = tmp / "fail"
    folder.mkdir()
    with pytest.raises(OSError):
        solve_to_file(_FailingRows(C[:100]), cal, folder / "out.h5", chunk_rows=40,
                      hemisphere="+x")
    assert os.listdir(folder) == []


def test_a_track_log_imports_as_a_recording_that_solve_tracks(recording, capsys):
    """``track --log`` couplings -> ``import track-log`` -> a dataset marked as a recording,
    which ``openemt solve`` solves as a time series by default."""
    from openemt.cli import main
    from openemt.live import TrackLogWriter

    tmp, _, truth, C = recording
    n = 600
    writer = TrackLogWriter(tmp / "log.h5")
    writer.set_sensors(["openemt"])
    for a in range(0, n, 200):
        m = min(200, n - a)
        writer.append_arrays({"times": np.arange(a, a + m) / 1500.0,
                              "poses": pose_from_vector(truth[a:a + m]),
                              "pose_vectors": truth[a:a + m], "status": np.zeros(m, np.int8),
                              "residual": np.zeros(m), "distortion": np.zeros(m),
                              "distorted": np.zeros(m, bool),
                              "couplings": C[a:a + m].astype(complex)})
    writer.close()
    assert main(["import", "track-log", str(tmp / "log.h5"), "-o", str(tmp / "log_ds.h5"),
                 "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["n_samples"] == n and summary["sample_rate_hz"] == pytest.approx(1500.0)
    assert main(["solve", str(tmp / "log_ds.h5"), "--calibration", str(tmp / "cal.json"),
                 "-o", str(tmp / "log_poses.h5"), "--hemisphere", "+x", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["recording"] is True and summary["initial"] == "track"
    assert summary["status_counts"]["converged"] == n
    np.testing.assert_allclose(read_poses(tmp / "log_poses.h5").pose_vectors[:, :3],
                               truth[:n, :3], atol=1e-3)
