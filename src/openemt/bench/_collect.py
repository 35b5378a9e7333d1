"""``openemt bench collect``: the collect-then-calibrate path on a simulated robot, against the
same calibration on ``openemt simulate --reference`` data.

Runs, each as its own ``openemt`` process in a temporary folder:

1. ``openemt collect --source sim --simulate-reference KIND --n-poses N --seed S`` (the
   simulated tracker on the robot's dwell motion; the robot served by an OpenIGTLink server at
   ``--rate`` Hz with ``--latency-ms`` and ``--clock-offset-ms``; ``--sim-speed`` simulated
   seconds per wall second, 1 = real time);
2. ``openemt calibrate col.h5 --mode reference --holdout H --seed 0``;
3. ``openemt simulate --reference KIND --n-poses N --seed S`` and the same calibration: the
   baseline.

Keys
----
time_offset_ms, time_offset_true_ms, time_offset_error_ms
    The offset collect measured (reference clock minus tracker clock, by cross-correlation of
    motion), the true one (latency + clock offset) and the difference. Target |error| < 5 ms.
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

import json
import os
import subprocess
import sys
import tempfile
import time

__all__ = ["add_arguments", "run"]

_CLI = "import sys\nfrom openemt.cli import main\nsys.exit(main(sys.argv[1:]))\n"


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


def _openemt(folder, *argv) -> dict:
    r = subprocess.run([sys.executable, "-c", _CLI, *map(str, argv), "--json", "--quiet"],
                       cwd=folder, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"openemt {' '.join(map(str, argv))} failed ({r.returncode}): "
                           f"{r.stderr.strip()[-2000:]}")
    return json.loads(r.stdout)


def run(args) -> dict:
    load = list(os.getloadavg())
    with tempfile.TemporaryDirectory(prefix="openemt-bench-collect-") as folder:
        t = time.perf_counter()
        col = _openemt(folder, "collect", "--source", "sim", "--simulate-reference", args.kind,
                       "--n-poses", args.n_poses, "--seed", args.seed, "--sim-rate", args.rate,
                       "--sim-latency-ms", args.latency_ms, "--sim-clock-offset-ms",
                       args.clock_offset_ms, "--sim-speed", args.sim_speed, "-o", "col.h5")
        wall = time.perf_counter() - t
        cal = _openemt(folder, "calibrate", "col.h5", "--mode", "reference", "--holdout",
                       args.holdout, "--seed", 0)
        _openemt(folder, "simulate", "--reference", args.kind, "--n-poses", args.n_poses,
                 "--seed", args.seed, "-o", "sim.h5")
        base = _openemt(folder, "calibrate", "sim.h5", "--mode", "reference", "--holdout",
                        args.holdout, "--seed", 0)
    truth = col["simulated"]
    h, b = cal["holdout"], base["holdout"]
    return {
        "kind": args.kind, "n_poses": col["n_poses"], "seed": args.seed,
        "reference_rate_hz": args.rate, "latency_ms": args.latency_ms,
        "clock_offset_ms": args.clock_offset_ms, "sim_speed": args.sim_speed,
        "time_offset_ms": col["time_offset_ms"],
        "time_offset_true_ms": truth["time_offset_s"] * 1e3,
        "time_offset_error_ms": col["time_offset_error_ms"],
        "offset_correlation": col["offset_correlation"],
        "dwells_found": col["dwells"]["found"], "dwells_true": truth["dwells_true"],
        "dwells": col["dwells"],
        "coverage": col["coverage"],
        "collect_wall_s": wall, "tracker_seconds": col["tracker_seconds"],
        "heldout_trans_rms_mm": h["trans_rms_mm"], "heldout_rot_rms_deg": h["rot_rms_deg"],
        "heldout_n": h["n"],
        "baseline_heldout_trans_rms_mm": b["trans_rms_mm"],
        "baseline_heldout_rot_rms_deg": b["rot_rms_deg"],
        "heldout_ratio": h["trans_rms_mm"] / b["trans_rms_mm"],
        "ill_conditioned": cal["ill_conditioned"],
        "load_average": load, "cpu_count": os.cpu_count(),
    }
