"""Constant-velocity Kalman filter of a pose stream (position and orientation), per sensor.

Position: each axis is a constant-velocity model driven by white acceleration of spectral
density ``q**2`` (``q`` = ``process_noise``, m/s^2/sqrt(Hz)); the state ``(x, v)`` is
predicted over the sample interval ``dt`` with

    F = [[1, dt], [0, 1]],   Q = q**2 [[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]]

(Bar-Shalom, Li and Kirubarajan 2001, "Estimation with Applications to Tracking and
Navigation", §6.2.2) and corrected with the measured position of noise ``r`` per axis
(``measurement_noise``, m). The three axes share one 2x2 covariance (same noise, same
measurement times).

Orientation: the same model on rotation-vector increments (a multiplicative error-state
filter). The orientation ``R`` is predicted with the world-frame angular velocity ``w`` as
``exp([w dt]x) R``; the innovation is the rotation vector ``e = log(R_meas R_pred^T)``, and
the correction ``R <- exp([k0 e]x) R_pred``, ``w <- w + k1 e`` uses the gains of the 2x2
covariance of ``(angle, angular velocity)`` with ``rotation_process_noise`` and
``rotation_measurement_noise``.

A sample that is not valid (solver status not converged), or a gap between valid samples longer
than ``max_gap`` seconds, restarts the filter at the next valid measurement: the output then
equals the measurement and the velocity starts at zero with a wide variance. The steady-state
response to a position step is stated in docs/live.md#filter.

:func:`kalman_filter_poses` is a pure array function over a block of samples that carries the
filter state from one block to the next; the loop runs in a compiled kernel.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .._compile_notice import warm_up_with
from .._errors import InputError
from ..solve._linalg import exp_so3, rotvec_from_matrix, store_pose

__all__ = ["STATE_SIZE", "filter_restarts", "kalman_filter_poses", "new_filter_state"]

#: Length of the filter state vector (see :func:`new_filter_state`).
STATE_SIZE = 22

# initial standard deviation of the velocity at a (re)start: 1 m/s and 10 rad/s
_V0 = 1.0
_W0 = 10.0


def new_filter_state() -> np.ndarray:
    """A fresh (not started) filter state.

    Layout: ``[started, t_last, x(3), v(3), rotvec(3), w(3), P_pos(00, 01, 11),
    P_rot(00, 01, 11), ever_started, restarts]`` (``restarts`` counts the restarts after a
    loss or a gap, see :func:`filter_restarts`).
    """
    return np.zeros(STATE_SIZE)


@njit(cache=True, inline="always")
def _predict(P, o, dt, q2):
    p00, p01, p11 = P[o], P[o + 1], P[o + 2]
    n00 = p00 + 2.0 * dt * p01 + dt * dt * p11 + q2 * dt ** 3 / 3.0
    n01 = p01 + dt * p11 + q2 * dt * dt / 2.0
    n11 = p11 + q2 * dt
    P[o], P[o + 1], P[o + 2] = n00, n01, n11


@njit(cache=True, inline="always")
def _gains(P, o, r2):
    s = P[o] + r2
    k0 = P[o] / s
    k1 = P[o + 1] / s
    p00, p01, p11 = P[o], P[o + 1], P[o + 2]
    P[o] = (1.0 - k0) * p00
    P[o + 1] = (1.0 - k0) * p01
    P[o + 2] = p11 - k1 * p01
    return k0, k1


@njit(cache=True)
def _kalman_kernel(vecs, times, valid, params, state, out_poses, out_vecs):
    q2, r2 = params[0] ** 2, params[1] ** 2
    qr2, rr2 = params[2] ** 2, params[3] ** 2
    max_gap = params[4]
    R = np.empty((3, 3))
    Rm = np.empty((3, 3))
    dR = np.empty((3, 3))
    tmp = np.empty((3, 3))
    phi = np.empty(3)
    e = np.empty(3)
    t = np.empty(3)
    rv = np.empty(3)
    for k in range(vecs.shape[0]):
        if not valid[k]:
            state[0] = 0.0
            for i in range(6):
                out_vecs[k, i] = vecs[k, i]
            for i in range(3):
                phi[i] = vecs[k, 3 + i]
                t[i] = vecs[k, i]
            exp_so3(phi, R)
            store_pose(k, R, t, phi, out_poses, out_vecs)
            continue
        dt = times[k] - state[1]
        if state[0] == 0.0 or dt > max_gap or dt <= 0.0:
            if state[20] != 0.0:
                state[21] += 1.0
            state[20] = 1.0
            state[0] = 1.0
            for i in range(3):
                state[2 + i] = vecs[k, i]
                state[5 + i] = 0.0
                state[8 + i] = vecs[k, 3 + i]
                state[11 + i] = 0.0
            state[14], state[15], state[16] = r2, 0.0, _V0 * _V0
            state[17], state[18], state[19] = rr2, 0.0, _W0 * _W0
        else:
            # position: predict and correct (all axes share the covariance)
            _predict(state, 14, dt, q2)
            k0, k1 = _gains(state, 14, r2)
            for i in range(3):
                xp = state[2 + i] + dt * state[5 + i]
                y = vecs[k, i] - xp
                state[2 + i] = xp + k0 * y
                state[5 + i] += k1 * y
            # orientation: R_pred = exp(w dt) R; e = log(R_meas R_pred^T)
            for i in range(3):
                phi[i] = state[8 + i]
            exp_so3(phi, R)
            for i in range(3):
                phi[i] = state[11 + i] * dt
            exp_so3(phi, dR)
            for i in range(3):
                for j in range(3):
                    tmp[i, j] = dR[i, 0] * R[0, j] + dR[i, 1] * R[1, j] + dR[i, 2] * R[2, j]
            for i in range(3):
                phi[i] = vecs[k, 3 + i]
            exp_so3(phi, Rm)
            for i in range(3):
                for j in range(3):
                    dR[i, j] = Rm[i, 0] * tmp[j, 0] + Rm[i, 1] * tmp[j, 1] + Rm[i, 2] * tmp[j, 2]
            rotvec_from_matrix(dR, e)
            _predict(state, 17, dt, qr2)
            k0, k1 = _gains(state, 17, rr2)
            for i in range(3):
                phi[i] = k0 * e[i]
                state[11 + i] += k1 * e[i]
            exp_so3(phi, dR)
            for i in range(3):
                for j in range(3):
                    R[i, j] = dR[i, 0] * tmp[0, j] + dR[i, 1] * tmp[1, j] + dR[i, 2] * tmp[2, j]
            rotvec_from_matrix(R, rv)
            for i in range(3):
                state[8 + i] = rv[i]
        state[1] = times[k]
        for i in range(3):
            t[i] = state[2 + i]
            rv[i] = state[8 + i]
        exp_so3(rv, R)
        store_pose(k, R, t, rv, out_poses, out_vecs)


def filter_restarts(state) -> int:
    """Restarts of the filter after a loss or a gap so far (the first start not counted)."""
    return int(state[21])


def kalman_filter_poses(pose_vectors, times, valid, *, process_noise: float,
                        measurement_noise: float, rotation_process_noise: float,
                        rotation_measurement_noise: float, max_gap: float, state=None):
    """Filter a block of measured poses with the constant-velocity Kalman filter.

    Parameters
    ----------
    pose_vectors : ndarray, shape (N, 6)
        Measured ``[x, y, z, rx, ry, rz]`` (m, rad).
    times : ndarray, shape (N,)
        Sample times (s), increasing.
    valid : ndarray, shape (N,), bool
        False for samples without a pose (the filter restarts after them).
    process_noise, measurement_noise, rotation_process_noise, rotation_measurement_noise, max_gap
        See the module docstring (SI units).
    state : ndarray, shape (STATE_SIZE,), optional
        Filter state from the previous block, updated in place; None starts afresh.

    Returns
    -------
    poses : ndarray, shape (N, 4, 4)
    pose_vectors : ndarray, shape (N, 6)
        Filtered outputs (the input unchanged where ``valid`` is False).
    state : ndarray, shape (STATE_SIZE,)
    """
    v = np.ascontiguousarray(pose_vectors, dtype=np.float64)
    t = np.ascontiguousarray(times, dtype=np.float64)
    ok = np.ascontiguousarray(valid, dtype=np.bool_)
    n = v.shape[0]
    if v.ndim != 2 or v.shape[1] != 6 or t.shape != (n,) or ok.shape != (n,):
        raise InputError(f"expected pose_vectors (N, 6) with times (N,) and valid (N,), got "
                         f"{v.shape}, {t.shape} and {ok.shape}")
    params = np.array([process_noise, measurement_noise, rotation_process_noise,
                       rotation_measurement_noise, max_gap], dtype=np.float64)
    if not np.all(np.isfinite(params) & (params > 0)):
        raise InputError(f"expected positive filter noises and max_gap, got {params.tolist()}")
    if state is None:
        state = new_filter_state()
    elif state.shape != (STATE_SIZE,) or state.dtype != np.float64:
        raise InputError(f"expected a filter state of shape ({STATE_SIZE},) float64, got "
                         f"{state.shape} {state.dtype}")
    poses = np.empty((n, 4, 4))
    out = np.empty((n, 6))
    _kalman_kernel(v, t, ok, params, state, poses, out)
    return poses, out, state


def _warm_up():
    kalman_filter_poses(np.array([[0.3, 0.0, 0.0, 0.1, 0.2, 0.3]]), np.array([0.0]),
                        np.array([True]), process_noise=1.0, measurement_noise=1e-4,
                        rotation_process_noise=1.0, rotation_measurement_noise=1e-3,
                        max_gap=0.1)


warm_up_with("openemt.live._filter:_kalman_kernel", _warm_up)
