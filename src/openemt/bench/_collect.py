"""``openemt bench collect``: the collect-then-calibrate path on a simulated robot, against the
same calibration on ``openemt simulate --reference`` data.

Runs, in a temporary folder, through the library workflows:

1. :func:`openemt.collect.collect` with ``--source sim --simulate-reference KIND --n-poses N
   --seed S`` (the simulated tracker on the robot's dwell motion; the robot served by an
   OpenIGTLink server at ``--rate`` Hz with ``--latency-ms`` and ``--clock-offset-ms``;
   ``--sim-speed`` simulated seconds per wall second, 1 = real time);
2. :func:`openemt.calibrate.fit_reference` on it (the preset's nominal start, ``--holdout``,
   seed 0), as ``openemt calibrate col.h5 --mode reference`` does;
3. :func:`openemt.simulate.simulate_reference` with the same N and seed and the same
   calibration: the baseline.

Keys
----
n_poses_written
    Poses in the collected dataset (the target: exactly ``--n-poses``).
seconds_per_signal_second
    Wall time of the collection (set-up, streams, analysis and writing) over the seconds of
    tracker signal it read; at ``--sim-speed 1`` the target is at most 1.5. Read it with
    ``load_average`` (1, 5 and 15 minute load at the start) on a shared machine.
time_offset_ms, time_offset_true_ms, time_offset_error_ms
    The offset collect measured (reference clock minus tracker clock, by cross-correlation of
    motion), the true one (latency + clock offset) and the difference. Target |error| < 5 ms.
offset_correlation, offset_confidence
    Of that estimate (docs/reference-calibration.md#collecting).
dwells_found, dwells_true
    Dwells kept over the collected span, and the robot's holds that lie within it.
heldout_trans_rms_mm, heldout_rot_rms_deg
    Held-out error of the calibration on the collected data (docs/reference-calibration.md
    #held-out-error).
baseline_heldout_trans_rms_mm, baseline_heldout_rot_rms_deg
    The same on the simulate-path data with the same number of poses.
heldout_ratio
    ``heldout_trans_rms_mm / baseline_heldout_trans_rms_mm``; target <= 1.25.
collect_wall_s
    Wall time of the collection (real time at ``--sim-speed 1``).
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

__all__ = ["add_arguments", "run"]



def add_arguments(parser) -> None:
    parser.add_argument("--kind", choices=("robot", "optical"), default="robot",
                        help="simulated reference (default robot)")
    parser.add_argument("--n-poses", type=int, default=80, help="poses (default 80)")
    parser.add_argument("--seed", type=int, default=1, help="seed (default 1)")
    parser.add_argument("--rate", type=float, default=250.0,
                        help="reference poses per second (default 250)")
    parser.add_argument("--latency-ms", type=float, default=30.0,
                        help="reference latency (default 30 ms)")
    parser.add_argument("--clock-offset-ms", type=float, default=250.0,
                        help="reference clock minus tracker clock (default 250 ms)")
    parser.add_argument("--sim-speed", type=float, default=1.0,
                        help="simulated seconds per wall second (default 1: real time)")
    parser.add_argument("--holdout", type=float, default=0.25,
                        help="held-out fraction of the calibrations (default 0.25)")


def _fit(ds, holdout):
    import warnings

    from openemt.calibrate import fit_reference
    from openemt.simulate import nominal_calibration

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        f = fit_reference(ds, nominal_calibration(ds.meta.get("preset", "concentric")),
                          holdout=holdout, seed=0)
    return f


def run(args) -> dict:
    from openemt.collect import CollectOptions, collect
    from openemt.io import read_dataset
    from openemt.simulate import simulate_reference

    load = list(os.getloadavg())
    with tempfile.TemporaryDirectory(prefix="openemt-bench-collect-") as folder:
        out = Path(folder) / "col.h5"
        t = time.perf_counter()
        col = collect(CollectOptions(
            output=out, source="sim", simulate_reference=args.kind, n_poses=args.n_poses,
            seed=args.seed, sim_rate=args.rate, sim_latency_ms=args.latency_ms,
            sim_clock_offset_ms=args.clock_offset_ms, sim_speed=args.sim_speed))
        wall = time.perf_counter() - t
        ds = read_dataset(out)
    cal = _fit(ds, args.holdout)
    base = _fit(simulate_reference("concentric", args.kind, args.n_poses, seed=args.seed),
                args.holdout)
    truth = col.simulated
    h, b = cal.holdout, base.holdout
    return {
        "kind": args.kind, "n_poses": col.n_poses, "n_poses_written": ds.n_samples,
        "n_poses_requested": args.n_poses, "seed": args.seed,
        "reference_rate_hz": args.rate, "latency_ms": args.latency_ms,
        "clock_offset_ms": args.clock_offset_ms, "sim_speed": args.sim_speed,
        "seconds_per_signal_second": col.seconds_per_signal_second,
        "time_offset_ms": col.time_offset_ms,
        "time_offset_true_ms": truth["time_offset_s"] * 1e3,
        "time_offset_error_ms": col.time_offset_error_ms,
        "offset_correlation": col.offset_correlation,
        "offset_confidence": col.offset_confidence,
        "dwells_found": col.dwells["found"], "dwells_true": truth["dwells_true"],
        "dwells": col.dwells, "pairing": col.pairing,
        "coverage": col.coverage,
        "collect_wall_s": wall, "tracker_seconds": col.tracker_seconds,
        "heldout_trans_rms_mm": h["trans_rms_mm"], "heldout_rot_rms_deg": h["rot_rms_deg"],
        "heldout_n": h["n"],
        "baseline_heldout_trans_rms_mm": b["trans_rms_mm"],
        "baseline_heldout_rot_rms_deg": b["rot_rms_deg"],
        "heldout_ratio": h["trans_rms_mm"] / b["trans_rms_mm"],
        "ill_conditioned": bool(cal.identifiability.get("ill_conditioned", False)),
        "load_average": load, "load_average_end": list(os.getloadavg()),
        "cpu_count": os.cpu_count(),
    }
