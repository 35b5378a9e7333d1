"""``openemt bench NAME``: benchmarks that print JSON (speed and accuracy targets live here).

Each benchmark is a module ``openemt.bench._<name>`` with ``add_arguments(parser)`` and
``run(args) -> dict``; the dict is the JSON summary.
"""

from __future__ import annotations

import importlib
import json

from . import command_help
from ._common import add_common, emit, to_jsonable

#: name -> (module, one-line help)
BENCHMARKS = {
    "noise": ("openemt.bench._noise",
              "the noise protocol of Teixeira Silva et al. 2017: solver accuracy vs SNR next to the Cramer-Rao bound"),
    "speed": ("openemt.bench._speed",
              "poses/s per solver on one core vs per-pose scipy least_squares"),
    "demod": ("openemt.bench._demod", "demodulator realtime factor, accuracy, mains rejection"),
    "track": ("openemt.bench._track", "live pipeline latency and position noise vs the CRB"),
    "correct": ("openemt.bench._correct",
                "output corrections on a simulated distortion: held-out vs in-sample"),
    "hybrid": ("openemt.bench._hybrid",
               "EM vs optical tracker: AX = YB alignment and auto correction for 10-300 pairs"),
    "collect": ("openemt.bench._collect",
                "collect on a simulated robot over OpenIGTLink, then calibrate: offset, dwells, held-out error vs the simulate path"),
    "reference": ("openemt.bench._reference",
                  "reference calibration per row weighting: held-out error against the "
                  "simulation's truth on the same poses"),
    "fuzz": ("openemt.bench._fuzz",
             "fuzzed files for every reader and command and couplings for every solver"),
    "compile": ("openemt.bench._compile",
                "numba compile time per kernel in a fresh process (empty cache) and cached"),
    "batch": ("openemt.bench._batch",
              "openemt solve file to file: a 1500/s recording warm-started vs cold, and "
              "poses/s per LocalCluster worker count (--workers 1,2)"),
}


def register(sub) -> None:
    p = sub.add_parser("bench", help=command_help("bench"),
                       description=__doc__.splitlines()[0])
    bsub = p.add_subparsers(dest="bench", metavar="NAME")
    bsub.required = True
    for name, (module, help_) in BENCHMARKS.items():
        bp = bsub.add_parser(name, help=help_)
        add_common(bp)
        mod = importlib.import_module(module)
        mod.add_arguments(bp)
        bp.set_defaults(func=_runner(mod))


def _runner(mod):
    def run(args) -> int:
        summary = mod.run(args)
        # without --json the same summary goes to stderr, readable
        human = json.dumps(to_jsonable(summary), indent=2).splitlines()
        emit(args, summary, human)
        return 0

    return run
