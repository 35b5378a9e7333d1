"""Terms of the improved rig model beyond the paper's: the stage's rotary-axis error motions,
the acquisition's gain non-linearity and coupling offset, and an induced dipole.

Parameter groups of the improved rig model (:mod:`openemt.calibrate._improved`), tried by
``--improved`` on md rows (:data:`openemt.calibrate.TERMS`):

* **Rz error motions.** A rotary axis carries, besides its location errors (axis position and
  tilt, fitted elsewhere), six *error motions* that vary with its angle: radial and axial
  runout (3 translations), wobble (2 tilts) and angular positioning error (ISO 230-1;
  Schwenke et al., CIRP Annals 57(2), 2008). openemt writes them as a small pose
  ``E(theta) = exp(xi(theta))`` inserted between the translation stages and the rotation,
  ``xi(theta) = sum_k (sin(k theta) a_k + (1 - cos(k theta)) b_k)`` with ``a_k, b_k`` in R^6
  (translation m, rotation rad), ``k = 2..order + 1``. Every basis function vanishes at
  ``theta = 0``: the error at the home angle is part of the fixture transforms. The first
  harmonic is left out: once per revolution, a radial motion is the axis's position (the
  eccentricity ISO 230-7 removes from radial error motions) and a tilt motion is the axis's
  tilt, both already in the fixtures and ``rz_tilt``; with it the fit is singular.
* **Gain non-linearity.** A sensor channel whose gain changes with the signal level reads
  ``c_read = c (1 - beta_j |c|)``; the calibration fits ``beta_j`` per sensor coil and reads
  ``c = c_read (1 + beta_j |c_read|)`` (first order) before the coupling model.
* **Coupling offset.** A pose-independent coupling ``C0`` (crosstalk of the drive into the
  sensor channels) is subtracted from every reading.
* **Induced dipole.** The field of a conductive or magnetic object near the rig
  (:class:`InducedDipoles`).

Pure array functions and a thin model wrapper; the calibration problem wires them in.
"""

from __future__ import annotations

import numpy as np

from .._errors import InputError
from ..geometry import left_jacobian_so3, pose_from_vector, skew

__all__ = [
    "error_motion_basis",
    "error_motion_twists",
    "error_motion_vectors",
    "gain_linearise",
    "gain_linearise_gradient",
]


def error_motion_basis(theta, order: int) -> np.ndarray:
    """Basis ``(N, 2 order)`` of the Rz error motions: ``sin(k theta), 1 - cos(k theta)``,
    ``k = 2..order + 1``.

    Examples
    --------
    >>> import numpy as np
    >>> error_motion_basis(np.array([0.0, np.pi / 4]), 1).round(12).tolist()
    [[0.0, 0.0], [1.0, 1.0]]
    """
    th = np.asarray(theta, dtype=np.float64)
    cols = []
    for k in range(2, int(order) + 2):
        cols += [np.sin(k * th), 1.0 - np.cos(k * th)]
    return np.stack(cols, axis=-1) if cols else np.zeros(th.shape + (0,))


