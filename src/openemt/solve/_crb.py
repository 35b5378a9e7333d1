"""Cramer-Rao bound of the pose, and the solver's Gauss-Newton covariance.

For couplings ``c = f(pose) + e`` with Gaussian noise ``e ~ N(0, S)`` (``m = n_so n_se``
entries), the Fisher information of the pose parameters is ``F = J^T S^-1 J`` and any unbiased
estimator has covariance ``>= F^-1``. ``J`` is the analytic Jacobian of the dipole model
(``openemt.field.coupling_jacobians``).
"""

from __future__ import annotations

import numpy as np

from .._errors import InputError
from ..field import DipoleModel, check_dipole_model, coupling_jacobians
from ..geometry import check_poses, left_jacobian_so3, vector_from_pose

__all__ = ["cramer_rao", "solver_covariance"]


def _noise_cov(noise_sigma, n, m):
    s = np.asarray(noise_sigma, dtype=np.float64)
    if s.ndim == 0:
        return np.broadcast_to(np.eye(m) * float(s) ** 2, (n, m, m))
    if s.shape == (n,):
        return s[:, None, None] ** 2 * np.eye(m)
    if s.shape == (m, m):
        return np.broadcast_to(s, (n, m, m))
    if s.shape == (n, m, m):
        return s
    raise InputError(f"expected `noise_sigma` as a scalar, ({n},) sigmas, or a ({m}, {m}) or "
                     f"({n}, {m}, {m}) covariance of the flattened couplings, got {s.shape}")


def cramer_rao(model: DipoleModel, poses, noise_sigma, *, parametrization: str = "vector"
               ) -> np.ndarray:
    """Cramer-Rao lower bound of the pose covariance, shape (N, 6, 6).

    Parameters
    ----------
    model : DipoleModel
        The coupling model.
    poses : ndarray, shape (N, 4, 4)
        True sensor poses.
    noise_sigma : float, ndarray (N,), (m, m) or (N, m, m)
        Standard deviation of white noise on each coupling (per sample), or the covariance of
        the flattened couplings (``C[k].ravel()``, ``m = n_source * n_sensor``).
    parametrization : {'vector', 'local'}
        ``'vector'``: the pose vector ``[x, y, z, rx, ry, rz]`` (rotation vector).
        ``'local'``: ``[t, phi]`` with a small rotation ``R -> exp([phi]x) R`` (source frame),
        whose trace gives the mean squared rotation-error angle directly.

    Returns
    -------
    ndarray, shape (N, 6, 6)
        For a single-coil sensor (5-DOF) the roll about the sensor axis is unobservable; the
        bound is then the pseudo-inverse of the Fisher information (the roll direction carries
        zero variance and must not be read as known).
    """
    check_dipole_model(model)
    if parametrization not in ("vector", "local"):
        raise InputError(f"expected parametrization 'vector' or 'local', got {parametrization!r}")
    P = check_poses(poses, batch=True)
    n = P.shape[0]
    m = model.n_source * model.n_sensor
    jac = coupling_jacobians(model, P)
    J = np.concatenate([jac.d_translation, jac.d_rotation], axis=-1).reshape(n, m, 6)
    if parametrization == "vector":
        Jl = left_jacobian_so3(vector_from_pose(P)[:, 3:])
        J = J.copy()
        J[:, :, 3:] = J[:, :, 3:] @ Jl
    S = _noise_cov(noise_sigma, n, m)
    Sinv_J = np.linalg.solve(S, J)
    F = np.swapaxes(J, 1, 2) @ Sinv_J
    if model.n_sensor == 1:
        return np.linalg.pinv(F, hermitian=True)
    return np.linalg.inv(F)


def solver_covariance(model, result, C, cnorm=None) -> np.ndarray:
    """Per-pose covariance ``s^2 (J^T J)^-1`` at the solved poses, with the residual variance
    ``s^2 = SSR / (m - dof)`` estimated from each sample's own fit; NaN for invalid samples."""
    n = C.shape[0]
    m = model.n_source * model.n_sensor
    dof = 5 if model.n_sensor == 1 else 6
    out = np.full((n, 6, 6), np.nan)
    ok = np.all(np.isfinite(result.poses.reshape(n, -1)), axis=1)
    if m <= dof or not np.any(ok):
        return out
    pred = model.coupling(result.poses[ok])
    ssr = np.sum((pred - C[ok]) ** 2, axis=(1, 2))
    sigma = np.sqrt(ssr / (m - dof))
    sigma = np.where(sigma > 0, sigma, np.finfo(float).tiny)
    out[ok] = cramer_rao(model, result.poses[ok], sigma)
    return out
