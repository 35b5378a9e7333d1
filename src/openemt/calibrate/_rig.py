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
* **Induced dipole.** The field of a conductive or magnetic object near the rig: a dipole at
  ``q`` with a moment per source coil's carrier, the induced dipoles of
  :class:`openemt.field.EnvironmentModel` (the improved model is its base plus that term).

Pure array functions and a thin model wrapper; the calibration problem wires them in.
"""

from __future__ import annotations

import numpy as np

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
