"""``openemt bench compile``: compile time of the numba kernels on first use, and cached loads.

The kernels are compiled the first time a process calls them and cached on disk
(``cache=True``); a fresh installation pays the compilation once. This benchmark starts a fresh
Python process with an empty numba cache (``NUMBA_CACHE_DIR`` set to a new temporary folder),
times the first call of each main kernel there (each call compiles what it needs that earlier
calls did not), then starts a second process on the now filled cache and times the same calls
(loading from the cache). Reported in seconds per kernel and in total (wall clock and process
CPU time), with the import time of the package.

Kernels, in call order: ``dipole_coupling`` (``DipoleModel.coupling``), ``dipole_jacobians``
(``coupling_jacobians``), ``closed_form`` (``solve_kim18``; the three closed forms share one
kernel), ``lm_batch`` (``solve_lm`` from given starts), ``lm_track`` (``solve_lm`` tracking),
``lm_5dof`` (``solve_lm`` with a single-coil sensor: the same compiled kernel, so near zero).

``per_kernel`` lists every kernel the commands announce (``openemt._compile_notice``: solver,
live and finite-coil groups, the induced dipoles' and the LM kernels' board specialisation,
``lm_batch@board``), each compiled by the commands' own warm-up call in list order,
with its compile seconds in the empty cache (helpers shared with an earlier kernel are counted
there) and its load seconds from the filled one.

With ``--commands``, the commands users wait on, each a fresh ``openemt`` process whose CPU
seconds (user + system, of the process and its children) and wall seconds are reported, all on
one new numba cache: the first ``openemt demo`` (empty cache) and a second one, ``openemt
track --source sim`` twice (whether each printed the compile notice), ``openemt info`` of the
demo's dataset, ``openemt calibrate --mode planar`` on the README's simulated grid (a second,
warm run is the one timed), and ``openemt reproduce table2 --improved`` on the bundled ILEMT
recording.
"""

from __future__ import annotations

import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time

from ._timing import best_time

__all__ = ["KERNELS", "add_arguments", "run"]

KERNELS = ("dipole_coupling", "dipole_jacobians", "closed_form", "lm_batch", "lm_track",
           "lm_5dof")


def add_arguments(parser) -> None:
    parser.add_argument("--keep-cache", default=None, metavar="DIR",
                        help="use this (new or empty) folder as the numba cache and keep it "
                             "(default: a temporary folder, removed afterwards)")
    parser.add_argument("--commands", action="store_true",
                        help="also time the commands users wait on in fresh processes (first "
                             "demo, second track, info, planar calibrate, reproduce table2 "
                             "--improved; minutes)")


def _child() -> dict:
    """The measurement inside one process: import, then the first call of every kernel."""
    t0 = time.perf_counter()
    import numpy as np

    from openemt.field import DipoleModel, coupling_jacobians
    from openemt.geometry import pose_from_vector
    from openemt.solve import solve_kim18, solve_lm

    import_s = time.perf_counter() - t0
    rng = np.random.default_rng(0)
    v = np.hstack([rng.uniform(-0.05, 0.05, (20, 3)) + [0.3, 0.0, 0.0],
                   rng.normal(scale=0.5, size=(20, 3))])
    P = pose_from_vector(v)
    model = DipoleModel(np.full((3, 3), 0.01) * np.eye(3), np.eye(3), np.zeros((3, 3)),
                        np.eye(3))
    conc = DipoleModel.concentric()
    five = DipoleModel(rng.normal(scale=0.02, size=(3, 6)), rng.normal(size=(3, 6)),
                       np.zeros((3, 1)), np.array([[0.0], [0.0], [1.0]]))
    data = {}
    calls = {
        "dipole_coupling": lambda: data.update(C=model.coupling(P), C5=five.coupling(P)),
        "dipole_jacobians": lambda: coupling_jacobians(model, P),
        "closed_form": lambda: solve_kim18(data["C"], conc),
        "lm_batch": lambda: solve_lm(data["C"], model, initial=v),
        "lm_track": lambda: solve_lm(data["C"], model, initial="track"),
        "lm_5dof": lambda: solve_lm(data["C5"], five, initial=v),
    }
    times = {}
    cpu = {}
    for name in KERNELS:
        cpu[name], times[name], _ = best_time(calls[name], 1)
    return {"import_s": import_s, "kernels_s": times, "total_s": sum(times.values()),
            "kernels_cpu_s": cpu, "total_cpu_s": sum(cpu.values())}


def _child_per_kernel() -> dict:
    """Every announced kernel compiled (or loaded) through the commands' warm-up, one by one."""
    from openemt._compile_notice import (
        BOARD_LM_KERNELS,
        COLD_START_KERNELS,
        INDUCED_DIPOLE_KERNELS,
        LIVE_KERNELS,
        PLANAR_KERNELS,
        SOLVER_KERNELS,
        compile_kernels,
    )

    out = {}
    for spec in dict.fromkeys(SOLVER_KERNELS + COLD_START_KERNELS + LIVE_KERNELS
                              + PLANAR_KERNELS + INDUCED_DIPOLE_KERNELS + BOARD_LM_KERNELS):
        cpu, wall, _ = best_time(lambda spec=spec: compile_kernels([spec]), 1)
        out[spec] = {"s": round(wall, 3), "cpu_s": round(cpu, 3)}
    return out


