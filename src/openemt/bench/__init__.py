"""Benchmarks that print JSON; each is a module ``_<name>.py`` with ``add_arguments(parser)`` and
``run(args) -> dict``, dispatched by ``openemt bench <name>``.

Solver benchmarks:

- ``_noise``: Teixeira Silva et al. 2017 noise protocol for the pose solvers next to the Cramer-Rao bound.
- ``_speed``: poses per second on one core for each solver vs a per-pose scipy baseline.
"""

__all__: list[str] = []

#: ``openemt bench`` NAME (the module ``openemt.bench._NAME``) -> one-line help
BENCHMARKS = {
    "noise": "the noise protocol of Teixeira Silva et al. 2017: solver accuracy vs SNR next to the "
             "Cramer-Rao bound",
    "speed": "poses/s per solver on one core vs per-pose scipy least_squares",
    "demod": "demodulator realtime factor, accuracy, mains rejection",
    "track": "live pipeline latency and position noise vs the CRB",
    "metal": "metal scenes: held-out pose error with no compensation, environment terms, witness "
             "sensors and two bands, and the distortion level's ROC area",
    "correct": "output corrections on a simulated distortion: held-out vs in-sample",
    "hybrid": "EM vs optical tracker: AX = YB alignment and auto correction for 10-300 pairs",
    "collect": "collect on a simulated robot over OpenIGTLink, then calibrate: offset, dwells, "
               "held-out error vs the simulate path",
    "reference": "reference calibration per row weighting: held-out error against the simulation's "
                 "truth on the same poses",
    "fuzz": "fuzzed files for every reader and command and couplings for every solver",
    "compile": "numba compile time per kernel in a fresh process (empty cache) and cached",
    "batch": "openemt solve file to file: a 1500/s recording warm-started vs cold, and poses/s per "
             "LocalCluster worker count (--workers 1,2)",
}
