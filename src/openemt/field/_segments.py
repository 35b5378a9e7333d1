"""Compiled Biot-Savart field of straight current segments, with its analytic gradient.

A segment from ``a`` to ``b`` carrying current ``I`` makes at ``r`` the flux density
(Hanson & Hirshman 2002, eq. 8, written with ``A = a - r``, ``B = b - r``)::

    B(r) = (mu0 I / 4 pi) (A x B) (|A| + |B|) / (|A| |B| (|A| |B| + A . B))

Its gradient follows in closed form: ``d(A x B)/dr_j = e_j x (a - b)`` is constant, and the
scalar factor ``f = N / (P Q)`` (``N = |A| + |B|``, ``P = |A| |B|``, ``Q = P + A . B``) has
``df = f (dN/N - dP/P - dQ/Q)``. A coil is a run of segments (a board's spiral trace, see
:mod:`openemt.board`); fields are in tesla for 1 A.

The kernels are the inner loop of the 5-DOF finite-coil solver (:mod:`openemt.solve._planar`),
of the LM kernels' board specialisation (:mod:`openemt.solve._model_kernels`) and of the planar
calibration (:mod:`openemt.calibrate._planar`); magpylib remains the reference they are tested
against. Each sum over a coil's segments is written for the processor's vector units: no branch
in the loop, one division per segment (the inverses of ``N``, ``P`` and ``Q`` all come from
``1 / (N P Q)``) and sums that the ``fastmath`` flags :data:`_VECTOR` let LLVM reorder into
vector lanes (on the 2-core development machine 6.1-6.2 ns per segment and point with the
directional gradient, 4.4 ns without, 6.6 ns with the full gradient and 4.9-5.1 ns for the
field alone; 15.1, 7.8, 22.4 and 8.6 ns for the sequential loops before).
"""

from __future__ import annotations

import numpy as np
from numba import njit
from scipy.constants import mu_0

from .._errors import InputError

__all__ = ["MU0_OVER_4PI", "ON_TRACE", "segment_coupling", "segment_fields"]

#: mu0 / (4 pi) in T m / A.
MU0_OVER_4PI = mu_0 / (4.0 * np.pi)

#: A point is on a segment (which then adds no field and no gradient there: an infinitely thin
#: trace has no finite field on itself) when ``Q = |A| |B| + A . B`` is at most this fraction of
#: ``P = |A| |B|``, i.e. ``1 + cos`` of the angle the segment subtends is: on a vertex both are 0,
#: inside the segment ``Q`` is rounding noise of ``P`` (about 1e-16 of it, which as a divisor
#: made the gradient there 1e13 times too large). Off the segment ``Q / P`` is about
#: ``8 d^2 / L^2`` at a distance ``d`` from the middle of a segment of length ``L``: below this
#: fraction only within ``3.5e-8 L`` of it (2.5 nm for 70 mm).
ON_TRACE = 1e-14

#: The ``fastmath`` flags of the kernels around the segment sums (:func:`_accumulate_along`,
#: :func:`_accumulate_field`, :func:`_accumulate_gradient`): reassociation (the sums over
#: segments run in vector lanes, in another order: results differ from the sequential sum in
#: the last bits, about 1e-15 relative), contraction into fused multiply-adds, and no signed
#: zeros. Not ``nnan``/``ninf``: the comparison that finds a point on a segment keeps its
#: meaning.
_VECTOR = {"reassoc", "contract", "nsz"}


@njit(cache=True, inline="always")
def _segment(S, s, rx, ry, rz):
    """Segment ``s`` of ``S`` seen from ``r``: ``A = a - r``, ``B = b - r``, ``|A|``, ``|B|``,
    ``P = |A| |B|`` and ``Q = P + A . B``, which is set to zero for a point on the segment
    (:data:`ON_TRACE`). Written as a select that LLVM's loop vectoriser accepts (the same
    test as one condition of the callers' division stopped it vectorising the loop)."""
    ax = S[s, 0, 0] - rx
    ay = S[s, 0, 1] - ry
    az = S[s, 0, 2] - rz
    bx = S[s, 1, 0] - rx
    by = S[s, 1, 1] - ry
    bz = S[s, 1, 2] - rz
    na = np.sqrt(ax * ax + ay * ay + az * az)
    nb = np.sqrt(bx * bx + by * by + bz * bz)
    P = na * nb
    Q = P + ax * bx + ay * by + az * bz
    Q = Q if Q > ON_TRACE * P else 0.0
    return ax, ay, az, bx, by, bz, na, nb, P, Q


