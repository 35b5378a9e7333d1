"""Calibration against simulated truth: parameter recovery and the cost of the dipole approximation."""

from __future__ import annotations

import numpy as np

from openemt.paper import dipole_cost, parameter_recovery


def test_exact_model_recovers_truth_within_standard_errors():
    r = parameter_recovery("concentric", mode="XYZ_all", snr_db=60.0, seed=0)
    assert r.rank == r.n_free == 41
    z = np.asarray(r.z)
    # 41 parameters: nearly all within 3 standard errors, none wildly off, and the standard
    # errors are of the right size (z has unit spread)
    assert r.fraction_within_3 >= 0.9
    assert r.max_abs_z < 4.0
    assert 0.6 < np.sqrt(np.mean(z ** 2)) < 1.6


def test_dipole_approximation_cost_and_octupole_gain():
    d = dipole_cost("concentric", seed=0)
    lo, hi = d.r_over_d
    assert 4.0 < lo < hi < 7.5
    dip, octu = d.dipole_calibrated, d.octupole_calibrated
    # the finite windings cost the dipole model tenths of a millimetre at these distances
    assert dip["trans_rms_mm"] > 0.2
    # the octupole terms give most of it back on held-out poses
    assert octu["trans_rms_mm"] < 0.4 * dip["trans_rms_mm"]
    assert octu["rot_rms_deg"] < 0.4 * dip["rot_rms_deg"]
    assert d.rms_residue["octupole"] < d.rms_residue["dipole"]


def test_improved_option_on_a_rotated_source_rig():
    """The --improved model on simulated ILEMT-style data of the rotated dipole-approximating
    source (mixed hemispheres, no rig errors): it runs unchanged and does not lose accuracy."""
    import warnings

    from openemt.calibrate import (
        fit,
        held_out_rows,
        improved_calibration,
        perturb_calibration,
        solve_held_out,
    )
    from openemt.simulate import simulate, truth_calibration

    ds = simulate("dipole-approx", "md,ld", snr_db=70.0, seed=1)
    start = perturb_calibration(truth_calibration("dipole-approx"), np.random.default_rng(0), mode="XYZ")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        xyz = fit(ds, start, "XYZ").calibration
        conc = fit(ds, xyz, "concentric").calibration
    test = ds.select(held_out_rows(ds))
    paper = solve_held_out(test, xyz, concentric_model=conc.model).summary
    imp = improved_calibration(ds, xyz, conc.model)
    got = imp.test(test).improved
    assert got["n_invalid"] == 0
    assert got["trans_rms_mm"] <= 1.05 * paper["trans_rms_mm"]
    assert got["rot_rms_deg"] <= 1.05 * paper["rot_rms_deg"]
