"""``openemt bench batch``: ``openemt solve``'s file-to-file path, on a simulated recording.

Data: the ``dipole-approx`` truth calibration (three air coils with 45 mm offsets, MacLachlan
et al. 2025 Table I), the smooth trajectory of ``openemt bench speed`` (0.05 m Lissajous around
0.25 m, about 0.2 m/s and 1 rad/s) sampled at ``--rate-hz`` (1500 samples/s, the live
pipeline's rate), white noise at ``--snr-db`` (80 dB) on the couplings, written as a dataset
marked as a recording (``meta["recording"]``, docs/data-format.md).

- ``recording_*``: :func:`openemt.solve.solve_to_file` in this process with one numba thread,
  as ``openemt solve`` runs a recording by default (``initial='track'``: each row warm-started
  from the previous converged one, failed or suspicious rows solved again cold), input file
  to output file; ``cold_*`` the same run with ``initial='kim18'`` (independent rows, what
  ``--initial kim18`` forces). Rates use the process CPU time (the work of one core, as
  ``bench speed``; ``*_wall_poses_per_s`` the wall clock), best of ``--repeats``.
  ``recording_vs_cold_max_position_diff_m``: the largest position difference between the two
  answers on the rows both call converged.
- ``--workers 1,2``: for each k a ``dask.distributed.LocalCluster`` of k worker processes with
  one thread each (and one numba thread), a recording of ``--worker-samples`` rows solved with ``--workers-initial``
  (default ``kim18``: independent rows, the compute-bound case) in blocks of
  ``--chunk-rows`` (12500); each worker reads its blocks from the input and writes them into the
  output. ``poses_per_s`` per k (wall clock, best of ``--repeats``, after a warm-up solve that
  loads the kernels on every worker), ``scaling_efficiency`` = poses/s at k / (k x poses/s at 1),
  ``worker_peak_rss_mb`` the largest peak resident memory of a worker process (and after the
  warm-up, before the first full block: ``worker_rss_after_warmup_mb``), the CPU and wall
  seconds of the block tasks together (``block_cpu_s``, ``block_wall_s``; ``cpu_per_wall``:
  the cores' worth of CPU the workers got over the run; ``busy_fraction``: the share of the
  run's wall time the k workers spent in block tasks; ``cpu_efficiency``: the block CPU at 1
  worker over that at k, the overhead of parallel running apart from other load), and the
  machine's load average before and after (other work on a shared machine lowers the
  scaling).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from .._compile_notice import serial_threads
from .._errors import InputError
from ._timing import best_time

__all__ = ["add_arguments", "run"]


def add_arguments(parser) -> None:
    parser.add_argument("--samples", type=int, default=150000,
                        help="samples of the simulated recording (150000: 100 s at 1500/s)")
    parser.add_argument("--rate-hz", type=float, default=1500.0,
                        help="sample rate of the recording (1500)")
    parser.add_argument("--snr-db", type=float, default=80.0, help="coupling SNR (80 dB)")
    parser.add_argument("--repeats", type=int, default=3, help="timing repeats (best taken)")
    parser.add_argument("--workers", default="",
                        help="comma-separated worker counts of the LocalCluster runs, e.g. "
                             "1,2 (default: none)")
    parser.add_argument("--workers-initial", default="kim18", choices=("kim18", "track"),
                        help="LM start of the LocalCluster runs (kim18: independent rows)")
    parser.add_argument("--worker-samples", type=int, default=300000,
                        help="rows of the recording the LocalCluster runs solve (300000)")
    parser.add_argument("--chunk-rows", type=int, default=12500,
                        help="rows per block of the LocalCluster runs (12500: 24 equal blocks "
                             "of the default 300000 rows)")
    parser.add_argument("--seed", type=int, default=0)


def _worker_counts(text: str) -> list[int]:
    if not text.strip():
        return []
    try:
        ks = [int(t) for t in text.split(",") if t.strip()]
    except ValueError:
        ks = [0]
    if not ks or min(ks) < 1:
        raise InputError(f"expected --workers as positive integers such as 1,2, got {text!r}")
    return ks


def simulated_recording(path, n: int, rate_hz: float, snr_db: float, seed: int):
    """Write the benchmark's recording to ``path``; returns (truth calibration, true pose
    vectors)."""
    from ..geometry import pose_from_vector
    from ..io import Dataset, recording_meta, write_dataset
    from ..simulate import add_noise, noise_sigma, truth_calibration
    from ._speed import trajectory

    cal = truth_calibration("dipole-approx")
    truth = trajectory(n, rate_hz)
    C = cal.model.coupling(pose_from_vector(truth))
    C = add_noise(C, noise_sigma(C, snr_db=snr_db), np.random.default_rng(seed))
    ds = Dataset(couplings=C, stage=np.zeros((n, 6)), source_fixture="", sensor_fixture="",
                 pattern="recording", file_index=np.full(n, -1), poses=pose_from_vector(truth),
                 meta={"recording": recording_meta(rate_hz, "openemt bench batch")})
    write_dataset(ds, path)
    return cal, truth


def run(args) -> dict:

    from ..io import open_dataset_couplings
    from ..solve import Status, read_poses, solve_to_file

    n = int(args.samples)
    if n < 10 or not args.rate_hz > 0:
        raise InputError(f"expected --samples >= 10 and a positive --rate-hz, got {n}, "
                         f"{args.rate_hz}")
    if args.chunk_rows < 1:
        raise InputError(f"expected a positive --chunk-rows, got {args.chunk_rows}")
    ks = _worker_counts(args.workers)
    summary: dict = {"samples": n, "rate_hz": args.rate_hz, "snr_db": args.snr_db,
                     "preset": "dipole-approx", "numba_threads": 1,
                     "load_average_start": list(os.getloadavg()), "cpu_count": os.cpu_count()}
    with serial_threads(), tempfile.TemporaryDirectory(prefix="openemt-bench-batch-") as tmp:
        tmp = Path(tmp)
        data = tmp / "data.h5"
        cal, truth = simulated_recording(data, n, args.rate_hz, args.snr_db, args.seed)
        answers = {}
        with open_dataset_couplings(data) as reader:
            for name, initial in (("recording", "track"), ("cold", "kim18")):
                out = tmp / f"poses_{name}.h5"
                # warm-up on a few rows: loads (or compiles) the kernels
                solve_to_file(reader[:200], cal, tmp / "warm.h5", hemisphere="+x",
                              initial=initial)
                cpu, wall, done = best_time(lambda out=out, initial=initial: solve_to_file(
                    reader, cal, out, hemisphere="+x", initial=initial), args.repeats)
                res = read_poses(out)
                answers[name] = res
                summary[f"{name}_poses_per_s"] = n / cpu
                summary[f"{name}_wall_poses_per_s"] = n / wall
                summary[f"{name}_status_counts"] = res.status_counts()
                summary[f"{name}_mean_iterations"] = float(res.iterations.mean())
                err = res.pose_vectors[:, :3] - truth[:, :3]
                summary[f"{name}_position_rms_error_m"] = float(np.sqrt(np.mean(err ** 2)
                                                                        * 3))
                if name == "recording":
                    summary["recording_cold_retries"] = done.cold_retries
        a, b = answers["recording"], answers["cold"]
        both = (a.status == Status.CONVERGED) & (b.status == Status.CONVERGED)
        summary["recording_vs_cold_max_position_diff_m"] = float(
            np.abs(a.pose_vectors[both, :3] - b.pose_vectors[both, :3]).max()) \
            if both.any() else None
        summary["recording_vs_cold_speedup"] = (summary["recording_poses_per_s"]
                                                / summary["cold_poses_per_s"])
        if ks:
            data = tmp / "workers.h5"
            simulated_recording(data, int(args.worker_samples), args.rate_hz, args.snr_db,
                                args.seed)
            summary["workers"] = _scaling(data, cal, ks, args, tmp)
    summary["load_average_end"] = list(os.getloadavg())
    targets = {"recording_poses_per_s >= 150000": summary["recording_poses_per_s"] >= 1.5e5}
    eff2 = summary.get("workers", {}).get("scaling_efficiency", {}).get("2")
    if eff2 is not None:
        targets["scaling_efficiency at 2 workers >= 0.8"] = eff2 >= 0.8
    summary["targets"] = targets
    return summary


def _scaling(data, cal, ks, args, tmp) -> dict:
    """The LocalCluster runs: poses/s per worker count and the scaling efficiency."""
    import distributed

    from ..io import open_dataset_couplings
    from ..solve import solve_to_file, status_count_names

    out: dict = {"initial": args.workers_initial, "chunk_rows": args.chunk_rows,
                 "poses_per_s": {}, "scaling_efficiency": {}, "worker_peak_rss_mb": {},
                 "worker_rss_after_warmup_mb": {}, "samples": None, "block_cpu_s": {},
                 "block_wall_s": {}, "cpu_per_wall": {}, "busy_fraction": {},
                 "load_average": {}}
    with open_dataset_couplings(data) as reader:
        n = out["samples"] = reader.shape[0]
        for k in ks:
            with distributed.LocalCluster(n_workers=k, threads_per_worker=1, processes=True,
                                          dashboard_address=None,
                                          env={"NUMBA_NUM_THREADS": "1",
                                               "OMP_NUM_THREADS": "1"}) as cluster, \
                    distributed.Client(cluster) as client:
                # warm-up: every worker loads the kernels (and opens the input) once
                warm_rows = min(n, 256 * k)
                warm = solve_to_file(reader[:warm_rows], cal, tmp / "warm.h5",
                                     hemisphere="+x", initial=args.workers_initial,
                                     chunk_rows=max(1, warm_rows // k), scheduler=client)
                load0 = os.getloadavg()[0]
                _, wall, done = best_time(lambda k=k, client=client: solve_to_file(
                    reader, cal, tmp / f"workers{k}.h5", hemisphere="+x",
                    initial=args.workers_initial, chunk_rows=args.chunk_rows, scheduler=client),
                    args.repeats)
                out["poses_per_s"][str(k)] = n / wall
                out["worker_peak_rss_mb"][str(k)] = float(max(done.block_rss_mb))
                out["block_cpu_s"][str(k)] = done.block_cpu_s
                out["block_wall_s"][str(k)] = done.block_wall_s
                out["cpu_per_wall"][str(k)] = done.block_cpu_s / wall
                out["busy_fraction"][str(k)] = done.block_wall_s / (k * wall)
                out["worker_rss_after_warmup_mb"][str(k)] = float(max(warm.block_rss_mb))
                out["load_average"][str(k)] = [load0, os.getloadavg()[0]]
                if k == ks[0]:
                    out["status_counts"] = status_count_names(done.counts)
    base = out["poses_per_s"].get("1")
    if base:
        out["cpu_efficiency"] = {}
        for k in ks:
            out["scaling_efficiency"][str(k)] = out["poses_per_s"][str(k)] / (k * base)
            # the same work's CPU at 1 and at k workers: the cost of running in parallel,
            # whatever else the machine runs
            out["cpu_efficiency"][str(k)] = out["block_cpu_s"]["1"] / out["block_cpu_s"][str(k)]
    return out
