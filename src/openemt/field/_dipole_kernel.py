"""Compiled per-sample kernel of the dipole coupling model and its analytic derivatives.

This is the one implementation of MacLachlan et al. 2025, eqs. 3-5. The batched numpy API in ``_dipole.py``
and the compiled solvers call these functions; nothing else re-derives the formula.

Conventions (all arrays float64, C-contiguous):
  L_so, M_so : (3, n_so)  source coil positions (m) and moments (gain units), source frame
  L_se, M_se : (3, n_se)  sensor coil positions and moments, sensor frame
  R, t       : (3, 3), (3,)  pose of the sensor in the source frame
  gain       : scalar, C = gain * m_se . B, B = (3 (M.u) u - M) / d^3  (ILEMT uses 1/250)

A coil pair at zero distance (d = 0) has no defined coupling: its entries and derivatives are
NaN.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["dipole_batch", "dipole_batch_jac", "dipole_eval"]


@njit(cache=True, fastmath=False)
def dipole_eval(L_so, M_so, L_se, M_se, gain, R, t, C, dC_dt, dC_dphi, dC_dMso, dC_dMse_src,
                want_jac):
    """Coupling of one pose and, if ``want_jac``, its derivatives.

    Outputs (written in place):
      C        (n_so, n_se)
      dC_dt    (n_so, n_se, 3)  d C / d t (translation of the sensor, source frame)
      dC_dphi  (n_so, n_se, 3)  d C / d phi for a rotation R -> exp([phi]x) R (t fixed)
      dC_dMso  (n_so, n_se, 3)  d C[i, j] / d M_so[:, i]
      dC_dMse_src (n_so, n_se, 3) d C[i, j] / d m_j, with m_j = R M_se[:, j] in source axes
    The position gradient d C[i, j] / d p_j equals dC_dt[i, j]; from it follow the derivatives
    for L_so (negated) and L_se (rotated by R^T) -- see ``dipole_batch_jac``.
    """
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
        lx = R[0, 0] * L_se[0, j] + R[0, 1] * L_se[1, j] + R[0, 2] * L_se[2, j]
        ly = R[1, 0] * L_se[0, j] + R[1, 1] * L_se[1, j] + R[1, 2] * L_se[2, j]
        lz = R[2, 0] * L_se[0, j] + R[2, 1] * L_se[1, j] + R[2, 2] * L_se[2, j]
        px = lx + t[0]
        py = ly + t[1]
        pz = lz + t[2]
        mx = R[0, 0] * M_se[0, j] + R[0, 1] * M_se[1, j] + R[0, 2] * M_se[2, j]
        my = R[1, 0] * M_se[0, j] + R[1, 1] * M_se[1, j] + R[1, 2] * M_se[2, j]
        mz = R[2, 0] * M_se[0, j] + R[2, 1] * M_se[1, j] + R[2, 2] * M_se[2, j]
        for i in range(n_so):
            rx = px - L_so[0, i]
            ry = py - L_so[1, i]
            rz = pz - L_so[2, i]
            if rx != qx or ry != qy or rz != qz:
                d2 = rx * rx + ry * ry + rz * rz
                if d2 > 0.0:
                    inv_d2 = 1.0 / d2
                    inv_d3 = inv_d2 / np.sqrt(d2)
                    inv_d5 = inv_d3 * inv_d2
                else:
                    # coils at the same point: the dipole field is undefined there (NaN
                    # couplings and derivatives, never an exception)
                    inv_d2 = inv_d3 = inv_d5 = np.nan
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


@njit(cache=True)
def dipole_batch(L_so, M_so, L_se, M_se, gain, Rs, ts, C):
    """Couplings ``C (N, n_so, n_se)`` for poses ``Rs (N, 3, 3)``, ``ts (N, 3)``."""
    n_so = L_so.shape[1]
    n_se = L_se.shape[1]
    dummy = np.empty((n_so, n_se, 3))
    for k in range(Rs.shape[0]):
        dipole_eval(L_so, M_so, L_se, M_se, gain, Rs[k], ts[k], C[k], dummy, dummy, dummy,
                    dummy, False)


@njit(cache=True)
def dipole_batch_jac(L_so, M_so, L_se, M_se, gain, Rs, ts, C, dC_dt, dC_dphi, dC_dMso,
                     dC_dMse_src):
    """Couplings and per-sample derivatives for a batch (see ``dipole_eval``)."""
    for k in range(Rs.shape[0]):
        dipole_eval(L_so, M_so, L_se, M_se, gain, Rs[k], ts[k], C[k], dC_dt[k], dC_dphi[k],
                    dC_dMso[k], dC_dMse_src[k], True)

