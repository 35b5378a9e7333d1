"""The coupling models the compiled LM kernels (:mod:`openemt.solve._lm`) accept, each as its
packed form, and the two functions the kernels call on whichever one they are given:

- ``unpack_any(mdl, scale)``: the unpacked model ``geo`` with its gain divided by ``scale``
  (the power of two the couplings were divided by);
- ``model_eval(geo, R, t, C, jac, want)``: the couplings of the pose ``(R, t)`` into ``C``
  ``(n_source, n_sensor)`` and, if ``want``, ``jac[0] = dC/dt`` and ``jac[1] = dC/dphi``
  (a rotation ``R -> exp([phi]x) R``), each ``(n_source, n_sensor, 3)``.

Both are resolved when a kernel is compiled, from the type of the packed model, so each model
gets its own specialisation of the one LM loop:

- a dipole model: one float64 array (:func:`~openemt.solve._packing.pack_model`), evaluated by
  :func:`openemt.field._dipole_kernel.dipole_eval`;
- a finite-coil board read by a sensor of one or more coils: the tuple of
  :func:`pack_board` (segments, coil offsets, coil gains, the sensor coils' axes and
  positions ``(3, n_sensor)`` in the sensor frame, their relative gains, the sensor's
  quadrature rule), evaluated coil by coil by the compiled segment kernel
  (:func:`openemt.field._segments.coupling_point`, as the 5-DOF board solver) in
  :func:`board_eval`. The axes come fourth, where a dipole model has its sensor moments (the
  LM's 5-DOF rotation basis reads that slot).
"""

from __future__ import annotations

import numpy as np
from numba import njit, types
from numba.extending import overload

from ..field._dipole_kernel import dipole_eval, unpack_model
from ..field._segments import coupling_point, sensor_rule

__all__ = ["board_eval", "is_board", "model_eval", "pack_board", "unpack_any"]


def pack_board(model) -> tuple:
    """The packed form of a :class:`~openemt.board.BoardModel` for the compiled LM kernels:
    ``(segments, offsets, gains, axes (3, n_sensor), positions (3, n_sensor), sensor_gains,
    nodes, weights)``."""
    S, off, g = model.packed()
    sensor = model.board.sensor
    nodes, weights = sensor_rule(model.sensor_length)
    c = np.ascontiguousarray
    return (c(S, dtype=np.float64), c(off, dtype=np.int64), c(g, dtype=np.float64),
            c(np.asarray(sensor.coil_axes(), np.float64).T),
            c(np.asarray(sensor.coil_positions(), np.float64).T),
            c(model.sensor_gains, dtype=np.float64), c(nodes), c(weights))


@njit(inline="always")
def board_eval(geo, R, t, C, jac, want):
    """:func:`model_eval` of a board (``geo`` from :func:`unpack_any` of :func:`pack_board`):
    sensor coil ``k`` sits at ``p = q + t``, ``q = R l_k``, with axis ``u = R a_k``; the
    coupling's derivatives are ``dC/dt = dC/dp`` and ``dC/dphi = q x dC/dp + u x dC/du``."""
    S, off, g, A, L, sg, nodes, wts, inv = geo
    dC_dt = jac[0]
    dC_dphi = jac[1]
    n_so = C.shape[0]
    n_se = C.shape[1]
    q = np.empty(3)
    p = np.empty(3)
    u = np.empty(3)
    Ck = np.empty(n_so)
    dp = np.empty((n_so, 3))
    du = np.empty((n_so, 3))
    for k in range(n_se):
        for a in range(3):
            q[a] = R[a, 0] * L[0, k] + R[a, 1] * L[1, k] + R[a, 2] * L[2, k]
            u[a] = R[a, 0] * A[0, k] + R[a, 1] * A[1, k] + R[a, 2] * A[2, k]
            p[a] = q[a] + t[a]
        coupling_point(S, off, g, p, u, nodes, wts, Ck, dp, du, want)
        f = sg[k] * inv
        for i in range(n_so):
            C[i, k] = f * Ck[i]
            if want:
                for a in range(3):
                    dC_dt[i, k, a] = f * dp[i, a]
                dC_dphi[i, k, 0] = f * (q[1] * dp[i, 2] - q[2] * dp[i, 1]
                                        + u[1] * du[i, 2] - u[2] * du[i, 1])
                dC_dphi[i, k, 1] = f * (q[2] * dp[i, 0] - q[0] * dp[i, 2]
                                        + u[2] * du[i, 0] - u[0] * du[i, 2])
                dC_dphi[i, k, 2] = f * (q[0] * dp[i, 1] - q[1] * dp[i, 0]
                                        + u[0] * du[i, 1] - u[1] * du[i, 0])


def is_board(mdl) -> bool:
    """Whether the numba type ``mdl`` is the packed form of :func:`pack_board`."""
    return isinstance(mdl, types.BaseTuple) and len(mdl) == 8


def unpack_any(mdl, scale):
    """The unpacked model of a packed one (compiled code only; see the module docstring)."""
    raise NotImplementedError("unpack_any runs in compiled kernels only")


def model_eval(geo, R, t, C, jac, want):
    """Couplings (and derivatives) of a pose (compiled code only; see the module docstring)."""
    raise NotImplementedError("model_eval runs in compiled kernels only")


@overload(unpack_any)
def _unpack_any(mdl, scale):
    if isinstance(mdl, types.Array):
        return lambda mdl, scale: unpack_model(mdl, scale)
    if is_board(mdl):
        def impl(mdl, scale):
            S, off, g, A, L, sg, nodes, wts = mdl
            return S, off, g, A, L, sg, nodes, wts, 1.0 / scale
        return impl
    return None


@overload(model_eval)
def _model_eval(geo, R, t, C, jac, want):
    if isinstance(geo, types.BaseTuple) and len(geo) == 5:
        return lambda geo, R, t, C, jac, want: dipole_eval(geo, R, t, C, jac, want)
    if isinstance(geo, types.BaseTuple) and len(geo) == 9:
        return lambda geo, R, t, C, jac, want: board_eval(geo, R, t, C, jac, want)
    return None
