"""Solver fuzzing (bounded; the long run is ``openemt bench fuzz``): generated couplings of
every class (clean, noisy, scaled by 10**+-150, random, rank one, a sign flipped, NaN/inf, zero)
never crash a solver, and every pose a solver calls ``converged`` passes a reference check
computed without the solver."""

import json

import numpy as np
from openemt_fuzz import _fuzzsolve

from openemt.cli import main
from openemt.simulate import truth_calibration


def test_reference_check_can_fail():
    model = truth_calibration("dipole-approx").model
    rng = np.random.default_rng(3)
    C, P, cls = _fuzzsolve.make_samples(model, 200, rng)
    clean = cls == _fuzzsolve.CLASSES.index("clean")
    assert _fuzzsolve.reference_check(model, C[clean], P[clean], P[clean], cls[clean]).all()
    moved = P[clean].copy()
    moved[:, 0, 3] += 0.002  # 2 mm off
    assert not _fuzzsolve.reference_check(model, C[clean], moved, P[clean], cls[clean]).any()


def test_no_crash_and_no_wrong_converged_pose():
    out = _fuzzsolve.fuzz_solvers(8000, seed=0)
    assert out["n_samples"] == 8000
    assert out["crashes"] == 0, out["examples"]
    assert out["wrong_converged"] == 0, out["examples"]
    lm = out["by_solver"]["lm/concentric"]
    # the rule is not so strict that it rejects good data
    assert lm["clean"]["converged"] == lm["clean"]["n"] > 0
    for bad in ("random", "rank1", "nonfinite", "zero"):
        assert lm[bad]["converged"] == 0


def test_bench_fuzz_command(tmp_path, capsys):
    code = main(["bench", "fuzz", "--reader-cases", "18", "--cli-cases", "7",
                 "--solver-samples", "400", "--live-cases", "0", "--writer-rounds", "0",
                 "--hostile-cases", "2", "--navigate-cases", "3", "--reference-cases", "1", "1",
                 "0", "--metal-cases", "4", "--json", "--quiet"])
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    assert out["reader_cases"] == 18 and out["cli_cases"] == 7 and out["solver_samples"] == 400
    assert out["hostile_live"]["cases"] == 0     # tests/test_live_fuzz.py runs live cases
    assert out["hostile_readers"]["runs"] == out["hostile_readers"]["held"] == 2
    assert out["navigate"]["cases"] == 3      # tests/test_fuzz_navigate.py runs more
    assert out["metal"]["cases"] == 4         # tests/test_fuzz_metal.py runs more
    assert out["findings"] == 0, out["examples"]
    assert sum(sum(c.values()) for c in out["readers"].values()) == 18