@njit(cache=True, inline="always")
def _factors(na, nb, P, Q):
    """``f = N / (P Q)`` and ``kA``, ``kB`` with ``df/dr_j = f (kA A_j + kB B_j)`` (from
    ``d|A|/dr_j = -A_j / |A|``, ``d|B|/dr_j = -B_j / |B|``), with one division: the inverses
    of ``N``, ``P`` and ``Q`` all come from ``1 / (N P Q)``; all zero on the segment."""
    N = na + nb
    den = N * P * Q
    inv = 1.0 / den if den > 0.0 else 0.0
    iN = P * Q * inv
    iQ = N * P * inv
    iP = N * Q * inv
    ia = nb * iP
    ib = na * iP
    return N * iP * iQ, ia * (ia - iN + nb * iQ) + iQ, ib * (ib - iN + na * iQ) + iQ


@njit(cache=True, inline="always")
def _accumulate_gradient(S, lo, hi, rx, ry, rz, out_b, out_g):
    """Add the field and its gradient ``out_g[a, j] = dB_a/dr_j`` of segments ``lo:hi`` of
    ``S`` (S, 2, 3) at ``r`` to ``out_b`` (3,), ``out_g`` (3, 3); unit prefactor. Branch-free,
    as :func:`_accumulate_along`."""
    b0 = b1 = b2 = 0.0
    g00 = g01 = g02 = g10 = g11 = g12 = g20 = g21 = g22 = 0.0
    for s in range(lo, hi):
        ax, ay, az, bx, by, bz, na, nb, P, Q = _segment(S, s, rx, ry, rz)
        f, kA, kB = _factors(na, nb, P, Q)
        cx = ay * bz - az * by
        cy = az * bx - ax * bz
        cz = ax * by - ay * bx
        b0 += f * cx
        b1 += f * cy
        b2 += f * cz
        dx = ax - bx
        dy = ay - by
        dz = az - bz
        fa = f * kA
        fb = f * kB
        df0 = fa * ax + fb * bx
        df1 = fa * ay + fb * by
        df2 = fa * az + fb * bz
        # d(A x B)/dr_j = e_j x (a - b)
        g00 += cx * df0
        g01 += dz * f + cx * df1
        g02 += -dy * f + cx * df2
        g10 += -dz * f + cy * df0
        g11 += cy * df1
        g12 += dx * f + cy * df2
        g20 += dy * f + cz * df0
        g21 += -dx * f + cz * df1
        g22 += cz * df2
    out_b[0] += b0
    out_b[1] += b1
    out_b[2] += b2
    out_g[0, 0] += g00
    out_g[0, 1] += g01
    out_g[0, 2] += g02
    out_g[1, 0] += g10
    out_g[1, 1] += g11
    out_g[1, 2] += g12
    out_g[2, 0] += g20
    out_g[2, 1] += g21
    out_g[2, 2] += g22


@njit(cache=True, fastmath=_VECTOR)
def _fields(S, offsets, points, grad):
    nc = offsets.shape[0] - 1
    n = points.shape[0]
    B = np.zeros((nc, n, 3))
    G = np.zeros((nc, n, 3, 3))
    for i in range(nc):
        for k in range(n):
            if grad:
                _accumulate_gradient(S, offsets[i], offsets[i + 1], points[k, 0], points[k, 1],
                                     points[k, 2], B[i, k], G[i, k])
            else:
                b0, b1, b2 = _accumulate_field(S, offsets[i], offsets[i + 1], points[k, 0],
                                               points[k, 1], points[k, 2])
                B[i, k, 0] = b0
                B[i, k, 1] = b1
                B[i, k, 2] = b2
    return B * MU0_OVER_4PI, G * MU0_OVER_4PI


