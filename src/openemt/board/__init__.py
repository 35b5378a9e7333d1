"""Board geometry files: finite source coils and the sensor of a tracker (docs/planar.md)."""

from ._coils import board_coils
from ._geometry import (
    BUILTIN_BOARDS,
    SENSOR_KINDS,
    SHAPES,
    Board,
    CoilSpec,
    SensorSpec,
    board_from_dict,
    load_board,
    read_board,
    write_board,
)
from ._model import PlanarModel

__all__ = ["BUILTIN_BOARDS", "SENSOR_KINDS", "SHAPES", "Board", "CoilSpec", "PlanarModel",
           "SensorSpec", "board_coils", "board_from_dict", "load_board", "read_board",
           "write_board"]
