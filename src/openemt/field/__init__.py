"""Coupling models behind one interface (:class:`CouplingModel`): the dipole model with analytic Jacobians, axial octupole terms of finite
coils, and finite-size coils on magpylib."""

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
    check_dipole_model,
    coupling,
    coupling_jacobian_pose,
    coupling_jacobians,
)
from ._environment import EnvironmentModel, EnvironmentTerms
from ._finite import FiniteCoilModel
from ._octupole import OctupoleModel, octupole_coupling
from ._protocol import (
    CouplingModel,
    ModelJacobians,
    check_coupling_model,
    numeric_jacobians,
    solver_family,
)

__all__ = [
    "ANSER_COIL_CENTERS",
    "ANSER_ROTATED_COILS",
    "COIL_KINDS",
    "ILEMT_GAIN",
    "Coil",
    "CouplingJacobians",
    "CouplingModel",
    "DipoleModel",
    "EnvironmentModel",
    "EnvironmentTerms",
    "FiniteCoilModel",
    "ModelJacobians",
    "OctupoleModel",
    "anser_field_generator",
    "check_coupling_model",
    "check_dipole_model",
    "circular_coil",
    "coil_fields",
    "coupling",
    "coupling_jacobian_pose",
    "coupling_jacobians",
    "numeric_jacobians",
    "octupole_coupling",
    "solver_family",
    "square_coil",
    "square_spiral_coil",
]
