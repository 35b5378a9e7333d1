"""Compiled per-sample kernel of the dipole coupling model and its analytic derivatives.

This is the one implementation of MacLachlan et al. 2025, eqs. 3-5. The batched numpy API in ``_dipole.py``
and the compiled solvers call these functions; nothing else re-derives the formula.

Conventions (all arrays float64, C-contiguous):
  geo        : the tuple (L_so, M_so, L_se, M_se, gain) of :func:`unpack_model`
  L_so, M_so : (3, n_so)  source coil positions (m) and moments (gain units), source frame
  L_se, M_se : (3, n_se)  sensor coil positions and moments, sensor frame
  gain       : scalar, C = gain * m_se . B, B = (3 (M.u) u - M) / d^3  (ILEMT uses 1/250)
  R, t       : (3, 3), (3,)  pose of the sensor in the source frame

Compiled callers get a model as one packed float64 array (:func:`pack_model`: ``[n_source,
n_sensor, gain, L_so, M_so, L_se, M_se]``, matrices row-major), read through the named header
indices ``M_*``, rather than as separate arrays that could be passed in the wrong order.

A coil pair at zero distance (d = 0) has no defined coupling: its entries and derivatives are
NaN.

:func:`concentric_eval` is the same formula for the case of all coil positions zero (the
closed-form solvers' models), reorganised so that what the pairs share is computed once; it
returns :func:`dipole_eval`'s couplings bit for bit.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["M_GAIN", "M_N_SENSOR", "M_N_SOURCE", "concentric_eval", "dipole_batch",
           "dipole_batch_jac", "dipole_eval", "pack_model", "unpack_model"]

# packed model array: header entries, then the four coil matrices
M_N_SOURCE = 0
M_N_SENSOR = 1
M_GAIN = 2
_M_HEADER = 3


def pack_model(model) -> np.ndarray:
    """One float64 array holding a :class:`~openemt.field.DipoleModel`'s coils and gain."""
    parts = [np.array([model.n_source, model.n_sensor, model.gain], dtype=np.float64)]
    parts += [np.asarray(getattr(model, f), dtype=np.float64).ravel()
              for f in ("L_so", "M_so", "L_se", "M_se")]
    return np.concatenate(parts)


@njit(inline="always")
def unpack_model(mdl, scale):
    """``(L_so, M_so, L_se, M_se, gain / scale)``: views of a packed model array, with the gain
    divided by the scale the couplings were divided by (1 for none)."""
    n_so = int(mdl[M_N_SOURCE])
    n_se = int(mdl[M_N_SENSOR])
    o = _M_HEADER
    L_so = mdl[o:o + 3 * n_so].reshape((3, n_so))
    o += 3 * n_so
    M_so = mdl[o:o + 3 * n_so].reshape((3, n_so))
    o += 3 * n_so
    L_se = mdl[o:o + 3 * n_se].reshape((3, n_se))
    o += 3 * n_se
    M_se = mdl[o:o + 3 * n_se].reshape((3, n_se))
    return L_so, M_so, L_se, M_se, mdl[M_GAIN] / scale


@njit(inline="always")
def _rotated_column(R, A, j):
    """``R @ A[:, j]`` as three scalars (a sensor coil's offset or moment in source axes)."""
    return (R[0, 0] * A[0, j] + R[0, 1] * A[1, j] + R[0, 2] * A[2, j],
            R[1, 0] * A[0, j] + R[1, 1] * A[1, j] + R[1, 2] * A[2, j],
            R[2, 0] * A[0, j] + R[2, 1] * A[1, j] + R[2, 2] * A[2, j])


@njit(inline="always")
def _inverse_powers(d2):
    """``(1/d^2, 1/d^3, 1/d^5)`` of a squared distance; NaN for coils at the same point, where
    the dipole field is undefined (NaN couplings and derivatives, never an exception)."""
    if d2 > 0.0:
        inv_d2 = 1.0 / d2
        inv_d3 = inv_d2 / np.sqrt(d2)
        return inv_d2, inv_d3, inv_d3 * inv_d2
    return np.nan, np.nan, np.nan


