"""Complex couplings: the closed-form spectral norm of ``check_couplings`` (the top eigenvalue
of the Hermitian Gram matrix ``C^H C``) against numpy's SVD, and the signed-real values and
solver decisions it feeds."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from openemt.field import DipoleModel
from openemt.geometry import pose_from_vector
from openemt.solve import solve_kim18, solve_kuipers, solve_svd
from openemt.solve._closed_form import check_couplings

_parts = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False, width=64)


def _reference(C):
    """The previous implementation: numpy's SVD norm, NaN for non-finite samples."""
    norms = np.full(C.shape[0], np.nan)
    ok = np.all(np.isfinite(C), axis=(1, 2))
    if np.any(ok):
        norms[ok] = np.linalg.norm(C[ok], ord=2, axis=(1, 2))
    return np.where(C.real < 0, -1.0, 1.0) * np.abs(C), norms


@settings(max_examples=200, deadline=None)
@given(re=arrays(np.float64, (4, 3, 3), elements=_parts),
       im=arrays(np.float64, (4, 3, 3), elements=_parts),
       scale=st.sampled_from([1e-12, 1e-6, 1.0, 1e6]))
def test_complex_norm_3x3_matches_svd(re, im, scale):
    C = (re + 1j * im) * scale
    real, norms = check_couplings(C)
    ref_real, ref = _reference(C)
    np.testing.assert_array_equal(real, ref_real)
    top = np.abs(C).max(axis=(1, 2))
    # the spectral norm to rounding of the largest entry (exact zero for a zero matrix)
    np.testing.assert_allclose(norms, ref, rtol=1e-13, atol=0)
    assert np.all(np.abs(norms - ref) <= 1e-13 * 3 * top)


@pytest.mark.parametrize("shape", [(20, 8, 1), (20, 8, 2), (20, 8, 3), (20, 2, 3), (6, 3, 5)])
def test_complex_norm_other_shapes(shape):
    rng = np.random.default_rng(3)
    C = rng.normal(size=shape) + 1j * rng.normal(size=shape)
    C[1] = C[1, :, :1] * rng.normal(size=shape[2])     # rank one
    C[2] *= 0.0                                         # zero
    C[3] = C[3].real                                    # real phasors
    C[4, 0, 0] = complex(np.nan, 1.0)                   # not finite: NaN norm
    C[5, -1, -1] = complex(1.0, np.inf)
    real, norms = check_couplings(C)
    ref_real, ref = _reference(C)
    np.testing.assert_array_equal(real, ref_real)
    np.testing.assert_array_equal(np.isnan(norms), np.isnan(ref))
    ok = np.isfinite(ref)
    np.testing.assert_allclose(norms[ok], ref[ok], rtol=1e-13, atol=1e-300)


def test_closed_forms_same_decisions_on_complex_input(monkeypatch):
    """Solves of complex couplings: the same poses, statuses and residuals as with numpy's SVD
    norm (the previous implementation), on random poses incl. zero, rank-deficient and
    non-finite samples."""
    from openemt.solve import _closed_form

    rng = np.random.default_rng(7)
    n = 400
    model = DipoleModel.concentric()
    v = np.column_stack([rng.uniform(0.05, 0.5, n), rng.uniform(-0.3, 0.3, (n, 2)),
                         rng.uniform(-2, 2, (n, 3))])
    C = model.coupling(pose_from_vector(v)).astype(complex)
    C *= np.exp(1j * rng.normal(0.0, 0.05, C.shape))   # phase noise: |z| != Re z
    C[0] = 0.0
    C[1, :, 2] = 0.0
    C[2, 1, 1] = np.nan
    new = {f: f(C, model) for f in (solve_svd, solve_kuipers, solve_kim18)}
    monkeypatch.setattr(_closed_form, "check_couplings",
                        lambda c, *shape: tuple(np.ascontiguousarray(a) for a in _reference(c)))
    for f, got in new.items():
        ref = f(C, model)
        np.testing.assert_array_equal(got.status, ref.status)
        assert len(set(got.status.tolist())) > 1
        np.testing.assert_allclose(got.pose_vectors, ref.pose_vectors, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(got.residual, ref.residual, rtol=1e-12, atol=0)


@pytest.mark.parametrize("gap", [0.0, 1e-12, 1e-6, 1e-2, 0.2, 0.5, 0.9])
def test_complex_norm_close_and_distant_top_singular_values(gap):
    """Both branches of the eigenvalue: Newton's method where the top singular value stands
    apart, the trigonometric form where a second one is close to it (or equal)."""
    rng = np.random.default_rng(11)

    def unitary():
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)) + 1j * rng.normal(size=(3, 3)))
        return q

    C = np.stack([unitary() @ np.diag([1.0, 1.0 - gap, 0.3 * k]) @ unitary().conj().T
                  for k in range(3)]) * 1e-6
    _, norms = check_couplings(C)
    np.testing.assert_allclose(norms, np.linalg.norm(C, ord=2, axis=(1, 2)), rtol=1e-13)
