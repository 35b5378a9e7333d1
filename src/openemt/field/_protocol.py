"""The one interface of every coupling model (docs/field-models.md#the-model-interface).

A coupling model predicts the ``(N, n_source, n_sensor)`` couplings of sensor poses
``(N, 4, 4)`` and exposes what calibration and pose solving need, whatever its physics (dipole
coils, dipole plus octupole terms, the finite coils of a planar board):

* ``kind`` (the file format's model block, docs/calibration-format.md), ``n_source``,
  ``n_sensor`` and ``dof`` (5 for a single sensor coil, whose roll is not measurable, else 6);
* ``coupling(poses)``;
* ``jacobians(poses, params=True)`` -> :class:`ModelJacobians`: the couplings and their
  derivatives with respect to the pose (translation and a left rotation ``R -> exp([phi]x) R``,
  both in the source frame) and, unless ``params`` is False, to the model's parameter vector;
* ``params`` (a flat vector), ``with_params(x)`` (the same model with other values),
  ``split_params(v)`` (a parameter-length vector, e.g. standard errors, as named arrays),
  ``parameter_groups`` (named index arrays into ``params``, the names calibration modes use),
  ``gauge`` (indices never fitted: the choices that fix the model's frame and scale),
  ``fit_groups`` / ``fixed_groups`` (the groups a calibration fits / holds by default) and
  ``parameter_label(i)`` / ``parameter_unit(i)`` (name, and report unit with its scale);
* ``cold_start``: the start name of its solver from no prior pose (``kim18``, ``grid``, ...);
* ``solver_family`` (optional, default ``'model'``): which solver
  :func:`openemt.solve.prepare` builds for it, through its registry
  (:data:`openemt.solve.SOLVER_FAMILIES`): ``'dipole'`` (the compiled dipole LM and the closed
  forms; the model has the dipole arrays ``L_so``, ``M_so``, ``L_se``, ``M_se``, ``gain``),
  ``'dipole-refined'`` (a dipole model with further terms: its ``dipole`` is solved, then the
  solution refined under the whole model), ``'planar'`` (the compiled 5-DOF board solver) or
  ``'model'`` (the interface-level LM, any model);
* ``packed()``: the model's arrays as the compiled kernels take them.

Compiled kernels stay specialised per model family (the dipole kernel, the segment kernel);
the interface is at the Python layer, so one fit engine (:mod:`openemt.calibrate`) and one
solver factory (:func:`openemt.solve.prepare`) serve every model.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from .._errors import InputError
from ..geometry import left_jacobian_so3

__all__ = ["CouplingModel", "ModelJacobians", "check_coupling_model", "numeric_jacobians",
           "solver_family"]


@dataclass(frozen=True, eq=False)
class ModelJacobians:
    """Couplings and derivatives of a batch of poses.

    Attributes
    ----------
    C : ndarray, shape (N, n_source, n_sensor)
    d_translation, d_rotation : ndarray, shape (N, n_source, n_sensor, 3)
        Gradient with respect to the pose translation and a left rotation ``exp([phi]x) R``.
    d_params : ndarray, shape (N, n_source, n_sensor, n_params), or None
        Gradient with respect to the model's parameter vector ``params`` (None when not asked
        for).
    """

    C: np.ndarray
    d_translation: np.ndarray
    d_rotation: np.ndarray
    d_params: np.ndarray | None

    def pose_vector(self, rotvecs) -> np.ndarray:
        """Jacobian with respect to ``[x, y, z, rx, ry, rz]``, ``(N, n_so, n_se, 6)``."""
        Jl = left_jacobian_so3(np.asarray(rotvecs, dtype=np.float64))
        d_rv = np.einsum("kija,kab->kijb", self.d_rotation, Jl)
        return np.concatenate([self.d_translation, d_rv], axis=-1)


@runtime_checkable
class CouplingModel(Protocol):
    """What every coupling model provides (see the module docstring)."""

    kind: str

    @property
    def n_source(self) -> int: ...

    @property
    def n_sensor(self) -> int: ...

    @property
    def dof(self) -> int: ...

    @property
    def params(self) -> np.ndarray: ...

    @property
    def parameter_groups(self) -> dict: ...

    @property
    def gauge(self) -> np.ndarray: ...

    @property
    def fit_groups(self) -> tuple: ...

    @property
    def fixed_groups(self) -> tuple: ...

    cold_start: str

    def coupling(self, poses) -> np.ndarray: ...

    def jacobians(self, poses, params: bool = True) -> ModelJacobians: ...

    def with_params(self, x): ...

    def split_params(self, x) -> dict: ...

    def parameter_label(self, i: int) -> str: ...

    def parameter_unit(self, i: int) -> tuple: ...

    def packed(self): ...


def check_coupling_model(model, what: str = "model"):
    """``model`` if it implements :class:`CouplingModel`, else a TypeError naming what is
    missing."""
    missing = [n for n in ("kind", "n_source", "n_sensor", "dof", "coupling", "jacobians",
                           "params", "with_params", "split_params", "parameter_groups", "gauge",
                           "fit_groups", "fixed_groups", "cold_start")
               if not hasattr(model, n)]
    if missing:
        raise TypeError(f"expected `{what}` to be a coupling model (openemt.field.CouplingModel"
                        f"), got {type(model).__name__} without {missing}")
    return model


def solver_family(model) -> str:
    """The solver family ``model`` declares (``'model'`` when it declares none)."""
    return getattr(model, "solver_family", "model")


def numeric_jacobians(model, poses, *, step: float = 1e-6) -> ModelJacobians:
    """Central-difference :class:`ModelJacobians` of any model (for tests and checks; slow).

    Steps are ``step`` in metres / radians for the pose and ``step * max(1, |x_i|)`` for each
    parameter.
    """
    from ..geometry import check_poses, pose_from_vector

    def rotation_matrix(phi):
        return pose_from_vector(np.concatenate([np.zeros(3), phi]))[:3, :3]

    P = np.array(check_poses(poses), dtype=np.float64).reshape(-1, 4, 4)
    C = model.coupling(P)
    dt = np.empty(C.shape + (3,))
    dr = np.empty(C.shape + (3,))
    for a in range(3):
        e = np.zeros(3)
        e[a] = step
        for out, move in ((dt, "t"), (dr, "r")):
            Qp, Qm = P.copy(), P.copy()
            if move == "t":
                Qp[:, a, 3] += step
                Qm[:, a, 3] -= step
            else:
                Qp[:, :3, :3] = rotation_matrix(e) @ P[:, :3, :3]
                Qm[:, :3, :3] = rotation_matrix(-e) @ P[:, :3, :3]
            out[..., a] = (model.coupling(Qp) - model.coupling(Qm)) / (2 * step)
    x = np.asarray(model.params, dtype=np.float64)
    dp = np.empty(C.shape + (x.size,))
    for i in range(x.size):
        h = step * max(1.0, abs(x[i]))
        xp, xm = x.copy(), x.copy()
        xp[i] += h
        xm[i] -= h
        dp[..., i] = (model.with_params(xp).coupling(P) - model.with_params(xm).coupling(P)) \
            / (2 * h)
    if not np.all(np.isfinite(C)):
        raise InputError("expected finite couplings at the poses for a numeric Jacobian, got "
                         "NaN")
    return ModelJacobians(C, dt, dr, dp)