@njit(cache=True)
def dipole_eval(geo, R, t, C, jac, want_jac):
    """Coupling of one pose and, if ``want_jac``, its derivatives
    ``jac = (dC_dt, dC_dphi, dC_dMso, dC_dMse_src)``.

    Outputs (written in place):
      C        (n_so, n_se)
      dC_dt    (n_so, n_se, 3)  d C / d t (translation of the sensor, source frame)
      dC_dphi  (n_so, n_se, 3)  d C / d phi for a rotation R -> exp([phi]x) R (t fixed)
      dC_dMso  (n_so, n_se, 3)  d C[i, j] / d M_so[:, i]
      dC_dMse_src (n_so, n_se, 3) d C[i, j] / d m_j, with m_j = R M_se[:, j] in source axes
    The position gradient d C[i, j] / d p_j equals dC_dt[i, j]; from it follow the derivatives
    for L_so (negated) and L_se (rotated by R^T) -- see ``dipole_batch_jac``.
    """
    L_so, M_so, L_se, M_se, gain = geo
    dC_dt, dC_dphi, dC_dMso, dC_dMse_src = jac
    n_so = L_so.shape[1]
    n_se = L_se.shape[1]
    # distance terms of the previous coil pair: coils at the same offset (concentric coils)
    # share them, so the square root and divisions are done once (same values, bit for bit)
    qx = np.nan
    qy = np.nan
    qz = np.nan
    inv_d2 = inv_d3 = inv_d5 = 0.0
    for j in range(n_se):
        # sensor coil j in the source frame (scalars: no per-call allocation)
        lx, ly, lz = _rotated_column(R, L_se, j)
        px = lx + t[0]
        py = ly + t[1]
        pz = lz + t[2]
        mx, my, mz = _rotated_column(R, M_se, j)
        for i in range(n_so):
            rx = px - L_so[0, i]
            ry = py - L_so[1, i]
            rz = pz - L_so[2, i]
            if rx != qx or ry != qy or rz != qz:
                inv_d2, inv_d3, inv_d5 = _inverse_powers(rx * rx + ry * ry + rz * rz)
                qx = rx
                qy = ry
                qz = rz
            Mx = M_so[0, i]
            My = M_so[1, i]
            Mz = M_so[2, i]
            Mr = Mx * rx + My * ry + Mz * rz
            mr = mx * rx + my * ry + mz * rz
            Mm = Mx * mx + My * my + Mz * mz
            C[i, j] = gain * (3.0 * Mr * mr * inv_d5 - Mm * inv_d3)
            if want_jac:
                inv_d7 = inv_d5 * inv_d2
                a5 = 3.0 * inv_d5
                # gradient with respect to the sensor coil position p_j
                c_r = 3.0 * Mm * inv_d5 - 15.0 * Mr * mr * inv_d7
                gpx = gain * (a5 * (mr * Mx + Mr * mx) + c_r * rx)
                gpy = gain * (a5 * (mr * My + Mr * my) + c_r * ry)
                gpz = gain * (a5 * (mr * Mz + Mr * mz) + c_r * rz)
                dC_dt[i, j, 0] = gpx
                dC_dt[i, j, 1] = gpy
                dC_dt[i, j, 2] = gpz
                # B field of source coil i at p_j (d C / d m_j)
                gmx = gain * (a5 * Mr * rx - Mx * inv_d3)
                gmy = gain * (a5 * Mr * ry - My * inv_d3)
                gmz = gain * (a5 * Mr * rz - Mz * inv_d3)
                dC_dMse_src[i, j, 0] = gmx
                dC_dMse_src[i, j, 1] = gmy
                dC_dMse_src[i, j, 2] = gmz
                # d C / d M_so[:, i] (symmetric in the two moments)
                dC_dMso[i, j, 0] = gain * (a5 * mr * rx - mx * inv_d3)
                dC_dMso[i, j, 1] = gain * (a5 * mr * ry - my * inv_d3)
                dC_dMso[i, j, 2] = gain * (a5 * mr * rz - mz * inv_d3)
                # rotation: dp = phi x (R L), dm = phi x m  =>  dC/dphi = (R L) x gp + m x gm
                dC_dphi[i, j, 0] = (ly * gpz - lz * gpy) + (my * gmz - mz * gmy)
                dC_dphi[i, j, 1] = (lz * gpx - lx * gpz) + (mz * gmx - mx * gmz)
                dC_dphi[i, j, 2] = (lx * gpy - ly * gpx) + (mx * gmy - my * gmx)


