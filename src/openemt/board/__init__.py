"""Board geometry files: finite source coils and the sensor of a tracker (docs/planar.md)."""

from ._coils import board_coils
from ._geometry import (
    BUILTIN_BOARDS,
    SENSOR_KINDS,
    SHAPES,
    Board,
    CoilSpec,
    SensorCoils,
    as_board,
    board_from_dict,
    builtin_board,
)
from ._model import BoardModel, DipoleOnlyError

__all__ = ["BUILTIN_BOARDS", "SENSOR_KINDS", "SHAPES", "Board", "BoardModel", "CoilSpec",
           "DipoleOnlyError", "SensorCoils", "as_board", "board_coils", "board_from_dict", "builtin_board"]
