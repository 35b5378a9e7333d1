"""Board geometry files: finite source coils and the sensor of a tracker (docs/planar.md)."""

from .._lazy import lazy_exports

#: where each public name lives; a module is imported on first use of one of its names
_SOURCES = {
    "._coils": ("board_coils",),
    "._geometry": ("BUILTIN_BOARDS", "SENSOR_KINDS", "SHAPES", "Board", "CoilSpec", "SensorCoils",
                   "as_board", "board_from_dict", "builtin_board"),
    "._model": ("BoardModel", "DipoleOnlyError"),
}
__all__, __getattr__, __dir__ = lazy_exports(__name__, _SOURCES)
