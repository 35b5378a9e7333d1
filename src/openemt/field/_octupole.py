"""Axial octupole (finite-size) terms of the coils and a dipole-plus-octupole coupling model.

A coil of finite size with an axis of symmetry and no net quadrupole (centred winding) has, after
its dipole term, an axial octupole (zonal harmonic l = 3). With the dipole written as the
scalar potential ``Phi_1 = |M| P_1(c) / d^2`` (so ``B = -grad Phi`` is the usual dipole field
``(3 (M.u) u - M) / d^3``), the octupole of the same coil is ``Phi_3 = kappa |M| P_3(c) / d^4``,
``c = n . u``, with a strength ``kappa`` in m^2 (of the order of the coil radius squared; its
sign depends on the winding's aspect ratio). Writing ``a = M.u``, ``b = m.u``, ``g = M.m`` and
``mu2 = |M|^2``, the coupling into a point sensor of moment ``m`` is::

    C3 = -gain kappa / (2 mu2 d^5) * (15 a^2 g - 3 g mu2 - 35 a^3 b + 15 a b mu2)

It is homogeneous of degree one in ``M`` and in ``m``, like the dipole coupling. A finite sensor
coil in the field of a point source has the same form with the roles of the two coils swapped
(reciprocity). The sum of the dipole model and these terms is :class:`OctupoleModel`; calibrations store the
strengths in ``Calibration.extra['rig']`` (``octupole_k_so``, ``octupole_k_se``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._errors import InputError
from ..geometry import check_poses
from ._dipole import CouplingJacobians, DipoleModel, coupling_jacobians

__all__ = ["OctupoleModel", "octupole_coupling"]


def _cross(a, b):
    """``a x b`` over the last axis (broadcasting), without :func:`numpy.cross`'s overhead."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def _dot(a, b):
    """``a . b`` over the last axis of 3-vectors (broadcasting)."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def _vec(cu, u, cM, M, cm, m):
    """``cu u + cM M + cm m`` for coefficients ``(...)`` and vectors ``(..., 3)``."""
    return cu[..., None] * u + cM[..., None] * M + cm[..., None] * m


def octupole_coupling(model: DipoleModel, k_so, k_se, R, t, want_grad=False):
    """Octupole couplings ``(N, n_so, n_se)`` of a dipole model's coils with strengths
    ``k_so (n_so,)`` and ``k_se (n_se,)`` (m^2) for poses ``R (N, 3, 3)``, ``t (N, 3)``.

    With ``want_grad`` also returns a dict of gradients shaped like
    :class:`~openemt.field.CouplingJacobians` fields plus ``d_k_so``/``d_k_se``
    ``(N, n_so, n_se)`` (``C`` for unit strength of the coil concerned).

    The source coil's octupole is ``C3`` of the module doc with ``a = M.u``, ``b = m.u``; the
    sensor coil's, by reciprocity, the same form with the roles of ``M`` and ``m`` swapped
    (seen from the sensor, ``u -> -u``: ``a -> -b``, ``b -> -a``), so both share ``d``,
    ``u``, ``a``, ``b`` and ``g``. Coils at zero distance give NaN (the field is undefined
    there), without a warning.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        return _octupole_values(model, k_so, k_se, R, t, want_grad)


