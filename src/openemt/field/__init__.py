"""Coupling models: the dipole model with analytic Jacobians, and finite-size coils."""

from ._dipole import (
    ILEMT_GAIN,
    CouplingJacobians,
    DipoleModel,
    coupling,
    coupling_jacobian_pose,
    coupling_jacobians,
)

__all__ = [
    "ILEMT_GAIN",
    "CouplingJacobians",
    "DipoleModel",
    "coupling",
    "coupling_jacobian_pose",
    "coupling_jacobians",
]