@njit(cache=True, inline="always")
def _accumulate_along(S, lo, hi, rx, ry, rz, ux, uy, uz, out):
    """Add ``B`` (``out[0:3]``) and ``u . dB/dr_j`` (``out[3:6]``) of segments ``lo:hi`` at
    ``r``: the directional gradient a single-coil coupling needs, without the full 3x3.

    Written for the processor's vector units: no branch in the loop (a point on a segment adds
    nothing through a zero factor instead of a ``continue``), one division per segment
    (:func:`_factors`) and the sums in registers, which the caller's ``fastmath`` flags
    (:data:`_VECTOR`) let LLVM reorder into vector lanes."""
    o0 = o1 = o2 = o3 = o4 = o5 = 0.0
    for s in range(lo, hi):
        ax, ay, az, bx, by, bz, na, nb, P, Q = _segment(S, s, rx, ry, rz)
        f, kA, kB = _factors(na, nb, P, Q)
        cx = ay * bz - az * by
        cy = az * bx - ax * bz
        cz = ax * by - ay * bx
        o0 += f * cx
        o1 += f * cy
        o2 += f * cz
        dx = ax - bx
        dy = ay - by
        dz = az - bz
        uc = ux * cx + uy * cy + uz * cz
        fa = uc * f * kA
        fb = uc * f * kB
        # u . d(A x B)/dr_j = u . (e_j x (a - b)) = ((a - b) x u)_j
        o3 += f * (dy * uz - dz * uy) + fa * ax + fb * bx
        o4 += f * (dz * ux - dx * uz) + fa * ay + fb * by
        o5 += f * (dx * uy - dy * ux) + fa * az + fb * bz
    out[0] += o0
    out[1] += o1
    out[2] += o2
    out[3] += o3
    out[4] += o4
    out[5] += o5


@njit(cache=True, inline="always")
def _accumulate_field(S, lo, hi, rx, ry, rz):
    """``B`` of segments ``lo:hi`` at ``r`` (unit prefactor), branch-free as
    :func:`_accumulate_along`: the field without derivatives (of a coupling, and of
    :func:`segment_fields`)."""
    o0 = o1 = o2 = 0.0
    for s in range(lo, hi):
        ax, ay, az, bx, by, bz, na, nb, P, Q = _segment(S, s, rx, ry, rz)
        den = P * Q
        f = (na + nb) / den if den > 0.0 else 0.0
        o0 += f * (ay * bz - az * by)
        o1 += f * (az * bx - ax * bz)
        o2 += f * (ax * by - ay * bx)
    return o0, o1, o2


@njit(cache=True, fastmath=_VECTOR)
def coupling_point(S, offsets, gains, p, u, s_nodes, s_weights, C, dCdp, dCdu, grad):
    """Couplings ``C[i] = gains[i] sum_k w_k B_i(p + s_k u) . u`` of every coil into a
    single-coil sensor at ``p`` with unit axis ``u`` (the field averaged along the coil by the
    rule ``s_nodes, s_weights``), and with ``grad`` their derivatives by ``p`` and ``u``."""
    nc = offsets.shape[0] - 1
    acc = np.empty(6)
    for i in range(nc):
        C[i] = 0.0
        for a in range(3):
            dCdp[i, a] = 0.0
            dCdu[i, a] = 0.0
        for k in range(s_nodes.shape[0]):
            s = s_nodes[k]
            w = s_weights[k] * gains[i] * MU0_OVER_4PI
            qx = p[0] + s * u[0]
            qy = p[1] + s * u[1]
            qz = p[2] + s * u[2]
            if grad:
                acc[:] = 0.0
                _accumulate_along(S, offsets[i], offsets[i + 1], qx, qy, qz, u[0], u[1], u[2],
                                  acc)
                C[i] += w * (acc[0] * u[0] + acc[1] * u[1] + acc[2] * u[2])
                for j in range(3):
                    dCdp[i, j] += w * acc[3 + j]
                    dCdu[i, j] += w * (acc[j] + s * acc[3 + j])
            else:
                b0, b1, b2 = _accumulate_field(S, offsets[i], offsets[i + 1], qx, qy, qz)
                C[i] += w * (b0 * u[0] + b1 * u[1] + b2 * u[2])


