"""Design a tracker before building it: Cramer-Rao maps of a coil layout over a volume, Monte
Carlo solves beside the bound, layout optimisation of a board, and carrier plans
(docs/design.md)."""

from ._carriers import CarrierOptions, CarrierReport, carrier_plan, plan_leakage
from ._crb import PoseBound, pose_bound
from ._map import BoundMap, DesignMap, MapOptions, bound_map, design_map, map_summary
from ._montecarlo import montecarlo
from ._optimize import OptimizedLayout, OptimizeOptions, optimize_layout
from ._orient import ORIENTATIONS, orientation_set
from ._targets import RIG_PRESETS, Target, Volume, board_volume, resolve_target, rig_volume

__all__ = ["ORIENTATIONS", "RIG_PRESETS", "BoundMap", "CarrierOptions", "CarrierReport",
           "DesignMap", "MapOptions", "OptimizeOptions", "OptimizedLayout", "PoseBound",
           "Target", "Volume", "board_volume", "bound_map", "carrier_plan", "design_map",
           "map_summary", "montecarlo", "optimize_layout", "orientation_set", "plan_leakage",
           "pose_bound", "resolve_target", "rig_volume"]
