"""Coupling models: the dipole model with analytic Jacobians, and finite-size coils."""

from ._coils import (
    ANSER_COIL_CENTERS,
    ANSER_ROTATED_COILS,
    COIL_KINDS,
    Coil,
    anser_field_generator,
    circular_coil,
    coil_fields,
    square_coil,
    square_spiral_coil,
)
from ._dipole import (
    ILEMT_GAIN,
    CouplingJacobians,
    DipoleModel,
    coupling,
    coupling_jacobian_pose,
    coupling_jacobians,
)
from ._finite import FiniteCoilModel

__all__ = [
    "ANSER_COIL_CENTERS",
    "ANSER_ROTATED_COILS",
    "COIL_KINDS",
    "ILEMT_GAIN",
    "Coil",
    "CouplingJacobians",
    "DipoleModel",
    "FiniteCoilModel",
    "anser_field_generator",
    "circular_coil",
    "coil_fields",
    "coupling",
    "coupling_jacobian_pose",
    "coupling_jacobians",
    "square_coil",
    "square_spiral_coil",
]