def _readonly(a: np.ndarray) -> np.ndarray:
    """A read-only view of ``a``: the kernels then see one array type whatever the caller
    passed (a writable and a read-only array would each compile a specialisation)."""
    v = a.view()
    v.flags.writeable = False
    return v


def _check_segments(segments, offsets):
    """Checked segments and offsets, read-only views (:func:`_readonly`)."""
    S = np.ascontiguousarray(segments, dtype=np.float64)
    if S.ndim != 3 or S.shape[1:] != (2, 3) or not np.all(np.isfinite(S)):
        raise InputError(f"expected finite segments of shape (S, 2, 3), got {S.shape}")
    off = np.ascontiguousarray(offsets, dtype=np.int64)
    if off.ndim != 1 or len(off) < 2 or off[0] != 0 or off[-1] != len(S) \
            or np.any(np.diff(off) < 0):
        raise InputError(f"expected coil offsets from 0 to {len(S)} (non-decreasing), got "
                         f"{off.tolist()[:10]}")
    return _readonly(S), _readonly(off)


def segment_fields(segments, offsets, points, *, gradient=False):
    """Fields ``(n_coils, N, 3)`` (T for 1 A) of coils made of straight segments at points
    ``(N, 3)``; with ``gradient=True`` also ``(n_coils, N, 3, 3)``, ``[..., a, j] = dB_a/dx_j``.

    ``segments`` is ``(S, 2, 3)`` (start, end), coil ``i`` owning ``offsets[i]:offsets[i+1]``
    (as :meth:`openemt.board.Board.segments` returns them).
    """
    S, off = _check_segments(segments, offsets)
    P = np.ascontiguousarray(points, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or not np.all(np.isfinite(P)):
        raise InputError(f"expected finite points of shape (N, 3), got {P.shape}")
    B, G = _fields(S, off, P, gradient)
    return (B, G) if gradient else B


def sensor_rule(length: float) -> tuple[np.ndarray, np.ndarray]:
    """Nodes (m along the axis) and weights of the field average over a sensor coil of
    ``length``: the 2-point Gauss rule, or the centre for a point sensor (``length = 0``)."""
    if length <= 0:
        return np.array([0.0]), np.array([1.0])
    s = length / (2 * np.sqrt(3.0))
    return np.array([-s, s]), np.array([0.5, 0.5])


def segment_coupling(segments, offsets, gains, points, axes, *, sensor_length=0.0,
                     gradient=False):
    """Couplings ``(N, n_coils)`` into single-coil sensors at ``points`` with ``axes`` (unit),
    ``C_i = gains_i * mean over the coil length of B_i . u`` (T for 1 A times gain); with
    ``gradient=True`` also the derivatives by position and by axis, each ``(N, n_coils, 3)``."""
    S, off = _check_segments(segments, offsets)
    P = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    U = np.asarray(axes, dtype=np.float64).reshape(-1, 3)
    U = np.ascontiguousarray(U / np.linalg.norm(U, axis=1, keepdims=True))
    g = _readonly(np.ascontiguousarray(np.broadcast_to(np.asarray(gains, np.float64),
                                                       (len(off) - 1,))))
    nodes, weights = sensor_rule(float(sensor_length))
    return _coupling_batch(S, off, g, P, U, nodes, weights, gradient, gradient)


@njit(cache=True)
def _coupling_batch_impl(S, off, g, P, U, nodes, weights, grad):
    n, nc = P.shape[0], off.shape[0] - 1
    C = np.empty((n, nc))
    dp = np.zeros((n, nc, 3))
    du = np.zeros((n, nc, 3))
    for k in range(n):
        coupling_point(S, off, g, P[k], U[k], nodes, weights, C[k], dp[k], du[k], grad)
    return C, dp, du


def _coupling_batch(S, off, g, P, U, nodes, weights, grad, ret_grad):
    C, dp, du = _coupling_batch_impl(S, off, g, P, U, nodes, weights, grad)
    return (C, dp, du) if ret_grad else C