def _octupole_values(model, k_so, k_se, R, t, want_grad):
    k_so = np.asarray(k_so, dtype=np.float64)[None, :, None]
    k_se = np.asarray(k_se, dtype=np.float64)[None, None, :]
    R = np.asarray(R, dtype=np.float64)
    Lr = np.matmul(R, model.L_se).transpose(0, 2, 1)                # (N, n_se, 3)
    p = Lr + t[:, None, :]
    mv = np.matmul(R, model.M_se).transpose(0, 2, 1)[:, None]       # (N, 1, n_se, 3)
    Mv = model.M_so.T[None, :, None, :]                              # (1, n_so, 1, 3)
    r = p[:, None, :, :] - model.L_so.T[None, :, None, :]           # (N, n_so, n_se, 3)
    d2 = _dot(r, r)
    d = np.sqrt(d2)
    inv_d = 1.0 / d
    u = r * inv_d[..., None]
    a = _dot(Mv, u)
    b = _dot(mv, u)
    g = _dot(Mv, mv)
    mu2 = _dot(Mv, Mv)                   # |M|^2 (source), |m|^2 (sensor)
    nu2 = _dot(mv, mv)
    a2, b2 = a * a, b * b
    ab = a * b
    # source octupole (first moment M) and sensor octupole (first moment m, u -> -u)
    fs = 15 * a2 * g - 3 * g * mu2 - 35 * a2 * ab + 15 * ab * mu2
    fe = 15 * b2 * g - 3 * g * nu2 - 35 * b2 * ab + 15 * ab * nu2
    d5 = d2 * d2 * d
    Ks = -0.5 * model.gain / (mu2 * d5)
    Ke = -0.5 * model.gain / (nu2 * d5)
    Cs, Ce = Ks * fs, Ke * fe
    C = Cs * k_so + Ce * k_se
    if not want_grad:
        return C, None
    # partial derivatives of f: source (a, b, g, |M|^2), sensor in its own (a', b') = (-b, -a)
    fa = 30 * a * g - 105 * a2 * b + 15 * b * mu2
    fb = -35 * a2 * a + 15 * a * mu2
    fg = 15 * a2 - 3 * mu2
    fmu = -3 * g + 15 * ab
    fa_e = -30 * b * g + 105 * b2 * a - 15 * a * nu2
    fb_e = 35 * b2 * b - 15 * b * nu2
    fg_e = 15 * b2 - 3 * nu2
    ws, we = Ks * k_so, Ke * k_se
    # gradient with respect to r = p_j - L_so_i: da/dr = (M - a u) / d, db/dr = (m - b u) / d
    cM = (ws * fa - we * fb_e) * inv_d
    cm = (ws * fb - we * fa_e) * inv_d
    cu = -(ws * (fa * a + fb * b + 5 * fs) + we * (-fa_e * b - fb_e * a + 5 * fe)) * inv_d
    g_r = _vec(cu, u, cM, Mv, cm, mv)
    # with respect to the source moment M and the sensor moment m (source frame)
    g_M = _vec(ws * fa - we * fb_e, u, ws * (2 * fmu - 2 * fs / mu2), Mv, ws * fg + we * fg_e,
               mv)
    g_m = _vec(ws * fb - we * fa_e, u, ws * fg + we * fg_e, Mv,
               we * (2 * fmu - 2 * fe / nu2), mv)
    # p_j = R L_se_j + t, m_j = R M_se_j (as the dipole kernel)
    d_phi = _cross(Lr[:, None, :, :], g_r) + _cross(mv, g_m)
    Rb = R[:, None]
    grads = {
        "C": C, "d_translation": g_r, "d_rotation": d_phi, "d_L_so": -g_r, "d_M_so": g_M,
        "d_L_se": np.matmul(g_r, Rb), "d_M_se": np.matmul(g_m, Rb),
        "d_k_so": Cs, "d_k_se": Ce,
    }
    return C, grads


