"""The simulated tracker: ILEMT-style calibration apparatus, coil presets and error sources.

``simulate(preset, pattern, ...)`` returns a :class:`openemt.io.Dataset` with known true poses;
``truth_calibration(preset)`` gives the matching dipole-equivalent calibration.
"""

from .._lazy import lazy_exports

#: where each public name lives; a module is imported on first use of one of its names
_SOURCES = {
    "._apparatus": ("STAGE_SIGMA", "fixture_combinations", "scene_model", "simulate",
                    "truth_calibration"),
    "._errors": ("Distortion", "add_noise", "distortion_coupling", "drift_factors", "noise_sigma",
                 "polarizability"),
    "._hybrid": ("DISTORTION_SCALE", "EM_NOISE", "OPTICAL_NOISE", "draw_xy", "field_distortion",
                 "simulate_hybrid", "simulate_ndi_session"),
    "._metal": ("METAL_KINDS", "METAL_SCENES", "MetalObject", "MetalScene", "Motion", "load_scene",
                "metal_scene", "rig_volume"),
    "._metal_physics": ("MATERIALS", "Material", "get_material", "sheet_reflection", "skin_depth",
                        "sphere_polarizability"),
    "._patterns": ("GRID_PITCH", "PATTERNS", "STAGE_Z_LIMIT", "stage_pattern"),
    "._presets": ("PRESETS", "Preset", "get_preset"),
    "._reference": ("REFERENCE_KINDS", "ReferenceKind", "nominal_calibration",
                    "reference_truth_calibration", "simulate_reference", "working_volume"),
    "._workflow": ("SimulateOptions", "SimulateResult", "parse_distortion", "write_simulation"),
}
__all__, __getattr__, __dir__ = lazy_exports(__name__, _SOURCES)
