"""Normalised calibration residuals and their analytic Jacobian (MacLachlan et al. 2025, §VI; docs/paper-procedure.md#calibration-objective).

For each row ``n`` the residual is ``(C_meas,n - C_pred(P_n, rho)) / ||C_meas,n||_2`` over all
``n_so * n_se`` entries, with the spectral norm of the measured matrix (the stored ILEMT
residuals are reproduced only with the spectral norm, not the Frobenius norm). The pose is
``P = F_so . so_J . F_st . st_J . F_se`` (MacLachlan et al. 2025, eq. 6).

Fixture derivatives use left twists ``xi = (rho, phi)`` (``P -> exp(xi) P``): a change
``(dt, dr)`` of a fixture pose vector ``v = (t, r)`` is the twist ``phi = J_l(r) dr``,
``rho = dt + t x phi`` on that fixture; it reaches ``P`` through the adjoint of everything to
the fixture's left, and a twist on ``P`` changes its translation by ``rho + phi x t_P`` and
rotates it by ``phi`` -- the quantities the dipole kernel differentiates against.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .._errors import InputError
from ..geometry import (
    adjoint,
    left_jacobian_so3,
    pose_from_vector,
    sensor_fixture_rotation,
    skew,
    source_fixture_rotation,
    stage_transform,
)
from ..solve import spectral_norms
from ._layout import ParameterLayout

__all__ = ["CalibrationProblem", "build_problem", "fixture_twist_map", "pose_twist_gradient"]


def fixture_twist_map(v) -> np.ndarray:
    """``(6, 6)`` map from a pose-vector change ``(dt, dr)`` to the left twist ``(rho, phi)``."""
    v = np.asarray(v, dtype=np.float64)
    Jl = left_jacobian_so3(v[3:])
    T = np.zeros((6, 6))
    T[:3, :3] = np.eye(3)
    T[:3, 3:] = skew(v[:3]) @ Jl
    T[3:, 3:] = Jl
    return T


@dataclass(frozen=True, eq=False)
class CalibrationProblem:
    """Measured couplings and known motions of the rows used in a fit.

    Attributes
    ----------
    layout : ParameterLayout
    C_meas : ndarray, shape (N, n_so, n_se)
        Signed real measured couplings.
    weight : ndarray, shape (N,)
        ``1 / ||C_meas,n||_2`` (spectral norm).
    so_J : ndarray, shape (N, 4, 4)
        Known source-fixture motions (rotation only).
    st_J : ndarray, shape (N, 4, 4)
        Known stage-and-sensor-fixture motions.
    gain : float
        Coupling scale of the model (``1/250`` for ILEMT).
    whiten : ndarray, shape (N, m, m), optional
        Per-row whitening of the normalised residual (``m = n_so * n_se``): row n's residual is
        ``whiten[n] @ r_n``. ``None`` (the paper's objective) leaves the rows as they are; the
        reference fit's errors-in-variables weighting sets it (docs/reference-calibration.md#errors-in-variables).
    """

    layout: ParameterLayout
    C_meas: np.ndarray
    weight: np.ndarray
    so_J: np.ndarray
    st_J: np.ndarray
    gain: float
    whiten: np.ndarray | None = None

    @property
    def n_rows(self) -> int:
        return self.C_meas.shape[0]

    def poses(self, x) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Ground-truth poses ``P (N, 4, 4)`` plus the partial products needed by the Jacobian:
        ``A = F_so so_J`` (left of F_st), ``D = A F_st st_J`` (left of F_se), and ``F_se``."""
        F_so, F_st, F_se = (pose_from_vector(f) for f in self.layout.fixtures(x))
        A = F_so @ self.so_J
        D = A @ F_st @ self.st_J
        return D @ F_se, A, D, F_se

    def predict(self, x) -> np.ndarray:
        """Predicted couplings ``(N, n_so, n_se)``."""
        P = self.poses(x)[0]
        return self.layout.model(x, self.gain).coupling(P)

    def with_whitening(self, whiten) -> CalibrationProblem:
        """The same problem with per-row whitening ``whiten`` ((N, m, m) or None)."""
        if whiten is not None:
            m = self.C_meas.shape[1] * self.C_meas.shape[2]
            whiten = np.asarray(whiten, dtype=np.float64)
            if whiten.shape != (self.n_rows, m, m):
                raise InputError(f"expected a whitening of shape ({self.n_rows}, {m}, {m}), "
                                 f"got {whiten.shape}")
        return replace(self, whiten=whiten)

    def _whitened(self, r, J=None):
        if self.whiten is None:
            return r.ravel(), None if J is None else J.reshape(r.size, -1)
        n = self.n_rows
        rw = np.einsum("kab,kb->ka", self.whiten, r.reshape(n, -1)).ravel()
        if J is None:
            return rw, None
        Jw = np.einsum("kab,kbp->kap", self.whiten, J.reshape(n, -1, J.shape[-1]))
        return rw, Jw.reshape(r.size, -1)

    def residuals(self, x) -> np.ndarray:
        """Normalised residual vector ``(N * n_so * n_se,)`` (whitened when ``whiten`` is
        set)."""
        return self._whitened((self.C_meas - self.predict(x)) * self.weight[:, None, None])[0]

    def residuals_and_jacobian(self, x) -> tuple[np.ndarray, np.ndarray]:
        """Residuals ``(m,)`` and their Jacobian ``(m, layout.size)`` w.r.t. the full vector."""
        P, A, D, _ = self.poses(x)
        jac = self.layout.model(x, self.gain).jacobians(P)
        dC, _ = self.gradients(x, jac, P, A, D)
        r = (self.C_meas - jac.C) * self.weight[:, None, None]
        J = dC * -self.weight[:, None, None, None]
        return self._whitened(r, J)

    def pose_gradient(self, x) -> tuple[np.ndarray, np.ndarray]:
        """Normalised residuals ``(N, m)`` (not whitened) and their derivative ``(N, m, 6)``
        with respect to a right perturbation ``(dt, dphi)`` of ``st_J`` (a translation and a
        small rotation in the moving frame of the known motion, e.g. a reference tool's noise
        as :func:`openemt.simulate.simulate_reference` draws it)."""
        P, A, D, _ = self.poses(x)
        jac = self.layout.model(x, self.gain).jacobians(P)
        H = pose_twist_gradient(jac.d_translation, jac.d_rotation, P)
        # with D = F_so so_J F_st st_J: D exp(d) F_se = exp(Ad(D) d) D F_se, a left twist
        # Ad(D) d of P
        n = self.n_rows
        G = np.einsum("kijb,kbc->kijc", H, adjoint(D)) * -self.weight[:, None, None, None]
        r = (self.C_meas - jac.C) * self.weight[:, None, None]
        return r.reshape(n, -1), G.reshape(n, -1, 6)

    def gradients(self, x, jac, P, A, D) -> tuple[np.ndarray, np.ndarray]:
        """Derivatives of the predicted couplings.

        Parameters
        ----------
        x : ndarray, shape (layout.size,)
        jac : openemt.field.ModelJacobians
            Coupling derivatives at the poses ``P`` (the model's ``jacobians``).
        P, A, D : ndarray, shape (N, 4, 4)
            Poses and the partial products of :meth:`poses`.

        Returns
        -------
        dC : ndarray, shape (N, n_so, n_se, layout.size)
            ``d C_pred / d x``.
        H : ndarray, shape (N, n_so, n_se, 6)
            ``d C_pred`` with respect to a left twist ``(rho, phi)`` of ``P`` (for further
            parameters that move ``P``: transport their twist with the adjoint of whatever
            stands to their left).
        """
        lay = self.layout
        n, ns, ne = jac.C.shape
        J = np.zeros((n, ns, ne, lay.size))
        J[..., lay.slices["model"]] = jac.d_params
        H = pose_twist_gradient(jac.d_translation, jac.d_rotation, P)
        F_so_v, F_st_v, F_se_v = lay.fixtures(x)
        J[..., lay.slices["F_so"]] = H @ fixture_twist_map(F_so_v)
        J[..., lay.slices["F_st"]] = np.einsum("kijb,kbc->kijc", H,
                                               adjoint(A) @ fixture_twist_map(F_st_v))
        J[..., lay.slices["F_se"]] = np.einsum("kijb,kbc->kijc", H,
                                               adjoint(D) @ fixture_twist_map(F_se_v))
        return J, H


def pose_twist_gradient(d_translation, d_rotation, P) -> np.ndarray:
    """Gradient ``(N, ..., 6)`` with respect to a left twist ``(rho, phi)`` of the poses ``P``.

    A twist moves the translation by ``rho + phi x t_P`` and rotates by ``phi``, so the phi part
    gains ``-G_t [t_P]x`` on top of the rotation gradient.
    """
    G_t = d_translation
    return np.concatenate(
        [G_t, d_rotation - np.einsum("kija,kab->kijb", G_t, skew(P[:, :3, 3]))], axis=-1)


def build_problem(dataset, layout: ParameterLayout, gain: float) -> CalibrationProblem:
    """Assemble a :class:`CalibrationProblem` from every row of ``dataset``.

    The target and the normalisation both use the signed real coupling (docs/paper-procedure.md#calibration-objective).
    """
    C = dataset.signed_real()
    if (C.shape[1], C.shape[2]) != (layout.n_source, layout.n_sensor):
        raise InputError(f"expected couplings with {layout.n_source} x {layout.n_sensor} coils, "
                         f"got {C.shape[1]} x {C.shape[2]}")
    n = C.shape[0]
    if n == 0:
        raise InputError("expected at least one calibration row, got 0")
    norms = spectral_norms(C)
    if not np.all(np.isfinite(norms)) or np.any(norms <= 0):
        raise InputError("expected finite, non-zero coupling matrices, got zero or NaN rows")
    so_J = np.zeros((n, 4, 4))
    so_J[:, 3, 3] = 1.0
    codes = np.asarray(dataset.source_fixture)
    for code in np.unique(codes):
        so_J[codes == code, :3, :3] = source_fixture_rotation(str(code))
    # st_J = stage transform . S(code): one fixture rotation per distinct code
    st_J = stage_transform(dataset.stage)
    se_codes = np.asarray(dataset.sensor_fixture)
    for code in np.unique(se_codes):
        rows = se_codes == code
        st_J[rows, :3, :3] = st_J[rows, :3, :3] @ sensor_fixture_rotation(str(code))
    return CalibrationProblem(layout=layout, C_meas=C, weight=1.0 / norms,
                              so_J=so_J, st_J=st_J, gain=float(gain))