@dataclass(frozen=True, eq=False)
class OctupoleModel:
    """Dipole model plus an axial octupole per coil (finite coil size).

    Attributes
    ----------
    dipole : DipoleModel
    k_so : ndarray, shape (n_source,)
        Octupole strength of each source coil (m^2).
    k_se : ndarray, shape (n_sensor,)
        Octupole strength of each sensor coil (m^2).
    """

    dipole: DipoleModel
    k_so: np.ndarray
    k_se: np.ndarray
    kind = "octupole"

    def __post_init__(self):
        for name, n in (("k_so", self.dipole.n_source), ("k_se", self.dipole.n_sensor)):
            v = np.asarray(getattr(self, name), dtype=np.float64).reshape(-1)
            if v.shape != (n,) or not np.all(np.isfinite(v)):
                raise InputError(f"expected finite `{name}` of shape ({n},), got {v.shape}")
            object.__setattr__(self, name, v)

    @property
    def n_source(self) -> int:
        return self.dipole.n_source

    @property
    def n_sensor(self) -> int:
        return self.dipole.n_sensor

    def coupling(self, poses) -> np.ndarray:
        """Couplings ``(N, n_source, n_sensor)`` for poses ``(N, 4, 4)``."""
        P = check_poses(poses)
        C3, _ = octupole_coupling(self.dipole, self.k_so, self.k_se, P[:, :3, :3], P[:, :3, 3])
        return self.dipole.coupling(P) + C3

    def split_jacobians(self, poses) -> tuple[CouplingJacobians, np.ndarray, np.ndarray]:
        """Coupling derivatives of the sum (as :func:`~openemt.field.coupling_jacobians`) and the
        derivatives with respect to ``k_so`` and ``k_se`` (each ``(N, n_so, n_se)``, the
        coupling of unit strength of the coil concerned)."""
        P = check_poses(poses)
        jd = coupling_jacobians(self.dipole, P)
        _, g = octupole_coupling(self.dipole, self.k_so, self.k_se, P[:, :3, :3], P[:, :3, 3],
                                 want_grad=True)
        fields = {k: getattr(jd, k) + g[k] for k in ("C", "d_translation", "d_rotation",
                                                     "d_L_so", "d_M_so", "d_L_se", "d_M_se")}
        return CouplingJacobians(**fields), g["d_k_so"], g["d_k_se"]

    # -- the coupling-model interface (openemt.field.CouplingModel) ------------------------
    @property
    def gain(self) -> float:
        return self.dipole.gain

    @property
    def dof(self) -> int:
        return self.dipole.dof

    @property
    def params(self) -> np.ndarray:
        """The dipole's parameters, then ``k_so`` and ``k_se``."""
        return np.concatenate([self.dipole.params, self.k_so, self.k_se])

    def _k_slices(self):
        p = self.dipole.params.size
        return slice(p, p + self.n_source), slice(p + self.n_source,
                                                  p + self.n_source + self.n_sensor)

    @property
    def parameter_groups(self) -> dict:
        so, se = self._k_slices()
        return {**self.dipole.parameter_groups, "k_so": np.arange(so.start, so.stop),
                "k_se": np.arange(se.start, se.stop)}

    @property
    def gauge(self) -> np.ndarray:
        return self.dipole.gauge

    @property
    def fit_groups(self) -> tuple:
        return self.dipole.fit_groups + ("k_so", "k_se")

    @property
    def fixed_groups(self) -> tuple:
        return self.dipole.fixed_groups

    cold_start = "kim18"
    solver_family = "dipole-refined"

    def with_params(self, x) -> OctupoleModel:
        x = np.asarray(x, dtype=np.float64)
        so, se = self._k_slices()
        return OctupoleModel(self.dipole.with_params(x[:so.start]), x[so], x[se])

    def split_params(self, x) -> dict:
        so, se = self._k_slices()
        x = np.asarray(x, dtype=np.float64)
        return {**self.dipole.split_params(x[:so.start]), "k_so": x[so], "k_se": x[se]}

    def parameter_unit(self, i: int) -> tuple:
        so, _ = self._k_slices()
        return self.dipole.parameter_unit(i) if i < so.start else ("mm^2", 1e6)

    def parameter_label(self, i: int) -> str:
        so, se = self._k_slices()
        if i < so.start:
            return self.dipole.parameter_label(i)
        return f"k_so[{i - so.start}]" if i < so.stop else f"k_se[{i - se.start}]"

    def jacobians(self, poses, params: bool = True):
        """:class:`~openemt.field.ModelJacobians` of the sum."""
        from ._dipole import param_jacobian
        from ._protocol import ModelJacobians

        jac, dks, dke = self.split_jacobians(poses)
        if not params:
            return ModelJacobians(jac.C, jac.d_translation, jac.d_rotation, None)
        d = np.concatenate([param_jacobian(self.dipole, jac), np.zeros(jac.C.shape + (
            self.n_source + self.n_sensor,))], axis=-1)
        so, se = self._k_slices()
        for i in range(self.n_source):
            d[:, i, :, so.start + i] = dks[:, i, :]
        for j in range(self.n_sensor):
            d[:, :, j, se.start + j] = dke[:, :, j]
        return ModelJacobians(jac.C, jac.d_translation, jac.d_rotation, d)

    def packed(self):
        return self.dipole.packed(), self.k_so, self.k_se

    def describe(self) -> dict:
        return {**self.dipole.describe(), "model_kind": self.kind, "k_so": self.k_so,
                "k_se": self.k_se}