@njit(inline="always")
def concentric_eval(M_so, M_se, gain, R, t, C, m):
    """Couplings ``C (n_so, n_se)`` of one pose for coils all at the origin of their frames:
    the values of :func:`dipole_eval` with zero ``L_so`` and ``L_se`` for a finite ``R``, bit
    for bit (the same operations in the same order; the distance terms, the rotated sensor
    moments and their projections on ``t`` computed once instead of once per coil pair). No
    derivatives.
    ``m`` (4, n_se) is scratch; ``d = 0`` gives NaN couplings as in :func:`dipole_eval`."""
    n_so = M_so.shape[1]
    n_se = M_se.shape[1]
    # with zero coil offsets, dipole_eval's separation vector is t itself (0 + t, t - 0)
    rx = t[0]
    ry = t[1]
    rz = t[2]
    _, inv_d3, inv_d5 = _inverse_powers(rx * rx + ry * ry + rz * rz)
    for j in range(n_se):
        mx, my, mz = _rotated_column(R, M_se, j)
        m[0, j] = mx
        m[1, j] = my
        m[2, j] = mz
        m[3, j] = mx * rx + my * ry + mz * rz
    for i in range(n_so):
        Mx = M_so[0, i]
        My = M_so[1, i]
        Mz = M_so[2, i]
        Mr = Mx * rx + My * ry + Mz * rz
        for j in range(n_se):
            Mm = Mx * m[0, j] + My * m[1, j] + Mz * m[2, j]
            C[i, j] = gain * (3.0 * Mr * m[3, j] * inv_d5 - Mm * inv_d3)


@njit(cache=True)
def dipole_batch(mdl, Rs, ts, C):
    """Couplings ``C (N, n_so, n_se)`` of the packed model ``mdl`` for poses
    ``Rs (N, 3, 3)``, ``ts (N, 3)``."""
    geo = unpack_model(mdl, 1.0)
    dummy = np.empty((C.shape[1], C.shape[2], 3))
    jac = (dummy, dummy, dummy, dummy)
    # the flag as a run-time value (not a literal), so that every caller shares one compiled
    # specialisation of dipole_eval
    want = np.zeros(1, dtype=np.bool_)
    for k in range(Rs.shape[0]):
        dipole_eval(geo, Rs[k], ts[k], C[k], jac, want[0])


@njit(cache=True)
def dipole_batch_jac(mdl, Rs, ts, C, jac):
    """Couplings and per-sample derivatives ``jac = (dC_dt, dC_dphi, dC_dMso, dC_dMse_src)``
    (each (N, n_so, n_se, 3)) for a batch (see ``dipole_eval``)."""
    geo = unpack_model(mdl, 1.0)
    dt, dphi, dMso, dMse = jac
    want = np.ones(1, dtype=np.bool_)  # run-time flag, as in dipole_batch
    for k in range(Rs.shape[0]):
        dipole_eval(geo, Rs[k], ts[k], C[k], (dt[k], dphi[k], dMso[k], dMse[k]), want[0])

