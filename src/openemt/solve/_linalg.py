"""Small compiled 3x3 / 6x6 linear-algebra helpers for the per-sample solvers.

Everything here works on one sample and is called from the batched kernels; nothing here knows
about coils or poses beyond rotations.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = [
    "cholesky_solve",
    "euler_zyx_matrix",
    "herm3_lambda_max",
    "exp_so3",
    "quat_matrix",
    "rotvec_from_matrix",
    "rotvec_from_quat",
    "store_nan_pose",
    "store_pose",
    "svd3",
    "sym3_eigvals",
    "sym3_lambda_max",
    "wahba_quat",
]


@njit(cache=True)
def svd3(A, U, s, V):
    """Singular value decomposition ``A = U diag(s) V^T`` of a 3x3 matrix (one-sided Jacobi).

    Singular values are sorted in decreasing order; ``U`` and ``V`` are orthogonal (their
    determinants may be -1). Accurate to a few ulps relative to ``s[0]``.
    """
    for i in range(3):
        for j in range(3):
            U[i, j] = A[i, j]
            V[i, j] = 1.0 if i == j else 0.0
    for _sweep in range(30):
        rotated = False
        for p in range(2):
            for q in range(p + 1, 3):
                alpha = U[0, p] * U[0, p] + U[1, p] * U[1, p] + U[2, p] * U[2, p]
                beta = U[0, q] * U[0, q] + U[1, q] * U[1, q] + U[2, q] * U[2, q]
                gamma = U[0, p] * U[0, q] + U[1, p] * U[1, q] + U[2, p] * U[2, q]
                if gamma == 0.0 or abs(gamma) <= 1e-16 * np.sqrt(alpha * beta):
                    continue
                rotated = True
                zeta = (beta - alpha) / (2.0 * gamma)
                t = (1.0 if zeta >= 0.0 else -1.0) / (abs(zeta) + np.sqrt(1.0 + zeta * zeta))
                c = 1.0 / np.sqrt(1.0 + t * t)
                sn = c * t
                for i in range(3):
                    up = U[i, p]
                    uq = U[i, q]
                    U[i, p] = c * up - sn * uq
                    U[i, q] = sn * up + c * uq
                    vp = V[i, p]
                    vq = V[i, q]
                    V[i, p] = c * vp - sn * vq
                    V[i, q] = sn * vp + c * vq
        if not rotated:
            break
    for j in range(3):
        s[j] = np.sqrt(U[0, j] * U[0, j] + U[1, j] * U[1, j] + U[2, j] * U[2, j])
    # sort decreasing (3 elements: bubble)
    for _ in range(2):
        for j in range(2):
            if s[j] < s[j + 1]:
                tmp = s[j]
                s[j] = s[j + 1]
                s[j + 1] = tmp
                for i in range(3):
                    tmp = U[i, j]
                    U[i, j] = U[i, j + 1]
                    U[i, j + 1] = tmp
                    tmp = V[i, j]
                    V[i, j] = V[i, j + 1]
                    V[i, j + 1] = tmp
    # normalise the left vectors; complete a zero column from the other two
    for j in range(3):
        if s[j] > 0.0:
            for i in range(3):
                U[i, j] /= s[j]
    if (s[2] <= 1e-300 * max(s[0], 1e-300) or s[2] == 0.0) and s[1] > 0.0:
        U[0, 2] = U[1, 0] * U[2, 1] - U[2, 0] * U[1, 1]
        U[1, 2] = U[2, 0] * U[0, 1] - U[0, 0] * U[2, 1]
        U[2, 2] = U[0, 0] * U[1, 1] - U[1, 0] * U[0, 1]


@njit(inline="always")
def exp_so3(phi, R):
    """Rotation matrix ``R = exp([phi]x)`` (Rodrigues), written into ``R`` (3, 3)."""
    th2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2]
    th = np.sqrt(th2)
    if th < 1e-8:
        a = 1.0 - th2 / 6.0
        b = 0.5 - th2 / 24.0
    else:
        a = np.sin(th) / th
        b = (1.0 - np.cos(th)) / th2
    x, y, z = phi[0], phi[1], phi[2]
    R[0, 0] = 1.0 - b * (y * y + z * z)
    R[1, 1] = 1.0 - b * (x * x + z * z)
    R[2, 2] = 1.0 - b * (x * x + y * y)
    R[0, 1] = -a * z + b * x * y
    R[1, 0] = a * z + b * x * y
    R[0, 2] = a * y + b * x * z
    R[2, 0] = -a * y + b * x * z
    R[1, 2] = -a * x + b * y * z
    R[2, 1] = a * x + b * y * z


@njit(inline="always")
def rotvec_from_matrix(R, out):
    """Rotation vector (angle in [0, pi]) of a rotation matrix, through a unit quaternion."""
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    # Shepperd's method: pick the largest of w, x, y, z for accuracy
    if tr >= R[0, 0] and tr >= R[1, 1] and tr >= R[2, 2]:
        w = 0.5 * np.sqrt(max(1.0 + tr, 0.0))
        f = 0.25 / w
        x = (R[2, 1] - R[1, 2]) * f
        y = (R[0, 2] - R[2, 0]) * f
        z = (R[1, 0] - R[0, 1]) * f
    elif R[0, 0] >= R[1, 1] and R[0, 0] >= R[2, 2]:
        x = 0.5 * np.sqrt(max(1.0 + 2.0 * R[0, 0] - tr, 0.0))
        f = 0.25 / x
        w = (R[2, 1] - R[1, 2]) * f
        y = (R[0, 1] + R[1, 0]) * f
        z = (R[0, 2] + R[2, 0]) * f
    elif R[1, 1] >= R[2, 2]:
        y = 0.5 * np.sqrt(max(1.0 + 2.0 * R[1, 1] - tr, 0.0))
        f = 0.25 / y
        w = (R[0, 2] - R[2, 0]) * f
        x = (R[0, 1] + R[1, 0]) * f
        z = (R[1, 2] + R[2, 1]) * f
    else:
        z = 0.5 * np.sqrt(max(1.0 + 2.0 * R[2, 2] - tr, 0.0))
        f = 0.25 / z
        w = (R[1, 0] - R[0, 1]) * f
        x = (R[0, 2] + R[2, 0]) * f
        y = (R[1, 2] + R[2, 1]) * f
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    _rotvec_from_wxyz(w, x, y, z, out)


@njit(inline="always")
def cholesky_solve(A, b, n, x, L):
    """Solve ``A x = b`` for a symmetric positive-definite ``n x n`` block of ``A``.

    Returns False (and leaves ``x`` undefined) when ``A`` is not numerically positive definite.
    """
    for i in range(n):
        for j in range(i + 1):
            acc = A[i, j]
            for k in range(j):
                acc -= L[i, k] * L[j, k]
            if i == j:
                if not acc > 0.0:
                    return False
                L[i, i] = np.sqrt(acc)
            else:
                L[i, j] = acc / L[j, j]
    for i in range(n):
        acc = b[i]
        for k in range(i):
            acc -= L[i, k] * x[k]
        x[i] = acc / L[i, i]
    for i in range(n - 1, -1, -1):
        acc = x[i]
        for k in range(i + 1, n):
            acc -= L[k, i] * x[k]
        x[i] = acc / L[i, i]
    return True


@njit(inline="always")
def euler_zyx_matrix(cps, sps, cth, sth, cph, sph, R):
    """``R = Rz(psi) Ry(theta) Rx(phi)`` from the cosines and sines of the three angles,
    written into ``R`` (3, 3)."""
    R[0, 0] = cps * cth
    R[0, 1] = cps * sth * sph - sps * cph
    R[0, 2] = cps * sth * cph + sps * sph
    R[1, 0] = sps * cth
    R[1, 1] = sps * sth * sph + cps * cph
    R[1, 2] = sps * sth * cph - cps * sph
    R[2, 0] = -sth
    R[2, 1] = cth * sph
    R[2, 2] = cth * cph


@njit(inline="always")
def _sym3_trig(a00, a01, a02, a11, a12, a22):
    """``(q, p, c)`` of the trigonometric eigenvalue formula of a symmetric 3x3 matrix: the
    eigenvalues are ``q + 2 p cos(phi + 2 pi k / 3)`` with ``c = cos(phi)``, phi in [0, pi/3];
    ``p = 0`` when all three are equal (``q``)."""
    p1 = a01 * a01 + a02 * a02 + a12 * a12
    q = (a00 + a11 + a22) / 3.0
    b0 = a00 - q
    b1 = a11 - q
    b2 = a22 - q
    p2 = b0 * b0 + b1 * b1 + b2 * b2 + 2.0 * p1
    if p2 <= 0.0:
        return q, 0.0, 1.0
    p = np.sqrt(p2 / 6.0)
    # r = det((A - q I) / p) / 2
    r = 0.5 * (b0 * (b1 * b2 - a12 * a12) - a01 * (a01 * b2 - a12 * a02)
               + a02 * (a01 * a12 - b1 * a02)) / (p * p * p)
    r = min(max(r, -1.0), 1.0)
    return q, p, np.cos(np.arccos(r) / 3.0)


@njit(inline="always")
def sym3_lambda_max(a00, a01, a02, a11, a12, a22):
    """Largest eigenvalue of the symmetric 3x3 matrix with these upper-triangle entries."""
    q, p, c = _sym3_trig(a00, a01, a02, a11, a12, a22)
    return q + 2.0 * p * c


@njit(inline="always")
def herm3_lambda_max(a00, a11, a22, a01, a02, a12):
    """Largest eigenvalue of the Hermitian 3x3 matrix with the real diagonal ``a00, a11, a22``
    and the complex upper-triangle entries ``a01, a02, a12``, or -1 where a second eigenvalue
    is close to it.

    The trigonometric formula of :func:`sym3_lambda_max`, whose characteristic polynomial is
    real for a Hermitian matrix too (``det(A - q I)`` has ``2 Re(a01 a12 conj(a02))`` and the
    squared moduli where the symmetric one has ``2 a01 a12 a02`` and the squares). Near a
    double top eigenvalue ``r = det(A - q I) / (2 p^3)`` approaches -1, where ``arccos``
    amplifies rounding (an error of about ``p eps / sqrt(2 (1 + r))``, 1e-8 at a double
    eigenvalue): for ``r < -1 + 1e-4`` (an error above about 1e-14 relative) -1 is returned and
    the caller uses an SVD."""
    n01 = a01.real * a01.real + a01.imag * a01.imag
    n02 = a02.real * a02.real + a02.imag * a02.imag
    n12 = a12.real * a12.real + a12.imag * a12.imag
    q = (a00 + a11 + a22) / 3.0
    b0 = a00 - q
    b1 = a11 - q
    b2 = a22 - q
    p2 = b0 * b0 + b1 * b1 + b2 * b2 + 2.0 * (n01 + n02 + n12)
    if p2 <= 0.0:
        return q
    p = np.sqrt(p2 / 6.0)
    if not p * p * p > 0.0:
        return q
    t = a01 * a12 * np.conj(a02)
    r = 0.5 * (b0 * b1 * b2 + 2.0 * t.real - b0 * n12 - b1 * n02 - b2 * n01) / (p * p * p)
    if r < -1.0 + 1e-4:
        return -1.0
    r = min(r, 1.0)
    return q + 2.0 * p * np.cos(np.arccos(r) / 3.0)


@njit(inline="always")
def sym3_eigvals(A, lam):
    """Eigenvalues of a symmetric 3x3 matrix, decreasing, into ``lam`` (trigonometric form)."""
    q, p, c = _sym3_trig(A[0, 0], A[0, 1], A[0, 2], A[1, 1], A[1, 2], A[2, 2])
    # cos(phi + 2 pi / 3) = -(cos phi + sqrt(3) sin phi) / 2
    sn = np.sqrt(max(1.0 - c * c, 0.0))
    lam[0] = q + 2.0 * p * c
    lam[2] = q - p * (c + 1.7320508075688772 * sn)
    lam[1] = 3.0 * q - lam[0] - lam[2]


@njit(inline="always")
def dominant_eigvec(A, lam0, v):
    """Unit eigenvector of symmetric ``A`` for its (simple) eigenvalue ``lam0``: the largest
    cross product of two rows of ``A - lam0 I``. Returns False if none is usable."""
    r00, r01, r02 = A[0, 0] - lam0, A[0, 1], A[0, 2]
    r10, r11, r12 = A[1, 0], A[1, 1] - lam0, A[1, 2]
    r20, r21, r22 = A[2, 0], A[2, 1], A[2, 2] - lam0
    best = -1.0
    for k in range(3):
        if k == 0:
            x0, x1, x2, y0, y1, y2 = r00, r01, r02, r10, r11, r12
        elif k == 1:
            x0, x1, x2, y0, y1, y2 = r00, r01, r02, r20, r21, r22
        else:
            x0, x1, x2, y0, y1, y2 = r10, r11, r12, r20, r21, r22
        c0 = x1 * y2 - x2 * y1
        c1 = x2 * y0 - x0 * y2
        c2 = x0 * y1 - x1 * y0
        nn = c0 * c0 + c1 * c1 + c2 * c2
        if nn > best:
            best = nn
            v[0], v[1], v[2] = c0, c1, c2
    if not best > 0.0:
        return False
    nv = 1.0 / np.sqrt(best)
    v[0] *= nv
    v[1] *= nv
    v[2] *= nv
    return True


@njit(inline="always")
def _det3(a00, a01, a02, a10, a11, a12, a20, a21, a22):
    return (a00 * (a11 * a22 - a12 * a21) - a01 * (a10 * a22 - a12 * a20)
            + a02 * (a10 * a21 - a11 * a20))


@njit(inline="always")
def det33(A):
    """Determinant of a 3x3 matrix (cofactor expansion along the first row)."""
    return _det3(A[0, 0], A[0, 1], A[0, 2], A[1, 0], A[1, 1], A[1, 2], A[2, 0], A[2, 1],
                 A[2, 2])


@njit(inline="always")
def wahba_quat(B, lam, q, M):
    """Unit quaternion ``q = (w, x, y, z)``, ``w >= 0``, of the rotation maximising
    ``tr(R^T B)`` (Davenport's q-method), given the largest eigenvalue ``lam`` of Davenport's
    symmetric 4x4 matrix ``K(B)``: ``lam = s1 + s2 + sign(det B) s3`` with the singular values
    ``s1 >= s2 >= s3`` of ``B``. The eigenvector is the largest column of the adjugate of
    ``K - lam I``, a 4-D cross product of three of its rows (no iteration). For ``det B > 0`` the
    rotation is the orthogonal polar factor of ``B``; for ``det B < 0`` Markley's
    determinant-corrected SVD solution ``U diag(1, 1, -1) V^T``. ``M`` is (4, 4) scratch.
    Returns False if ``lam`` is (numerically) not a simple eigenvalue.
    """
    M[0, 0] = B[0, 0] + B[1, 1] + B[2, 2] - lam
    M[1, 1] = B[0, 0] - B[1, 1] - B[2, 2] - lam
    M[2, 2] = -B[0, 0] + B[1, 1] - B[2, 2] - lam
    M[3, 3] = -B[0, 0] - B[1, 1] + B[2, 2] - lam
    M[0, 1] = M[1, 0] = B[2, 1] - B[1, 2]
    M[0, 2] = M[2, 0] = B[0, 2] - B[2, 0]
    M[0, 3] = M[3, 0] = B[1, 0] - B[0, 1]
    M[1, 2] = M[2, 1] = B[0, 1] + B[1, 0]
    M[1, 3] = M[3, 1] = B[0, 2] + B[2, 0]
    M[2, 3] = M[3, 2] = B[1, 2] + B[2, 1]
    # diagonal of adj(K - lam I) = prod_j (lam_j - lam) q_i^2: pick the largest |q_i|
    best = -1.0
    ib = 0
    for i in range(4):
        a = 1 if i == 0 else 0
        b = 2 if i <= 1 else 1
        c = 3 if i <= 2 else 2
        m = abs(_det3(M[a, a], M[a, b], M[a, c], M[b, a], M[b, b], M[b, c],
                      M[c, a], M[c, b], M[c, c]))
        if m > best:
            best = m
            ib = i
    if not best > 0.0:
        return False
    # column ib of the adjugate: 4-D cross product of the other three rows
    a = 1 if ib == 0 else 0
    b = 2 if ib <= 1 else 1
    c = 3 if ib <= 2 else 2
    nn = 0.0
    for j in range(4):
        e = 1 if j == 0 else 0
        f = 2 if j <= 1 else 1
        g = 3 if j <= 2 else 2
        v = _det3(M[a, e], M[a, f], M[a, g], M[b, e], M[b, f], M[b, g],
                  M[c, e], M[c, f], M[c, g])
        if j % 2 == 1:
            v = -v
        q[j] = v
        nn += v * v
    nv = 1.0 / np.sqrt(nn)
    if q[0] < 0.0:
        nv = -nv
    for j in range(4):
        q[j] *= nv
    return True


@njit(inline="always")
def quat_matrix(q, R):
    """Rotation matrix of a unit quaternion ``q = (w, x, y, z)`` into ``R`` (3, 3)."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    R[0, 0] = 1.0 - 2.0 * (yy + zz)
    R[1, 1] = 1.0 - 2.0 * (xx + zz)
    R[2, 2] = 1.0 - 2.0 * (xx + yy)
    R[0, 1] = 2.0 * (xy - wz)
    R[1, 0] = 2.0 * (xy + wz)
    R[0, 2] = 2.0 * (xz + wy)
    R[2, 0] = 2.0 * (xz - wy)
    R[1, 2] = 2.0 * (yz - wx)
    R[2, 1] = 2.0 * (yz + wx)


@njit(inline="always")
def _rotvec_from_wxyz(w, x, y, z, out):
    """Rotation vector (angle in [0, pi]) of the unit quaternion (w, x, y, z), ``w >= 0``."""
    nv = np.sqrt(x * x + y * y + z * z)
    if nv < 1e-300:
        out[0] = 0.0
        out[1] = 0.0
        out[2] = 0.0
        return
    f = 2.0 * np.arctan2(nv, w) / nv
    out[0] = f * x
    out[1] = f * y
    out[2] = f * z


@njit(inline="always")
def rotvec_from_quat(q, out):
    """Rotation vector (angle in [0, pi]) of a unit quaternion with ``w >= 0``."""
    _rotvec_from_wxyz(q[0], q[1], q[2], q[3], out)



@njit(inline="always")
def store_pose(k, R, t, rv, poses, vecs):
    """Write sample ``k`` of the batch outputs: pose ``[[R, t], [0, 1]]`` into ``poses (N, 4, 4)``
    and ``[t, rv]`` into ``vecs (N, 6)``."""
    for i in range(3):
        for j in range(3):
            poses[k, i, j] = R[i, j]
        poses[k, i, 3] = t[i]
        poses[k, 3, i] = 0.0
        vecs[k, i] = t[i]
        vecs[k, 3 + i] = rv[i]
    poses[k, 3, 3] = 1.0


@njit(inline="always")
def store_nan_pose(k, poses, vecs):
    """Sample ``k`` of the batch outputs set to NaN (no pose, never a plausible one)."""
    for i in range(4):
        for j in range(4):
            poses[k, i, j] = np.nan
    for i in range(6):
        vecs[k, i] = np.nan
