"""Coupling models behind one interface (:class:`CouplingModel`): the dipole model with analytic Jacobians, axial octupole terms of finite
coils, and finite-size coils on magpylib."""

from .._lazy import lazy_exports

#: where each public name lives; a module is imported on first use of one of its names
_SOURCES = {
    "._coils": ("ANSER_COIL_CENTERS", "ANSER_ROTATED_COILS", "COIL_KINDS", "Coil",
                "anser_field_generator", "circular_coil", "coil_fields", "square_coil",
                "square_spiral_coil"),
    "._dipole": ("ILEMT_GAIN", "CouplingJacobians", "DipoleModel", "check_dipole_model", "coupling",
                 "coupling_jacobian_pose", "coupling_jacobians"),
    "._environment": ("EnvironmentModel", "EnvironmentTerms"),
    "._finite": ("FiniteCoilModel",),
    "._octupole": ("OctupoleModel", "octupole_coupling"),
    "._protocol": ("CouplingModel", "ModelJacobians", "check_coupling_model", "numeric_jacobians",
                   "solver_family"),
}
__all__, __getattr__, __dir__ = lazy_exports(__name__, _SOURCES)
