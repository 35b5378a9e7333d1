"""The Cramer-Rao bound of the pose of any coupling model, from its analytic pose Jacobian.

For couplings ``c = f(pose) + e`` with white Gaussian noise of standard deviation ``sigma`` on
every entry, the Fisher information of the pose is ``F = J^T J / sigma^2`` where ``J`` is the
Jacobian of the flattened couplings with respect to ``[t, phi]`` (translation, and a left
rotation ``R -> exp([phi]x) R``, both in the source frame: the model's
``jacobians(poses, params=False)``, :class:`openemt.field.ModelJacobians`). For a single-coil
(5-DOF) sensor the rotation about the sensor axis is not observable; the rotation is then
parametrised by the two directions normal to the axis, so the bound is the inverse of a 5 x 5
Fisher information.

:func:`openemt.solve.cramer_rao` computes the same bound for the dipole model;
``tests/test_design.py`` checks the two against each other.
"""

from __future__ import annotations

import numpy as np

__all__ = ["PoseBound", "pose_bound"]


class PoseBound:
    """The bound at ``N`` poses.

    Attributes
    ----------
    position_cov : ndarray, shape (N, 3, 3)
        Bound of the position covariance (m^2).
    position_std : ndarray, shape (N,)
        ``sqrt(trace(position_cov))``: the bound of the RMS position error (m).
    rotation_std : ndarray, shape (N,)
        Bound of the RMS rotation-angle error (rad): for a 5-DOF sensor the angle of the sensor
        axis, for a 6-DOF sensor of the whole rotation.
    ok : ndarray of bool, shape (N,)
        False where the Fisher information is singular (the pose is not determined); the
        bounds there are inf.
    """

    def __init__(self, position_cov, rotation_cov, ok):
        self.position_cov = position_cov
        self.position_std = np.where(ok, np.sqrt(np.trace(position_cov, axis1=1, axis2=2)),
                                     np.inf)
        self.rotation_std = np.where(ok, np.sqrt(np.trace(rotation_cov, axis1=1, axis2=2)),
                                     np.inf)
        self.ok = ok


def pose_bound(model, poses, noise_sigma: float, *, jacobians=None) -> PoseBound:
    """The Cramer-Rao bound of the pose at ``poses (N, 4, 4)`` for white coupling noise of
    standard deviation ``noise_sigma`` (the couplings' units) on every coupling.

    ``jacobians`` (the model's :class:`~openemt.field.ModelJacobians` at these poses) may be
    given when already computed.
    """
    P = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    n = P.shape[0]
    jac = model.jacobians(P, params=False) if jacobians is None else jacobians
    m = model.n_source * model.n_sensor
    Jt = jac.d_translation.reshape(n, m, 3)
    Jr = jac.d_rotation.reshape(n, m, 3)
    if model.dof == 5:
        # the two rotation directions normal to the sensor axis: the axis is the direction
        # the couplings do not change with (the null vector of Jr^T Jr, exactly the coil axis
        # of a single-coil sensor)
        _, vecs = np.linalg.eigh(np.swapaxes(Jr, 1, 2) @ Jr)
        Jr = Jr @ vecs[:, :, 1:]
    J = np.concatenate([Jt, Jr], axis=-1) / float(noise_sigma)
    F = np.swapaxes(J, 1, 2) @ J
    k = F.shape[-1]
    cond = np.linalg.cond(F)
    ok = np.isfinite(cond) & (cond < 1e14)
    cov = np.full_like(F, np.nan)
    if np.any(ok):
        cov[ok] = np.linalg.inv(F[ok])
    cov[~ok] = 0.0
    return PoseBound(cov[:, :3, :3], cov[:, 3:k, 3:k], ok)

