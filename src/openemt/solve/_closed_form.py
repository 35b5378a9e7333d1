"""Closed-form pose solutions for concentric three-axis dipole sources and sensors.

For concentric coils the dipole model (MacLachlan et al. 2025, eqs. 3-5, ``openemt.field``) reduces to

    C = (g / d^3) M_so^T H R M_se,      H = 3 u u^T - I,

with ``u`` the unit position direction, ``d`` the distance, ``R`` the sensor rotation and ``g``
the model gain. Whitening with the known moments gives ``C0 = M_so^-T C M_se^-1 = k H R`` with
``k = g / d^3``; ``H`` has eigenvalues (2, -1, -1) so the singular values of ``C0`` are
``(2k, k, k)`` and its first left singular vector is ``+/-u``. Three solvers invert this:

``svd``
    Teixeira Silva et al. 2017: distance from the three singular values (mean of the
    three distance estimates of their eq. 25), direction from the first right singular vector of
    ``T = C0^T`` (= first left singular vector of ``C0``), and orientation from the Wahba
    problem ``min ||k R - H^-1 C0||`` solved by SVD with the determinant correction (Markley).
``kuipers``
    Kuipers' closed form (the benchmark of Teixeira Silva et al. 2017): distance from the invariant
    ``||C0||_F^2 = 6 k^2``, direction cosines from ``C0 C0^T = k^2 (I + 3 u u^T)`` (magnitudes
    from the diagonal, relative signs from the off-diagonal terms), orientation matrix
    ``H^-1 C0 / k`` read out as Z-Y-X Euler angles element by element (no orthogonalisation).
``kim18``
    Kim, Song & Park 2018 as ILEMT applies it to calibrated concentric models (docs/paper-procedure.md#kim18): ``Y = C0^T = U S V^T``, ``R = V diag(1, -1, -1) U^T``,
    ``d = (6 g / (2 s1 + s2 + s3))^(1/3)``, ``p = +/- d V[:, 0]``. Non-orthogonal moments and
    unequal gains enter through the whitening.

Each resolves the +/- ambiguity with the hemisphere direction ``n``: the solution with
``p . n >= 0`` is returned.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .._errors import InputError
from ..field import DipoleModel, check_dipole_model
from ..field._dipole_kernel import concentric_eval
from ._hemisphere import DEFAULT_HEMISPHERE, hemisphere_vectors
from ._linalg import (
    det33,
    dominant_eigvec,
    euler_zyx_matrix,
    herm3_lambda_max,
    quat_matrix,
    rotvec_from_matrix,
    rotvec_from_quat,
    store_nan_pose,
    store_pose,
    svd3,
    sym3_eigvals,
    sym3_lambda_max,
    wahba_quat,
)
from ._model_kernels import model_eval
from ._packing import (
    O_RANK_TOL,
    pack_model,
    pack_options,
    unpack_model,
)
from ._result import ST_CONVERGED, ST_INVALID_INPUT, SolveResult
from ._validity import (
    MAX_RANGE_M,
    MAX_RELATIVE_RESIDUAL,
    check_validity_options,
    classify,
)

__all__ = ["check_couplings", "closed_form_one", "closed_form_scratch", "complex_spectral_norm",
           "new_outputs",
           "normalise_coupling", "residual_norms", "residuals_at", "result_from_outputs",
           "solve_kim18", "solve_kuipers", "solve_svd", "spectral_norms", "whitening"]

#: closed-form method codes of the compiled kernel
CF_SVD = 0
CF_KUIPERS = 1
CF_KIM18 = 2
_METHODS = {"svd": CF_SVD, "kuipers": CF_KUIPERS, "kim18": CF_KIM18}

#: Whitened couplings with ``s3 < RANK_TOL * s1`` are rank deficient (INVALID_INPUT).
RANK_TOL = 1e-6
#: A closed-form direction with ``|u . n| <= AMBIGUITY_TOL`` lies on the hemisphere plane.
AMBIGUITY_TOL = 1e-6
# outcomes of the fast concentric path
_FAST_USE_SVD = 0
_FAST_DONE = 1
_FAST_RANK_DEFICIENT = 2


# ------------------------------------------------------------------------------------------
# validation shared with the LM solver
# ------------------------------------------------------------------------------------------
def check_couplings(couplings, n_source=None, n_sensor=None) -> tuple[np.ndarray, np.ndarray]:
    """Validate couplings ``(N, n_so, n_se)``; return signed-real float64 values and the spectral
    norms to normalise residuals with.

    Complex input is taken as measured phasors: the target is ``sign(Re z) |z|`` and the norm is
    the spectral norm of the complex matrix, as ILEMT does (docs/paper-procedure.md#iterative-solution). For real input
    the norms are returned as -1 and computed inside the compiled kernels.
    """
    C = np.asarray(couplings)
    if C.dtype.kind not in "iufc":
        raise TypeError(f"expected numeric `couplings`, got dtype {C.dtype}")
    if C.ndim != 3:
        raise InputError(f"expected `couplings` of shape (N, n_source, n_sensor), got {C.shape}")
    if n_source is not None and (C.shape[1], C.shape[2]) != (n_source, n_sensor):
        raise InputError(f"expected `couplings` of shape (N, {n_source}, {n_sensor}) for this "
                         f"model, got {C.shape}")
    if C.dtype.kind == "c":
        C = np.ascontiguousarray(C, dtype=np.complex128)
        real = np.abs(C)                     # numpy's |z|; the kernel negates where Re z < 0
        norms = np.empty(C.shape[0])
        _complex_norms(C, real, norms)
        # sensors of more than 3 coils, close top singular values: numpy's SVD
        rest = np.flatnonzero(norms < 0)
        if rest.size:
            norms[rest] = np.linalg.norm(C[rest], ord=2, axis=(1, 2))
        return real, norms
    return (np.ascontiguousarray(C, dtype=np.float64),
            np.full(C.shape[0], -1.0))


@njit(inline="always")
def complex_spectral_norm(C, G):
    """Spectral norm of a complex matrix ``C`` (n_so, n_se) with ``n_se <= 3``: the square root
    of the top eigenvalue of the Hermitian Gram matrix ``G = C^H C`` (n_se, n_se scratch; of
    ``C`` divided by its largest real or imaginary part where that is outside 1e-40..1e40,
    multiplied back after): directly for one or two columns, by the trigonometric formula for
    three (:func:`~openemt.solve._linalg.herm3_lambda_max`). -1 for more columns or a second
    singular value close to the first (the caller computes those by SVD)."""
    n_so, n_se = C.shape
    if n_se > 3:
        return -1.0
    m = 0.0                      # the largest part: outside 1e-40..1e40 the Gram matrix is
    for i in range(n_so):        # formed of C / m (its eigenvalue formula has 3rd powers)
        for a in range(n_se):
            m = max(m, abs(C[i, a].real), abs(C[i, a].imag))
    if not m > 0.0:
        return 0.0
    scaled = not (1e-40 < m < 1e40)
    if not scaled:
        m = 1.0
    for a in range(n_se):
        for b in range(a, n_se):
            acc = 0j
            for i in range(n_so):
                x = C[i, a]
                y = C[i, b]
                if scaled:
                    x = complex(x.real / m, x.imag / m)
                    y = complex(y.real / m, y.imag / m)
                acc += np.conj(x) * y
            G[a, b] = acc
    if n_se == 1:
        lam = G[0, 0].real
    elif n_se == 2:
        h = 0.5 * (G[0, 0].real - G[1, 1].real)
        lam = 0.5 * (G[0, 0].real + G[1, 1].real) + np.sqrt(
            h * h + G[0, 1].real ** 2 + G[0, 1].imag ** 2)
    else:
        lam = herm3_lambda_max(G[0, 0].real, G[1, 1].real, G[2, 2].real, G[0, 1], G[0, 2],
                               G[1, 2])
        if lam < 0.0:
            return -1.0              # a close second singular value: the caller's SVD
    return np.sqrt(max(lam, 0.0)) * m


@njit(cache=True)
def _complex_norms(C, real, norms):
    """The complex spectral norms of couplings ``C`` (N, n_so, n_se) into ``norms`` (NaN for a
    sample with a non-finite entry, -1 where :func:`complex_spectral_norm` has no closed
    form); ``real`` (``|C|`` on entry) negated where ``Re C < 0``: the signed-real values."""
    G = np.empty((C.shape[2], C.shape[2]), np.complex128)
    for k in range(C.shape[0]):
        finite = True
        for i in range(C.shape[1]):
            for j in range(C.shape[2]):
                z = C[k, i, j]
                if z.real < 0:
                    real[k, i, j] = -real[k, i, j]
                finite = finite and np.isfinite(z.real) and np.isfinite(z.imag)
        norms[k] = complex_spectral_norm(C[k], G) if finite else np.nan


@njit(inline="always")
def _spectral_norm33(C):
    """Spectral norm of a real 3x3 matrix: square root of the top eigenvalue of ``C^T C``."""
    c00, c01, c02 = C[0, 0], C[0, 1], C[0, 2]
    c10, c11, c12 = C[1, 0], C[1, 1], C[1, 2]
    c20, c21, c22 = C[2, 0], C[2, 1], C[2, 2]
    lam = sym3_lambda_max(c00 * c00 + c10 * c10 + c20 * c20,
                           c00 * c01 + c10 * c11 + c20 * c21,
                           c00 * c02 + c10 * c12 + c20 * c22,
                           c01 * c01 + c11 * c11 + c21 * c21,
                           c01 * c02 + c11 * c12 + c21 * c22,
                           c02 * c02 + c12 * c12 + c22 * c22)
    return np.sqrt(max(lam, 0.0))


@njit(cache=True)
def spectral_norm(C, G):
    """Spectral norm of a real matrix ``C`` (n_so, n_se); ``G`` is (n_se, n_se) scratch."""
    n_so, n_se = C.shape
    if n_so == 3 and n_se == 3:
        return _spectral_norm33(C)
    for a in range(n_se):
        for b in range(n_se):
            acc = 0.0
            for i in range(n_so):
                acc += C[i, a] * C[i, b]
            G[a, b] = acc
    if n_se == 1:
        return np.sqrt(G[0, 0])
    if n_se == 2:
        h = 0.5 * (G[0, 0] - G[1, 1])
        return np.sqrt(max(0.5 * (G[0, 0] + G[1, 1]) + np.sqrt(h * h + G[0, 1] * G[0, 1]),
                           0.0))
    if n_se == 3:
        return np.sqrt(max(sym3_lambda_max(G[0, 0], G[0, 1], G[0, 2], G[1, 1], G[1, 2],
                                            G[2, 2]), 0.0))
    # power iteration on the Gram matrix (other sizes; not on the hot path of 3x3 trackers)
    v = np.empty(n_se)
    for a in range(n_se):
        v[a] = 1.0 / np.sqrt(n_se)
    w = np.empty(n_se)
    lam = 0.0
    for _ in range(200):
        for a in range(n_se):
            acc = 0.0
            for b in range(n_se):
                acc += G[a, b] * v[b]
            w[a] = acc
        nw = 0.0
        for a in range(n_se):
            nw += w[a] * w[a]
        nw = np.sqrt(nw)
        if nw == 0.0:
            return 0.0
        if abs(nw - lam) <= 1e-15 * nw:
            lam = nw
            break
        lam = nw
        for a in range(n_se):
            v[a] = w[a] / nw
    return np.sqrt(lam)


def spectral_norms(C) -> np.ndarray:
    """Spectral norms of real coupling matrices ``(N, n_so, n_se)`` -> ``(N,)``."""
    C = np.ascontiguousarray(C, dtype=np.float64)
    return _spectral_norms(C)


@njit(cache=True)
def _spectral_norms(C):
    out = np.empty(C.shape[0])
    G = np.empty((C.shape[2], C.shape[2]))
    for k in range(C.shape[0]):
        out[k] = spectral_norm(C[k], G)
    return out


# ------------------------------------------------------------------------------------------
# the compiled kernel
# ------------------------------------------------------------------------------------------
@njit(inline="always")
def _fast_concentric(C0, rank_tol, s, U, R, G, X, q, M):
    """Singular values, dominant direction and rotation of ``C0 = k H R`` without a full SVD.

    Eigenvalues of ``C0 C0^T`` (trigonometric closed form) give the singular values; the
    eigenvector of the largest gives ``u = U[:, 0]``; the rotation is the Wahba solution for
    ``H^-1 C0 = U diag(s0/2, -s1, -s2) V^T``: ``U diag(1, -1, -1) V^T`` (the Kim18 rotation and
    the solution of Teixeira Silva et al. 2017), with Markley's determinant correction when ``det C0 < 0``, found as
    a unit quaternion ``q`` by Davenport's q-method (``wahba_quat``) from the known singular
    values. Returns ``_FAST_DONE`` (``s``, ``U[:, 0]``, ``q``, ``R`` set), ``_FAST_RANK_DEFICIENT``
    or ``_FAST_USE_SVD`` (fall back to the SVD path: a nearly double top singular value, or no
    usable eigenvector).
    """
    for i in range(3):
        for j in range(i + 1):
            acc = C0[i, 0] * C0[j, 0] + C0[i, 1] * C0[j, 1] + C0[i, 2] * C0[j, 2]
            G[i, j] = acc
            G[j, i] = acc
    sym3_eigvals(G, s)
    if not s[0] > 0.0:
        return _FAST_RANK_DEFICIENT
    lam0 = s[0]
    lam1 = s[1]
    for i in range(3):
        s[i] = np.sqrt(max(s[i], 0.0))
    if not s[2] > rank_tol * s[0]:
        return _FAST_RANK_DEFICIENT
    if not lam0 > 1.05 * lam1:
        return _FAST_USE_SVD
    u = X[0]
    if not dominant_eigvec(G, lam0, u):
        return _FAST_USE_SVD
    u0, u1, u2 = u[0], u[1], u[2]
    U[0, 0], U[1, 0], U[2, 0] = u0, u1, u2
    # G <- H^-1 C0 / k with H^-1 = 1.5 u u^T - I and k = (s0/2 + s1 + s2)/3; its singular
    # values are (s0/2, s1, s2) / k and sign(det G) = sign(det C0) (det H^-1 = 1/2)
    w0 = 0.5 * s[0]
    w1 = s[1]
    w2 = s[2]
    lam = w0 + w1 + w2
    ik = 3.0 / lam  # 1 / k
    for j in range(3):
        dot = u0 * C0[0, j] + u1 * C0[1, j] + u2 * C0[2, j]
        G[0, j] = (1.5 * u0 * dot - C0[0, j]) * ik
        G[1, j] = (1.5 * u1 * dot - C0[1, j]) * ik
        G[2, j] = (1.5 * u2 * dot - C0[2, j]) * ik
    det = det33(C0)
    if det < 0.0:
        lam -= 2.0 * min(w0, min(w1, w2))
    if not wahba_quat(G, lam * ik, q, M):
        return _FAST_USE_SVD
    quat_matrix(q, R)
    return _FAST_DONE


@njit(inline="always")
def _cos_sin(x, y):
    """Cosine and sine of ``atan2(y, x)`` (angle 0 for ``x = y = 0``)."""
    h = np.sqrt(x * x + y * y)
    if h > 0.0:
        return x / h, y / h
    return 1.0, 0.0


@njit(cache=True)
def closed_form_one(method, C, W, gain, n, rank_tol, R, t, cws):
    """Closed-form pose of one 3x3 coupling ``C``; writes ``R``, ``t``.

    ``W`` (2, 3, 3) holds the whitening matrices ``M_so^-T`` and ``M_se^-1``; ``n`` the
    hemisphere direction; ``cws`` the scratch of :func:`closed_form_scratch`, whose ``q`` (4,)
    is the rotation's quaternion when the fast path produced it (``q[0] = -1`` otherwise).
    Returns ``ST_CONVERGED`` (a pose was found; the caller judges it) or ``ST_INVALID_INPUT``.
    """
    C0, U, s, V, B, q, M = cws
    Wso = W[0]
    Wse = W[1]
    q[0] = -1.0
    for i in range(3):
        for j in range(3):
            if not np.isfinite(C[i, j]):
                return ST_INVALID_INPUT
    # C0 = Wso C Wse (whitened coupling, = k H R), as two 3x3 products
    for i in range(3):
        for j in range(3):
            B[i, j] = Wso[i, 0] * C[0, j] + Wso[i, 1] * C[1, j] + Wso[i, 2] * C[2, j]
    for i in range(3):
        for j in range(3):
            C0[i, j] = B[i, 0] * Wse[0, j] + B[i, 1] * Wse[1, j] + B[i, 2] * Wse[2, j]
    u0 = 0.0
    u1 = 0.0
    u2 = 0.0
    fast = _FAST_USE_SVD
    if method == CF_KUIPERS:
        # Kuipers: invariants of C0 C0^T = k^2 (I + 3 u u^T)
        for i in range(3):
            for j in range(3):
                B[i, j] = C0[i, 0] * C0[j, 0] + C0[i, 1] * C0[j, 1] + C0[i, 2] * C0[j, 2]
        k2 = (B[0, 0] + B[1, 1] + B[2, 2]) / 6.0
        if not k2 > 0.0:
            return ST_INVALID_INPUT
        k = np.sqrt(k2)
        det = det33(C0)
        if not abs(det) > rank_tol * 2.0 * k2 * k:
            return ST_INVALID_INPUT
        m = 0
        best = -np.inf
        for i in range(3):
            B[i, i] = (B[i, i] / k2 - 1.0) / 3.0
            if B[i, i] > best:
                best = B[i, i]
                m = i
        for i in range(3):
            if i != m:
                for j in range(3):
                    if j != i:
                        B[i, j] = B[i, j] / k2 / 3.0
        if not best > 0.0:
            return ST_INVALID_INPUT
        sq = np.sqrt(best)
        u0 = B[0, m] / sq
        u1 = B[1, m] / sq
        u2 = B[2, m] / sq
        nu = np.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
        u0 /= nu
        u1 /= nu
        u2 /= nu
        dist = (gain / k) ** (1.0 / 3.0)
    else:
        fast = _fast_concentric(C0, rank_tol, s, U, R, B, V, q, M)
        if fast == _FAST_RANK_DEFICIENT:
            return ST_INVALID_INPUT
        if fast == _FAST_USE_SVD:
            svd3(C0, U, s, V)
            if not s[0] > 0.0 or not s[2] > rank_tol * s[0]:
                return ST_INVALID_INPUT
        u0 = U[0, 0]
        u1 = U[1, 0]
        u2 = U[2, 0]
        if method == CF_SVD:
            # Teixeira Silva et al. 2017, eq. 25: rho = cbrt(C/sigma), three estimates averaged
            dist = ((2.0 * gain / s[0]) ** (1.0 / 3.0) + (gain / s[1]) ** (1.0 / 3.0)
                    + (gain / s[2]) ** (1.0 / 3.0)) / 3.0
        else:
            # Kim18 (docs/paper-procedure.md#kim18) with 3 mu / (2 pi) = 6 gain
            dist = (6.0 * gain / (2.0 * s[0] + s[1] + s[2])) ** (1.0 / 3.0)
    # hemisphere: p . n >= 0
    proj = u0 * n[0] + u1 * n[1] + u2 * n[2]
    if proj < 0.0:
        u0, u1, u2 = -u0, -u1, -u2
    t[0] = dist * u0
    t[1] = dist * u1
    t[2] = dist * u2
    # orientation
    if method == CF_KUIPERS:
        k = np.sqrt(k2)
        # A = H^-1 C0 / k with H^-1 = 1.5 u u^T - I
        uv = (u0, u1, u2)
        for j in range(3):
            dot = u0 * C0[0, j] + u1 * C0[1, j] + u2 * C0[2, j]
            for i in range(3):
                B[i, j] = (1.5 * uv[i] * dot - C0[i, j]) / k
        # Z-Y-X Euler angles theta = asin(-B20), psi = atan2(B10, B00), phi = atan2(B21, B22)
        # and R = Rz(psi) Ry(theta) Rx(phi) (``euler_zyx_matrix``), with the sines and cosines
        # of the angles taken directly from the matrix entries instead of through the angles
        sth = min(max(-B[2, 0], -1.0), 1.0)
        cth = np.sqrt(1.0 - sth * sth)
        cps, sps = _cos_sin(B[0, 0], B[1, 0])
        cph, sph = _cos_sin(B[2, 2], B[2, 1])
        euler_zyx_matrix(cps, sps, cth, sth, cph, sph, R)
    elif fast == _FAST_USE_SVD:
        # Kim18 (docs/paper-procedure.md#kim18): Y = C0^T = V S U^T, R = V_Y diag(1,-1,-1) U_Y^T
        # = U diag(1,-1,-1) V^T. The Teixeira Silva et al. 2017 Wahba step min ||k R - H^-1 C0|| gives the same
        # rotation: H^-1 C0 = U diag(s0/2, -s1, -s2) V^T. When noise makes det(U V^T) < 0 both
        # flip the axis of the smallest Wahba weight (Markley's determinant correction) so
        # that R stays a rotation.
        detU = det33(U)
        detV = det33(V)
        d0, d1, d2 = 1.0, -1.0, -1.0
        if detU * detV < 0.0:
            w0, w1, w2 = 0.5 * s[0], s[1], s[2]
            if w0 <= w1 and w0 <= w2:
                d0 = -d0
            elif w1 <= w2:
                d1 = -d1
            else:
                d2 = -d2
        for i in range(3):
            for j in range(3):
                R[i, j] = d0 * U[i, 0] * V[j, 0] + d1 * U[i, 1] * V[j, 1] + d2 * U[i, 2] * V[j, 2]
    return ST_CONVERGED


@njit(cache=True)
def closed_form_scratch():
    """Scratch arrays of :func:`closed_form_one`: ``(C0, U, s, V, B, q, M)``."""
    return (np.empty((3, 3)), np.empty((3, 3)), np.empty(3), np.empty((3, 3)), np.empty((3, 3)),
            np.empty(4), np.empty((4, 4)))


@njit(inline="always")
def normalise_coupling(Cm, cn_in, Cn, G):
    """``Cn = Cm / s`` with ``s`` the power of two just above ``max |Cm|``: an exact scaling,
    so the normalised coupling solved with the gain divided by ``s`` gives bit for bit the pose
    of the unscaled problem, for couplings of any scale (docs/solve.md#validity-rule).

    Returns ``(s, cn, fn)``: the scale, ``cn = ||Cm||_2`` (the spectral norm ILEMT's resnorm is
    divided by; ``cn_in`` when known (complex input), else computed here for negative
    ``cn_in``) and ``fn = ||Cn||_F``. ``s = 0`` marks invalid input: non-finite, zero, or a
    largest magnitude outside about 1e-307..1e307.
    """
    mx = 0.0
    for i in range(Cm.shape[0]):
        for j in range(Cm.shape[1]):
            v = Cm[i, j]
            if not np.isfinite(v):
                return 0.0, 0.0, 0.0
            mx = max(mx, abs(v))
    s = math.ldexp(1.0, math.frexp(mx)[1])
    inv = 1.0 / s
    if not (mx > 0.0 and np.isfinite(s) and np.isfinite(inv)):
        return 0.0, 0.0, 0.0
    ss = 0.0
    for i in range(Cm.shape[0]):
        for j in range(Cm.shape[1]):
            c = Cm[i, j] * inv
            Cn[i, j] = c
            ss += c * c
    cn = cn_in if cn_in >= 0.0 else spectral_norm(Cn, G) * s
    if not (cn > 0.0 and np.isfinite(cn)):
        return 0.0, 0.0, 0.0
    return s, cn, np.sqrt(ss)


@njit(inline="always")
def residual_norms(Cp, Ck, s, cn, fn):
    """``(resnorm, relative residual)`` of the predicted coupling ``Cp`` against the measured
    ``Ck`` (scale ``s``, spectral norm ``cn``, normalised Frobenius norm ``fn``, from
    :func:`normalise_coupling`), both at the couplings' own scale."""
    inv = 1.0 / s
    ss = 0.0
    rr = 0.0
    for i in range(Ck.shape[0]):
        for j in range(Ck.shape[1]):
            d = Cp[i, j] - Ck[i, j]
            ss += d * d
            rr += (d * inv) ** 2
    return ss / cn, np.sqrt(rr) / fn


#: The scales ``s`` (powers of two) within which :func:`residuals_at` takes the couplings a
#: solve last predicted at the scale ``s`` times ``s`` as the couplings at their own scale: the
#: kernels' models divide only their gain by ``s`` (``unpack_any``), exactly while the gain over
#: ``s`` stays a normal number, which these bounds keep for any gain between about 1e-230 and
#: 1e230.
EXACT_SCALE_MIN = 2.0 ** -256
EXACT_SCALE_MAX = 2.0 ** 256


@njit(inline="always")
def residuals_at(geo, R, t, Ck, s, cn, fn, Cp, jac, known):
    """``(resnorm, relative residual)`` of the pose ``(R, t)`` for the measured coupling ``Ck``
    (scale ``s``, spectral norm ``cn``, normalised Frobenius norm ``fn``, from
    :func:`normalise_coupling`) under the unpacked model ``geo``, evaluated at the couplings'
    own scale. ``Cp`` receives the predicted coupling; ``jac`` (the derivative arrays of
    ``dipole_eval``, unused) is scratch. With ``known``, ``Cp`` already holds the coupling of
    ``(R, t)`` predicted at the scale ``s`` (a solve's last evaluation, where it ended there):
    times ``s`` (in place) it is the coupling at their own scale bit for bit (``s`` a power of
    two that divides only the model's gain, :data:`EXACT_SCALE_MIN` ..
    :data:`EXACT_SCALE_MAX`), so the model is not evaluated again."""
    if known and EXACT_SCALE_MIN <= s <= EXACT_SCALE_MAX:
        for i in range(Ck.shape[0]):
            for j in range(Ck.shape[1]):
                Cp[i, j] *= s
    else:
        no_jac = Ck.shape[0] < 0  # False at run time: one model_eval specialisation for all
        model_eval(geo, R, t, Cp, jac, no_jac)
    return residual_norms(Cp, Ck, s, cn, fn)


#: Samples per block of the closed-form batch kernel. Each block first normalises its
#: couplings (scale, spectral norm: a long chain of dependent operations ending in arccos and
#: cos), then solves them; the normalisations of a block are independent of each other, so the
#: processor overlaps their latencies instead of waiting on each inside the solve.
_BLOCK = 32


@njit(cache=True)
def _closed_form_batch(method, C, cnorm, W, mdl, nvec, opts, out):
    """The closed form ``method`` of every sample, judged by the validity rule with the
    residual of the concentric model ``mdl`` at the solved pose (:func:`concentric_eval`, in
    the same pass: no second sweep over the outputs)."""
    poses, vecs, status, residual, relres, iterations = out
    N = C.shape[0]
    R = np.empty((3, 3))
    t = np.empty(3)
    cws = closed_form_scratch()
    q = cws[5]
    G = np.empty((3, 3))
    Cp = np.empty((3, 3))
    mw = np.empty((4, 3))
    rv = np.empty(3)
    Cn = np.empty((_BLOCK, 3, 3))
    sb = np.empty(_BLOCK)
    cnb = np.empty(_BLOCK)
    fnb = np.empty(_BLOCK)
    box = np.empty((2, 3))
    box[0] = -np.inf
    box[1] = np.inf
    one_n = nvec.shape[0] == 1
    n = np.empty(3)  # this sample's hemisphere
    n[0], n[1], n[2] = nvec[0, 0], nvec[0, 1], nvec[0, 2]
    _, M_so, _, M_se, gain = unpack_model(mdl, 1.0)
    rank_tol = opts[O_RANK_TOL]
    for k0 in range(0, N, _BLOCK):
        nb = min(N - k0, _BLOCK)
        for b in range(nb):
            sb[b], cnb[b], fnb[b] = normalise_coupling(C[k0 + b], cnorm[k0 + b], Cn[b], G)
        for b in range(nb):
            k = k0 + b
            iterations[k] = 0
            if not one_n:
                n[0], n[1], n[2] = nvec[k, 0], nvec[k, 1], nvec[k, 2]
            s = sb[b]
            if not s > 0.0 or closed_form_one(method, Cn[b], W, gain / s, n, rank_tol, R, t,
                                              cws) == ST_INVALID_INPUT:
                _store_invalid(k, out)
                continue
            if q[0] >= 0.0:
                rotvec_from_quat(q, rv)
            else:
                rotvec_from_matrix(R, rv)
            store_pose(k, R, t, rv, poses, vecs)
            concentric_eval(M_so, M_se, gain, R, t, Cp, mw)
            residual[k], rho = residual_norms(Cp, C[k], s, cnb[b], fnb[b])
            relres[k] = rho
            status[k] = classify(False, rho, t, n, box, opts)


@njit(cache=True)
def _store_invalid(k, out):
    """Row ``k`` of the outputs ``(poses, vecs, status, residual, relres, iterations)``: NaN
    pose, ``INVALID_INPUT``."""
    poses, vecs, status, residual, relres, iterations = out
    store_nan_pose(k, poses, vecs)
    status[k] = ST_INVALID_INPUT
    residual[k] = np.nan
    relres[k] = np.nan
    iterations[k] = 0


def new_outputs(n: int) -> tuple:
    """Output arrays of the compiled solvers for ``n`` samples: ``(poses, pose_vectors,
    status, residual, relative_residual, iterations)``."""
    return (np.empty((n, 4, 4)), np.empty((n, 6)), np.empty(n, dtype=np.int8), np.empty(n),
            np.empty(n), np.empty(n, dtype=np.int32))


def result_from_outputs(out, solver: str) -> SolveResult:
    """:class:`SolveResult` of the arrays of :func:`new_outputs`."""
    poses, vecs, status, residual, relres, iterations = out
    return SolveResult(poses, vecs, status, residual, iterations, solver=solver,
                       relative_residual=relres)


def _concentric_model(model, name) -> DipoleModel:
    if model is None:
        return DipoleModel.concentric()
    check_dipole_model(model)
    if model.n_source != 3 or model.n_sensor != 3:
        raise InputError(f"expected a 3x3-coil model for the {name} closed form, got "
                         f"{model.n_source}x{model.n_sensor}")
    if not model.is_concentric:
        raise InputError(f"expected a concentric model (all coil positions 0) for the {name} "
                         f"closed form, got non-zero coil positions; use solve_lm")
    for nm in ("M_so", "M_se"):
        M = getattr(model, nm)
        if abs(np.linalg.det(M)) <= 1e-12 * np.linalg.norm(M) ** 3:
            raise InputError(f"expected invertible `{nm}` moments, got a singular matrix")
    return model


def whitening(model) -> np.ndarray:
    """``(2, 3, 3)`` whitening matrices ``[M_so^-T, M_se^-1]`` of a concentric 3x3 model."""
    return np.ascontiguousarray(np.stack([np.linalg.inv(model.M_so.T), np.linalg.inv(model.M_se)]))


def _solve_closed_form(method, couplings, model, hemisphere, rank_tol, ambiguity_tol,
                       max_relative_residual, max_range):
    model = _concentric_model(model, method)
    max_rel, max_range = check_validity_options(max_relative_residual, max_range)
    C, cnorm = check_couplings(couplings, 3, 3)
    n = C.shape[0]
    # one hemisphere for all samples: pass a single row (the kernel broadcasts it)
    # (a vector of 3 numbers is one direction; 3 strings are one hemisphere per sample)
    uniform = isinstance(hemisphere, str) or (
        np.shape(hemisphere) == (3,) and np.asarray(hemisphere).dtype.kind in "iuf")
    nvec = hemisphere_vectors(hemisphere, 1 if uniform else n, allow_none=False)
    opts = pack_options(rank_tol=rank_tol, ambiguity_tol=ambiguity_tol,
                        max_relative_residual=max_rel, max_range=max_range)
    out = new_outputs(n)
    _closed_form_batch(_METHODS[method], C, cnorm, whitening(model), pack_model(model), nvec,
                       opts, out)
    return result_from_outputs(out, method)


_COMMON_DOC = """
    Parameters
    ----------
    couplings : ndarray, shape (N, 3, 3)
        Signed real couplings ``C[k, source, sensor]`` (complex phasors are accepted and converted
        with ``sign(Re z) |z|``; their complex spectral norm then normalises the residual).
    model : DipoleModel, optional
        A concentric 3x3 model giving the moments and gain (ideal unit orthogonal coils with
        ``gain = 1/250`` if omitted).
    hemisphere : str, array_like (3,), sequence of str (N,) or array (N, 3)
        Resolves the +/- position ambiguity: the solution with ``p . n >= 0`` (default
        ``'+x'``, as every solver).
    rank_tol : float
        Coupling matrices with ``s3 < rank_tol * s1`` (after whitening) are INVALID_INPUT.
    ambiguity_tol : float
        Samples with ``|u . n| <= ambiguity_tol`` are flagged AMBIGUOUS (pose still returned).
    max_relative_residual, max_range : float or None
        The validity rule (docs/solve.md#validity-rule): a pose is CONVERGED only if
        ``||C_model(pose) - C||_F / ||C||_F <= max_relative_residual`` (default
        ``MAX_RELATIVE_RESIDUAL`` = 0.01) and it lies within ``max_range`` m of the source
        (default ``MAX_RANGE_M`` = 3). ``None`` disables a test.

    Returns
    -------
    SolveResult
        ``status`` is CONVERGED, NOT_CONVERGED, OUT_OF_VOLUME, AMBIGUOUS or INVALID_INPUT;
        ``residual`` is ILEMT's resnorm of the closed-form pose under ``model``,
        ``relative_residual`` the unit-free residual; ``iterations`` are 0.
"""


def solve_svd(couplings, model=None, *, hemisphere=DEFAULT_HEMISPHERE, rank_tol=RANK_TOL,
              ambiguity_tol=AMBIGUITY_TOL, max_relative_residual=MAX_RELATIVE_RESIDUAL,
              max_range=MAX_RANGE_M) -> SolveResult:
    """Closed-form SVD pose solution of Teixeira Silva et al. (Teixeira Silva et al. 2017).

    Distance from the singular values, direction from the first singular vector, orientation
    from the Wahba problem solved by SVD.
    """
    return _solve_closed_form("svd", couplings, model, hemisphere, rank_tol, ambiguity_tol,
                              max_relative_residual, max_range)


def solve_kuipers(couplings, model=None, *, hemisphere=DEFAULT_HEMISPHERE, rank_tol=RANK_TOL,
                  ambiguity_tol=AMBIGUITY_TOL, max_relative_residual=MAX_RELATIVE_RESIDUAL,
                  max_range=MAX_RANGE_M) -> SolveResult:
    """Kuipers' closed-form pose solution (the benchmark of Teixeira Silva et al. 2017).

    Distance from the Frobenius invariant, direction cosines from ``C0 C0^T``, orientation from
    Z-Y-X Euler angles read off ``H^-1 C0 / k``.
    """
    return _solve_closed_form("kuipers", couplings, model, hemisphere, rank_tol, ambiguity_tol,
                              max_relative_residual, max_range)


def solve_kim18(couplings, model=None, *, hemisphere=DEFAULT_HEMISPHERE, rank_tol=RANK_TOL,
                ambiguity_tol=AMBIGUITY_TOL, max_relative_residual=MAX_RELATIVE_RESIDUAL,
                max_range=MAX_RANGE_M) -> SolveResult:
    """Kim-Song-Park 2018 closed form for calibrated concentric models (docs/paper-procedure.md#kim18).

    Accepts non-orthogonal moments and unequal gains (through the whitening by ``M_so``,
    ``M_se``).
    """
    return _solve_closed_form("kim18", couplings, model, hemisphere, rank_tol, ambiguity_tol,
                              max_relative_residual, max_range)


_EXAMPLE = """
Examples
--------
Couplings of the ideal concentric model at a known pose, solved back (``status`` 0 is
``Status.CONVERGED``):

>>> import numpy as np
>>> from openemt import {name}
>>> from openemt.field import DipoleModel
>>> from openemt.geometry import pose_from_vector
>>> model = DipoleModel.concentric()
>>> truth = pose_from_vector(np.array([[0.3, 0.1, -0.05, 0.2, -0.4, 1.0]]))  # m, rad
>>> result = {name}(model.coupling(truth), model)
>>> result.status, np.round(result.pose_vectors, 6)
(array([0], dtype=int8), array([[ 0.3 ,  0.1 , -0.05,  0.2 , -0.4 ,  1.  ]]))
"""

for _f in (solve_svd, solve_kuipers, solve_kim18):
    _f.__doc__ += _COMMON_DOC + _EXAMPLE.format(name=_f.__name__)
