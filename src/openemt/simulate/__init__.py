"""The simulated tracker: ILEMT-style calibration apparatus, coil presets and error sources.

``simulate(preset, pattern, ...)`` returns a :class:`openemt.io.Dataset` with known true poses;
``truth_calibration(preset)`` gives the matching dipole-equivalent calibration.
"""

from ._apparatus import (
    STAGE_SIGMA,
    fixture_combinations,
    scene_model,
    simulate,
    truth_calibration,
)
from ._errors import (
    Distortion,
    add_noise,
    distortion_coupling,
    drift_factors,
    noise_sigma,
    polarizability,
)
from ._hybrid import (
    DISTORTION_SCALE,
    EM_NOISE,
    OPTICAL_NOISE,
    draw_xy,
    field_distortion,
    simulate_hybrid,
    simulate_ndi_session,
)
from ._metal import (
    METAL_KINDS,
    METAL_SCENES,
    MetalObject,
    MetalScene,
    Motion,
    load_scene,
    metal_scene,
    rig_volume,
)
from ._metal_physics import (
    MATERIALS,
    Material,
    get_material,
    sheet_reflection,
    skin_depth,
    sphere_polarizability,
)
from ._patterns import GRID_PITCH, PATTERNS, STAGE_Z_LIMIT, stage_pattern
from ._presets import PRESETS, Preset, get_preset
from ._reference import (
    REFERENCE_KINDS,
    ReferenceKind,
    nominal_calibration,
    reference_truth_calibration,
    simulate_reference,
)
from ._workflow import SimulateOptions, SimulateResult, parse_distortion, write_simulation

__all__ = [
    "MATERIALS",
    "METAL_KINDS",
    "METAL_SCENES",
    "Material",
    "MetalObject",
    "MetalScene",
    "Motion",
    "get_material",
    "load_scene",
    "metal_scene",
    "rig_volume",
    "scene_model",
    "sheet_reflection",
    "skin_depth",
    "sphere_polarizability",
    "DISTORTION_SCALE",
    "EM_NOISE",
    "OPTICAL_NOISE",
    "draw_xy",
    "GRID_PITCH",
    "PATTERNS",
    "PRESETS",
    "REFERENCE_KINDS",
    "STAGE_SIGMA",
    "STAGE_Z_LIMIT",
    "Distortion",
    "Preset",
    "ReferenceKind",
    "SimulateOptions",
    "SimulateResult",
    "add_noise",
    "distortion_coupling",
    "drift_factors",
    "field_distortion",
    "fixture_combinations",
    "get_preset",
    "noise_sigma",
    "nominal_calibration",
    "parse_distortion",
    "polarizability",
    "reference_truth_calibration",
    "simulate",
    "simulate_hybrid",
    "simulate_ndi_session",
    "simulate_reference",
    "stage_pattern",
    "truth_calibration",
    "write_simulation",
]
