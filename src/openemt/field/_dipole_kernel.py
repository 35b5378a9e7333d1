"""Compiled per-sample kernel of the dipole coupling model and its analytic derivatives.

This is the one implementation of seed 000 eqs. 3-5. The batched numpy API in ``_dipole.py``
and the compiled solvers call these functions; nothing else re-derives the formula.

Conventions (all arrays float64, C-contiguous):
  L_so, M_so : (3, n_so)  source coil positions (m) and moments (gain units), source frame
  L_se, M_se : (3, n_se)  sensor coil positions and moments, sensor frame
  R, t       : (3, 3), (3,)  pose of the sensor in the source frame
  gain       : scalar, C = gain * m_se . B, B = (3 (M.u) u - M) / d^3  (ILEMT uses 1/250)
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
    p = np.empty(3)
    m = np.empty(3)
    Lr = np.empty(3)
    for j in range(n_se):
        for a in range(3):
            Lr[a] = R[a, 0] * L_se[0, j] + R[a, 1] * L_se[1, j] + R[a, 2] * L_se[2, j]
            p[a] = Lr[a] + t[a]
            m[a] = R[a, 0] * M_se[0, j] + R[a, 1] * M_se[1, j] + R[a, 2] * M_se[2, j]
        for i in range(n_so):
            rx = p[0] - L_so[0, i]
            ry = p[1] - L_so[1, i]
            rz = p[2] - L_so[2, i]
            d2 = rx * rx + ry * ry + rz * rz
            d = np.sqrt(d2)
            inv_d3 = 1.0 / (d2 * d)
            inv_d5 = inv_d3 / d2
            Mx = M_so[0, i]
            My = M_so[1, i]
            Mz = M_so[2, i]
            Mr = Mx * rx + My * ry + Mz * rz
            mr = m[0] * rx + m[1] * ry + m[2] * rz
            Mm = Mx * m[0] + My * m[1] + Mz * m[2]
            C[i, j] = gain * (3.0 * Mr * mr * inv_d5 - Mm * inv_d3)
            if want_jac:
                inv_d7 = inv_d5 / d2
                r0 = (rx, ry, rz)
                Mv = (Mx, My, Mz)
                # gradient with respect to the sensor coil position p_j
                for a in range(3):
                    g = (3.0 * mr * Mv[a] * inv_d5 + 3.0 * Mr * m[a] * inv_d5
                         - 15.0 * Mr * mr * r0[a] * inv_d7 + 3.0 * Mm * r0[a] * inv_d5)
                    dC_dt[i, j, a] = gain * g
                    # B field of source coil i at p_j (d C / d m_j)
                    dC_dMse_src[i, j, a] = gain * (3.0 * Mr * r0[a] * inv_d5 - Mv[a] * inv_d3)
                    # d C / d M_so[:, i] (symmetric in the two moments)
                    dC_dMso[i, j, a] = gain * (3.0 * mr * r0[a] * inv_d5 - m[a] * inv_d3)
                # rotation: dp = phi x (R L), dm = phi x m  =>  dC/dphi = (R L) x gp + m x gm
                gp0 = dC_dt[i, j, 0]
                gp1 = dC_dt[i, j, 1]
                gp2 = dC_dt[i, j, 2]
                gm0 = dC_dMse_src[i, j, 0]
                gm1 = dC_dMse_src[i, j, 1]
                gm2 = dC_dMse_src[i, j, 2]
                dC_dphi[i, j, 0] = (Lr[1] * gp2 - Lr[2] * gp1) + (m[1] * gm2 - m[2] * gm1)
                dC_dphi[i, j, 1] = (Lr[2] * gp0 - Lr[0] * gp2) + (m[2] * gm0 - m[0] * gm2)
                dC_dphi[i, j, 2] = (Lr[0] * gp1 - Lr[1] * gp0) + (m[0] * gm1 - m[1] * gm0)


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

