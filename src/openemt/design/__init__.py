"""Design a tracker before building it: Cramer-Rao maps of a coil layout over a volume, Monte
Carlo solves beside the bound, layout optimisation of a board, and carrier plans
(docs/design.md)."""

from .._lazy import lazy_exports

#: where each public name lives; a module is imported on first use of one of its names
_SOURCES = {
    "._carriers": ("CarrierOptions", "CarrierReport", "carrier_plan", "plan_leakage"),
    "._crb": ("PoseBound", "pose_bound"),
    "._map": ("BoundMap", "DesignMap", "MapOptions", "bound_map", "design_map", "map_summary"),
    "._montecarlo": ("montecarlo",),
    "._optimize": ("OptimizedLayout", "OptimizeOptions", "optimize_layout"),
    "._orient": ("ORIENTATIONS", "orientation_set"),
    "._targets": ("RIG_PRESETS", "Target", "Volume", "board_volume", "resolve_target",
                  "rig_volume"),
}
__all__, __getattr__, __dir__ = lazy_exports(__name__, _SOURCES)
