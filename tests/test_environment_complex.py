"""Induced dipoles with a complex response per carrier (a phase per dipole and source coil):
the model, its Jacobians, the fit to complex couplings and the calibration file."""

from __future__ import annotations

import numpy as np
import pytest
from _numdiff import central_differences
from test_calibrate import truth_model
from test_environment import _poses, _terms

from openemt._errors import InputError
from openemt.field import EnvironmentModel, EnvironmentTerms, numeric_jacobians
from openemt.io import Calibration, read_calibration, write_calibration
from openemt.solve import prepare


def _complex_terms(rng, model, n_dip=2):
    t = _terms(rng, model, n_dip)
    return EnvironmentTerms(t.positions, t.moments, t.gain_beta, t.offset,
                            rng.uniform(-1.2, 1.2, (n_dip, model.n_source)))


def test_complex_environment_model_jacobians_are_analytic():
    rng = np.random.default_rng(3)
    base = truth_model(rng)
    m = EnvironmentModel(base, _complex_terms(rng, base))
    P = _poses(rng, 4)
    a, b = m.jacobians(P), numeric_jacobians(m, P)
    for k in ("d_translation", "d_rotation", "d_params"):
        x, y = getattr(a, k), getattr(b, k)
        assert np.abs(x - y).max() < 1e-6 * np.abs(y).max(), k
    # the quadrature's gradient in the terms, against central differences
    Q, dQ = m.quadrature_jacobians(P)
    np.testing.assert_allclose(Q, m.complex_coupling(P).imag, rtol=0, atol=1e-15)
    num = central_differences(
        lambda v: EnvironmentModel(base, m.terms.with_vector(v)).complex_coupling(P).imag,
        m.terms.vector(), rel_step=1e-7)
    assert np.abs(dQ - num).max() < 1e-6 * np.abs(num).max()
    # the real part is the in-phase model: moments times cos(phase)
    inph = EnvironmentTerms(m.terms.positions, m.terms.in_phase_moments(), m.terms.gain_beta,
                            m.terms.offset)
    np.testing.assert_allclose(m.coupling(P), EnvironmentModel(base, inph).coupling(P),
                               rtol=0, atol=1e-15)


def test_terms_without_phases_are_the_real_model_bit_for_bit():
    rng = np.random.default_rng(4)
    base = truth_model(rng)
    t = _terms(rng, base, 2)
    m = EnvironmentModel(base, t)
    P = _poses(rng, 5)
    C = m.complex_coupling(P)
    assert np.array_equal(C.real, m.coupling(P)) and not np.any(C.imag)
    back = EnvironmentTerms.from_dict(t.to_dict())
    assert back.phases is None and "phases_rad" not in t.to_dict()["induced_dipoles"][0]
    assert np.array_equal(EnvironmentModel(base, back).coupling(P), m.coupling(P))
    # zero phases: the same in-phase prediction and Jacobians as without
    z = t.with_phases()
    a, b = EnvironmentModel(base, z).jacobians(P), m.jacobians(P)
    assert np.array_equal(a.C, b.C) and np.array_equal(a.d_translation, b.d_translation)


def _sphere_scene():
    """Two conducting spheres beside and under the rig's volume: their responses are a
    complex scalar times the source field per carrier, what a phased induced dipole is."""
    from openemt.simulate import MetalObject, MetalScene, rig_volume

    lo, hi = rig_volume()
    return MetalScene((MetalObject("sphere", "stainless_steel", (hi[0] + 0.06, 0.24, 0.0),
                                   radius=0.03),
                       MetalObject("sphere", "aluminium", (0.0, 0.24, lo[2] - 0.07),
                                   radius=0.025)))


def _metal_couplings(rng, model, scene, n, noise):
    from openemt.geometry import pose_from_vector
    from openemt.simulate import rig_volume

    lo, hi = rig_volume()
    P = pose_from_vector(np.c_[rng.uniform(lo, hi, (n, 3)), rng.normal(0, 1.0, (n, 3))])
    C0 = model.coupling(P)
    C = C0 + scene.induced_couplings(model, P, np.array([7500.0, 10500.0, 13500.0]))
    return P, C + noise * (rng.normal(size=C.shape) + 1j * rng.normal(size=C.shape))


def test_fit_to_complex_couplings_reproduces_them_to_the_noise():
    """Complex (phase-calibrated) couplings of a simulated metal scene: the fitted terms
    carry a phase per dipole and carrier and predict the in-phase and the quadrature parts of
    poses they were not fitted on to the noise; fitted to the real part alone they predict no
    quadrature."""
    from openemt.calibrate import fit_environment
    from openemt.simulate import truth_calibration

    rng = np.random.default_rng(7)
    model = truth_calibration("dipole-approx").model
    scene = _sphere_scene()
    noise = 1e-6 * 0.03                       # per part, ~1e-6 of the largest coupling
    P, C = _metal_couplings(rng, model, scene, 80, noise)
    Q, CQ = _metal_couplings(rng, model, scene, 40, noise)
    assert np.abs(C.imag).max() > 1e3 * noise            # the quadrature is well measured
    f = fit_environment(model, P, C, dipoles=2)
    assert f.terms.phases is not None and f.terms.phases.shape == (2, 3)
    # the phases differ per carrier (eddy currents lag less at higher frequency)
    assert np.ptp(f.terms.phases, axis=1).min() > 0.01
    pred = f.model.complex_coupling(Q)
    for part in ("real", "imag"):
        r = getattr(CQ, part) - getattr(pred, part)
        assert np.sqrt(np.mean(r ** 2)) < 1.5 * noise, part
    assert f.rms < 1.5 * np.sqrt(2) * noise < 1e-3 * f.rms_base
    # the real part alone: real moments, no quadrature predicted (it stays in the residual)
    g = fit_environment(model, P, C.real, dipoles=2)
    assert g.terms.phases is None and not np.any(g.model.complex_coupling(Q).imag)
    assert np.sqrt(np.mean(CQ.imag ** 2)) > 100 * noise
    # complex couplings without quadrature are fitted as the real ones were
    h = fit_environment(model, P, C.real + 0j, dipoles=2)
    assert h.terms.phases is None
    assert np.array_equal(h.terms.vector(), fit_environment(model, P, C.real.copy(),
                                                            dipoles=2).terms.vector())


def test_calibration_file_carries_the_phases(tmp_path):
    rng = np.random.default_rng(8)
    base = truth_model(rng)
    terms = _complex_terms(rng, base, 1)
    cal = Calibration(model=base, mode="XYZ", extra={"environment": terms.to_dict()})
    path = tmp_path / "cal.json"
    write_calibration(cal, path)
    back = read_calibration(path)
    np.testing.assert_array_equal(back.environment.phases, terms.phases)
    P = _poses(rng, 6)
    np.testing.assert_array_equal(back.coupling_model.complex_coupling(P),
                                  EnvironmentModel(base, terms).complex_coupling(P))
    res = prepare(back)(back.coupling_model.coupling(P))
    np.testing.assert_allclose(res.poses[:, :3, 3], P[:, :3, 3], rtol=0, atol=1e-9)
    doc = terms.to_dict()
    del doc["induced_dipoles"][0]["phases_rad"]
    assert EnvironmentTerms.from_dict(doc).phases is None
    doc["induced_dipoles"][0]["phases_rad"] = [0.1, 0.2]
    with pytest.raises(InputError, match="phases of shape"):
        EnvironmentTerms.from_dict(doc)
