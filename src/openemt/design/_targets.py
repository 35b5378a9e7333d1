"""What ``openemt design`` maps: a tracker resolved to its coupling model and a default volume.

A target is a built-in board name (``anser``, ``anser-6dof``), a rig preset of the simulator
(``concentric``, ``dipole-approx``: the rig source and sensor as their true calibration's
model), a board file (TOML/JSON with ``coils``), a calibration (openemt JSON or ILEMT ``.mat``:
its model) or a tracker file (``format = "openemt-tracker"``: its first sensor's calibration,
and the tracker's ADC figures for the noise). See docs/design.md#targets.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .._errors import InputError

__all__ = ["RIG_PRESETS", "Target", "Volume", "board_volume", "carrier_plan", "resolve_target",
           "rig_volume"]

#: Shipped tracker files whose carrier plan a target without its own tracker file borrows
#: (the first with the target's source count and sensor coil count).
PLAN_TRACKERS = ("anser", "anser-6dof", "simulated")

#: Simulator presets whose rig source and sensor ``design`` maps.
RIG_PRESETS = ("concentric", "dipole-approx")


@dataclass(frozen=True)
class Volume:
    """A box of grid points (m): ``x``, ``y``, ``z`` as (low, high), ``n`` points per axis."""

    x: tuple
    y: tuple
    z: tuple
    n: tuple = (7, 7, 5)

    def __post_init__(self):
        for name in ("x", "y", "z"):
            lo, hi = getattr(self, name)
            if not (np.isfinite(lo) and np.isfinite(hi) and hi >= lo):
                raise InputError(f"expected a volume range low <= high (m) for {name}, got "
                                 f"({lo}, {hi})")
        if len(self.n) != 3 or any(int(k) < 1 or int(k) > 200 for k in self.n):
            raise InputError(f"expected 3 grid sizes between 1 and 200, got {self.n}")

    def axes(self) -> list:
        return [np.linspace(*getattr(self, a), int(k)) if k > 1 else
                np.array([0.5 * sum(getattr(self, a))]) for a, k in zip("xyz", self.n)]

    def points(self) -> np.ndarray:
        """Grid points ``(nx * ny * nz, 3)``, x slowest and z fastest."""
        g = np.meshgrid(*self.axes(), indexing="ij")
        return np.stack(g, axis=-1).reshape(-1, 3)

    def to_dict(self) -> dict:
        return {"x_mm": [v * 1e3 for v in self.x], "y_mm": [v * 1e3 for v in self.y],
                "z_mm": [v * 1e3 for v in self.z], "n": [int(k) for k in self.n]}


def board_volume(n=(7, 7, 5)) -> Volume:
    """The Anser working volume: x and y over the extent of the 7 x 7 test grid of
    docs/planar.md (pitch 42.86 mm: +-128.6 mm), z from 60 to 160 mm over the board (the
    heights of the tracking path that docs/planar.md benchmarks)."""
    from ..simulate import GRID_PITCH

    h = 3 * GRID_PITCH
    return Volume((-h, h), (-h, h), (0.060, 0.160), tuple(n))


def rig_volume(preset: str, n=(5, 5, 5)) -> Volume:
    """The box of the sensor positions of the rig's ``md`` calibration pattern (home
    fixtures) of a simulator preset, in the source frame."""
    from ..simulate import working_volume

    lo, hi, _ = working_volume(preset)
    return Volume(*[(float(a), float(b)) for a, b in zip(lo, hi)], tuple(n))


@dataclass(frozen=True, eq=False)
class Target:
    """A resolved target: its coupling ``model``, a ``kind`` (``board``, ``rig``,
    ``calibration``, ``tracker``), a default volume, the board (for boards: what ``optimize``
    changes) and a tracker spec (for tracker files: ADC figures)."""

    name: str
    kind: str
    model: object
    volume: Volume
    board: object = None
    tracker: object = None
    calibration: object = None


def carrier_plan(target):
    """``(ChannelLayout, output_rate, window)`` of the target's first sensor: its own tracker
    file's, else the first of :data:`PLAN_TRACKERS` with as many carriers as the model has
    source coils and as many channels in its first sensor as the model has sensor coils;
    None when none fits."""
    from ..live import example_tracker, read_tracker

    model = target.model
    specs = [target.tracker] if target.tracker is not None else \
        [read_tracker(example_tracker(n)) for n in PLAN_TRACKERS]
    for spec in specs:
        s0 = spec.sensors[0]
        if len(spec.frequencies) == model.n_source and len(s0.channels) == model.n_sensor:
            # the tracker's layout with the first sensor's channels, one carrier band
            layout = replace(spec.layout(), sensor_channels=s0.channels, bands=())
            return layout, spec.output_rate, spec.window
    return None


def _looks_like_tracker(path: Path) -> bool:
    if path.suffix.lower() != ".toml":
        return False
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return False
    return doc.get("format") == "openemt-tracker"


def _looks_like_board(path: Path) -> bool:
    if path.suffix.lower() == ".toml":
        return True
    if path.suffix.lower() != ".json":
        return False
    import json

    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return False
    return isinstance(doc, dict) and "coils" in doc


def _default_volume(model) -> Volume | None:
    """A board's default volume; None for other models (the map asks for one)."""
    return board_volume() if hasattr(model, "board") else None


def resolve_target(target) -> Target:
    """The :class:`Target` named by ``target`` (see the module docstring)."""
    from ..board import BUILTIN_BOARDS, BoardModel

    name = str(target)
    if name in BUILTIN_BOARDS:
        from ..board import builtin_board

        b = builtin_board(name)
        return Target(name, "board", BoardModel.from_board(b), board_volume(), board=b)
    if name in RIG_PRESETS:
        from ..simulate import truth_calibration

        cal = truth_calibration(name)
        return Target(name, "rig", cal.model, rig_volume(name), calibration=cal)
    path = Path(name)
    if not path.exists():
        raise InputError(f"expected a built-in board {list(BUILTIN_BOARDS)}, a rig preset "
                         f"{list(RIG_PRESETS)}, or a board, calibration or tracker file, got "
                         f"{name!r} (no such file)")
    if _looks_like_tracker(path):
        from ..live import read_tracker

        spec = read_tracker(path)
        cals = spec.calibrations()
        if not cals or cals[0] is None:
            raise InputError(f"{path}: expected a tracker whose first sensor names a "
                             f"calibration, got none")
        model = cals[0].model
        return Target(name, "tracker", model, _default_volume(model),
                      board=getattr(model, "board", None), tracker=spec)
    if path.suffix.lower() in (".json", ".mat") and not _looks_like_board(path):
        from ..io import read_calibration

        cal = read_calibration(path)
        return Target(name, "calibration", cal.model, _default_volume(cal.model),
                      board=getattr(cal.model, "board", None), calibration=cal)
    from ..io import read_board

    b = read_board(path)
    return Target(name, "board", BoardModel.from_board(b), board_volume(), board=b)