def _fresh(argv, cache_dir: str, what: str, cwd=None):
    """Run ``argv`` in a fresh process on numba cache ``cache_dir``: (its completed process,
    wall seconds); a failure is a RuntimeError naming ``what``."""
    env = dict(os.environ, NUMBA_CACHE_DIR=cache_dir)
    t = time.perf_counter()
    out = subprocess.run(argv, env=env, cwd=cwd, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t
    if out.returncode != 0:
        tail = " ".join(out.stderr.strip().splitlines()[-1:])
        raise RuntimeError(f"{what} failed (exit {out.returncode}): {tail}")
    return out, wall


def _process(cache_dir: str, what: str = "kernels") -> dict:
    out, wall = _fresh([sys.executable, "-m", "openemt.bench._compile", what], cache_dir,
                       "the measuring process")
    res = json.loads(out.stdout.strip().splitlines()[-1])
    res["process_wall_s"] = wall
    return res


def _command(argv, cache_dir: str, cwd: str) -> dict:
    """Run ``openemt *argv`` in a fresh process on numba cache ``cache_dir``: its CPU seconds
    (user + system, with its children), wall seconds and whether it printed a compile line."""
    code = "import sys; from openemt.cli import main; sys.exit(main(sys.argv[1:]))"
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    out, wall = _fresh([sys.executable, "-c", code, *map(str, argv)], cache_dir,
                       f"openemt {' '.join(map(str, argv[:2]))}", cwd)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"cpu_s": round(cpu, 3), "wall_s": round(wall, 3),
            "compile_notice": any(line.startswith("compiling ")
                                  for line in out.stderr.splitlines())}


def _commands() -> dict:
    """The commands users wait on (module docstring), timed on one new numba cache."""
    from ..datasets import path as dataset_path

    work = tempfile.mkdtemp(prefix="openemt-bench-commands-")
    cache = os.path.join(work, "numba-cache")
    os.makedirs(cache)
    ilemt = dataset_path("cal_9_15_premo_cmu")

    def run_(*argv):
        return _command(argv, cache, work)

    try:
        res = {"first_demo": run_("demo", "-o", "demo", "--json"),
               "cached_demo": run_("demo", "-o", "demo2", "--json")}
        track = ("track", "--source", "sim", "--duration", "1", "--no-igtl", "--fast", "--json")
        res["first_track"] = run_(*track)
        res["second_track"] = run_(*track)
        res["info"] = run_("info", os.path.join("demo", "test_data.h5"), "--json")
        run_("simulate", "--preset", "anser", "--source-fixtures", "YoutZup",
             "--sensor-fixtures", "YoutZup", "--snr-db", "80", "--seed", "1", "-o", "grid.h5",
             "--json")
        planar = ("calibrate", "grid.h5", "--mode", "planar", "--holdout", "checkerboard",
                  "-o", "board_cal.json", "--json")
        res["first_planar_calibrate"] = run_(*planar)
        res["planar_calibrate"] = run_(*planar)
        res["reproduce_table2_improved"] = run_("reproduce", "table2", ilemt, "--improved",
                                                "--json")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    keys = {"first_demo_cpu_s": res["first_demo"]["cpu_s"],
            "first_demo_wall_s": res["first_demo"]["wall_s"],
            "cached_demo_cpu_s": res["cached_demo"]["cpu_s"],
            "second_track_compile_notice": res["second_track"]["compile_notice"],
            "info_cpu_s": res["info"]["cpu_s"],
            "planar_calibrate_warm_cpu_s": res["planar_calibrate"]["cpu_s"],
            "reproduce_table2_improved_cpu_s": res["reproduce_table2_improved"]["cpu_s"]}
    return {**keys, "commands": res}


def run(args) -> dict:
    """Compile (empty cache) and cached times of the main kernels, each in a fresh process."""
    import numba

    keep = args.keep_cache is not None
    cache = args.keep_cache if keep else tempfile.mkdtemp(prefix="openemt-numba-cache-")
    if keep:
        os.makedirs(cache, exist_ok=True)
        if os.listdir(cache):
            from .._errors import InputError

            raise InputError(f"expected a new or empty folder for --keep-cache, got {cache!r} "
                             f"with files in it")
    per_cache = tempfile.mkdtemp(prefix="openemt-numba-cache-")
    try:
        first = _process(cache)
        cached = _process(cache)
        per_first = _process(per_cache, "per_kernel")
        per_cached = _process(per_cache, "per_kernel")
    finally:
        if not keep:
            shutil.rmtree(cache, ignore_errors=True)
        shutil.rmtree(per_cache, ignore_errors=True)
    per_kernel = {spec: {"compile_s": v["s"], "compile_cpu_s": v["cpu_s"],
                         "cached_s": per_cached[spec]["s"]}
                  for spec, v in per_first.items() if spec != "process_wall_s"}
    commands = _commands() if getattr(args, "commands", False) else {}
    return {**commands, "numba_version": numba.__version__, "python": sys.version.split()[0],
            "cpu_count": os.cpu_count(), "kernels": list(KERNELS),
            "first_use": first, "cached": cached,
            "compile_total_s": first["total_s"], "compile_total_cpu_s": first["total_cpu_s"],
            "cached_total_s": cached["total_s"],
            "per_kernel": per_kernel,
            "per_kernel_compile_cpu_s": round(sum(v["compile_cpu_s"]
                                                  for v in per_kernel.values()), 3),
            "cache_dir": cache if keep else "temporary (removed)",
            "note": "seconds in each fresh process (*_s wall clock, *_cpu_s process CPU time, "
                    "which other load on the machine does not inflate); first_use compiles "
                    "into an empty NUMBA_CACHE_DIR, cached loads from it"}


if __name__ == "__main__":
    print(json.dumps(_child_per_kernel() if sys.argv[1:] == ["per_kernel"] else _child()))