def error_motion_vectors(theta, coeffs) -> np.ndarray:
    """Error-motion pose vectors ``xi (N, 6)`` for coefficients ``coeffs (2 order, 6)``."""
    c = np.asarray(coeffs, dtype=np.float64).reshape(-1, 6)
    return error_motion_basis(theta, c.shape[0] // 2) @ c


def error_motion_twists(theta, coeffs) -> tuple[np.ndarray, np.ndarray]:
    """Error-motion poses ``E (N, 4, 4)`` and the map ``(N, 6, 12 order)`` from a change of the
    flattened coefficients to a left twist ``(rho, phi)`` of ``E``."""
    c = np.asarray(coeffs, dtype=np.float64).reshape(-1, 6)
    f = error_motion_basis(theta, c.shape[0] // 2)
    xi = f @ c
    Jl = left_jacobian_so3(xi[:, 3:])
    T = np.zeros((xi.shape[0], 6, 6))
    T[:, :3, :3] = np.eye(3)
    T[:, :3, 3:] = skew(xi[:, :3]) @ Jl
    T[:, 3:, 3:] = Jl
    # d xi / d c[b, :] = f[:, b] * I6 -> twist map T f_b, laid out coefficient-major
    M = np.einsum("kab,kf->kafb", T, f).reshape(xi.shape[0], 6, -1)
    return pose_from_vector(xi), M


def gain_linearise(C, beta) -> np.ndarray:
    """Couplings ``C (N, n_so, n_se)`` read through a gain ``1 - beta_j |c|`` of sensor channel
    ``j``, restored to first order: ``C (1 + beta_j |C|)``.

    Examples
    --------
    >>> import numpy as np
    >>> gain_linearise(np.array([[[2.0, -1.0]]]), [0.1, 0.0]).tolist()
    [[[2.4, -1.0]]]
    """
    C = np.asarray(C)
    return C * (1.0 + np.asarray(beta, dtype=np.float64) * np.abs(C))


def gain_linearise_gradient(C) -> np.ndarray:
    """``d gain_linearise(C, beta) / d beta_j``: ``(N, n_so, n_se, n_se)``, nonzero only in
    the column of channel ``j``."""
    C = np.asarray(C, dtype=np.float64)
    n, ns, ne = C.shape
    G = np.zeros((n, ns, ne, ne))
    for j in range(ne):
        G[:, :, j, j] = C[:, :, j] * np.abs(C[:, :, j])
    return G


class InducedDipoles:
    """A coupling model plus the field of a conductive or magnetic object near the rig.

    An object at ``q`` (source frame) carries, at each source coil's carrier, an induced moment
    ``mu_i`` (in phase with the drive, what the signed real coupling sees: eddy currents of a
    conductor or the magnetisation of iron, frequency-dependent). Its field reaches the sensor
    coils as that of a dipole at ``q``, so the coupling gains ``C_ind[i, j]`` = the dipole model
    of a "source coil" ``i`` at ``q`` with moment ``mu_i`` into sensor coil ``j`` (such metal
    distortions are reviewed by Kindratenko, "A survey of electromagnetic position tracker
    calibration techniques", Virtual Reality 5(3), 2000). ``base`` is a
    :class:`~openemt.field.DipoleModel`
    or :class:`~openemt.field.OctupoleModel`; ``coupling`` and ``split_jacobians`` follow the
    latter (``(CouplingJacobians, d_k_so, d_k_se)``, the last two None for a dipole base), and
    ``jacobians(poses, params=False)`` gives the pose derivatives of the model interface, so
    :func:`openemt.solve.refine_poses` refines poses with it.
    """

    def __init__(self, base, q, mu):
        from ..field import DipoleModel

        self.base = base
        self.dipole = getattr(base, "dipole", base)
        d = self.dipole
        q = np.asarray(q, dtype=np.float64)
        self.q = q
        self.mu = np.asarray(mu, dtype=np.float64).reshape(d.n_source, 3).T   # (3, n_so)
        self.induced = DipoleModel(gain=d.gain, L_so=np.repeat(q[:, None], d.n_source, axis=1),
                                   M_so=self.mu, L_se=d.L_se, M_se=d.M_se)
        self.n_source, self.n_sensor = d.n_source, d.n_sensor

    def coupling(self, poses) -> np.ndarray:
        return self.base.coupling(poses) + self.induced.coupling(poses)

    def induced_jacobians(self, poses):
        """:func:`openemt.field.coupling_jacobians` of the induced part alone (its ``d_L_so``
        and ``d_M_so`` are the derivatives with respect to ``q`` and ``mu_i``)."""
        from ..field import coupling_jacobians

        return coupling_jacobians(self.induced, poses)

    def jacobians(self, poses, params: bool = False):
        """Pose derivatives as the model interface gives them (:class:`~openemt.field.
        ModelJacobians`, no parameter part: the object's parameters are fitted by the improved
        problem), for :func:`openemt.solve.refine_poses`."""
        from ..field import ModelJacobians

        if params:
            raise InputError("expected params=False: an induced dipole's parameters belong to "
                             "the improved calibration problem, got params=True")
        jac, _, _ = self.split_jacobians(poses)
        return ModelJacobians(jac.C, jac.d_translation, jac.d_rotation, None)

    def split_jacobians(self, poses):
        from ..field import CouplingJacobians, coupling_jacobians

        if hasattr(self.base, "split_jacobians"):
            jb, dks, dke = self.base.split_jacobians(poses)
        else:
            jb, dks, dke = coupling_jacobians(self.base, poses), None, None
        ji = self.induced_jacobians(poses)
        fields = {k: getattr(jb, k) + (getattr(ji, k) if k in (
            "C", "d_translation", "d_rotation", "d_L_se", "d_M_se") else 0.0)
            for k in ("C", "d_translation", "d_rotation", "d_L_so", "d_M_so", "d_L_se",
                      "d_M_se")}
        return CouplingJacobians(**fields), dks, dke
