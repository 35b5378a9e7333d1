"""Board geometry as data: finite source coils and the sensor coil of a tracker, read from a
TOML or JSON file (SI units). See docs/planar.md#board-file.

A board is a list of source coils, each a printed or wound spiral described by its centre,
normal, in-plane angle, shape (``square_spiral``, ``rectangular``, ``circular``), turns per
layer (a multiple of 1/4 for the rectangular shapes), number of layers (1 or 2) and their
spacing, outer size, trace width and trace spacing; and a sensor (``single``: one coil along
the sensor's z axis, 5-DOF; ``dual``: two coils at an angle, 6-DOF; ``triad``: three coils
along x, y, z), with a length (0 = point) and diameter. Each coil is turned into straight current segments (:meth:`CoilSpec.segments`)
for the Biot-Savart kernel (:mod:`openemt.field._segments`).

A two-layer coil is one trace: it spirals inward on the top layer, passes through a via and
spirals back outward on the bottom layer, the mirror image of the top one, so both layers
circulate the same way about the normal (as the Anser coils, Jaeger et al. 2017).
"""

from __future__ import annotations

import functools
import math
import tomllib
from dataclasses import dataclass, field
from importlib import resources

import numpy as np

from .._errors import InputError

__all__ = [
    "BUILTIN_BOARDS",
    "SENSOR_KINDS",
    "SHAPES",
    "Board",
    "CoilSpec",
    "SensorCoils",
    "as_board",
    "board_from_dict",
    "builtin_board",
]

#: Coil shapes a board file may name.
SHAPES = ("square_spiral", "rectangular", "circular")
#: Sensor kinds: one coil along the sensor z axis (5-DOF), two coils at an angle (6-DOF, as
#: commercial 6-DOF tools are built) or three along x, y, z (6-DOF).
SENSOR_KINDS = ("single", "dual", "triad")
#: Board files shipped with the package (``builtin_board(name)``).
BUILTIN_BOARDS = ("anser", "anser-6dof")

#: Plausibility limits (m) used to catch millimetres given where metres are expected.
MAX_POSITION_M = 2.0
MAX_COIL_SIZE_M = 1.0
MAX_SENSOR_LENGTH_M = 0.1
#: Most source coils of a board file, and most straight segments of all its coils together
#: (docs/robustness.md, "Bounded work"; the Anser board has 8 coils and ~2,000 segments).
MAX_BOARD_COILS = 64
MAX_BOARD_SEGMENTS = 2_000_000
#: Segments per turn of a circular coil (a 64-gon: its area is within 0.2 % of the circle's).
CIRCLE_SEGMENTS = 64

_COIL_KEYS = {"name", "center", "normal", "angle", "shape", "turns_per_layer", "layers",
              "layer_spacing", "outer_size", "trace_width", "trace_spacing"}


def _where(src: str) -> str:
    return f"{src}: " if src else ""


def _num(v, what: str, src: str, *, lo=0.0, positive=False, limit=None, unit="m") -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise InputError(f"{_where(src)}expected a number for {what}, got {v!r}")
    v = float(v)
    if not math.isfinite(v) or v < lo or (positive and v <= 0):
        raise InputError(f"{_where(src)}expected a finite {'positive' if positive else 'non-negative'}"
                         f" {what}, got {v!r}")
    if limit is not None and v > limit:
        raise InputError(f"{_where(src)}expected {what} in {unit} (at most {limit:g} {unit}), got "
                         f"{v:g}: millimetres given where metres are expected?")
    return v


def _vec(v, what: str, src: str, *, limit=None) -> np.ndarray:
    try:
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{_where(src)}expected 3 numbers for {what}, got {v!r}") from None
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise InputError(f"{_where(src)}expected 3 finite numbers for {what}, got {v!r}")
    if limit is not None and np.max(np.abs(a)) > limit:
        raise InputError(f"{_where(src)}expected {what} in m (|value| <= {limit:g} m), got "
                         f"{a.tolist()}: millimetres given where metres are expected?")
    return a


def _rect_spiral(hx: float, hy: float, pitch: float, n_seg: int) -> np.ndarray:
    """Vertices ``(n_seg + 1, 2)`` of an inward counter-clockwise rectangular spiral starting
    at the corner ``(hx, -hy)`` of the outer turn's centreline; a side shrinks by ``pitch``
    every second segment, so neighbouring traces are ``pitch`` apart."""
    v = [(hx, -hy)]
    x, y = hx, -hy
    for m in range(n_seg):
        shrink = (m // 2) * pitch
        d = m % 4
        if d == 0:
            y = y + 2 * hy - shrink
        elif d == 1:
            x = x - (2 * hx - shrink)
        elif d == 2:
            y = y - (2 * hy - shrink)
        else:
            x = x + 2 * hx - shrink
        v.append((x, y))
    return np.array(v)


@dataclass(frozen=True, eq=False)
class CoilSpec:
    """One source coil of a board (SI units). See the module docstring for the fields."""

    name: str
    center: np.ndarray
    normal: np.ndarray
    angle: float
    shape: str
    turns_per_layer: float
    layers: int
    layer_spacing: float
    outer_size: tuple
    trace_width: float
    trace_spacing: float

    @property
    def rotation(self) -> np.ndarray:
        """Columns: the coil's local x, y and z (= normal) in the board frame: local x is the
        global axis least aligned with the normal, projected into the coil plane and turned by
        ``angle`` about it (for normal +z: global x turned by ``angle``)."""
        from ..field._coils import coil_frame

        return coil_frame(self.normal, self.angle)

    @property
    def pitch(self) -> float:
        return self.trace_width + self.trace_spacing

    def local_path(self) -> np.ndarray:
        """Closed current path ``(n_vertices, 3)`` in coil coordinates (last = first vertex)."""
        z = (np.array([0.5, -0.5]) * self.layer_spacing if self.layers == 2
             else np.array([0.0]))
        if self.shape == "circular":
            r0 = self.outer_size[0] / 2 - self.trace_width / 2
            n = round(self.turns_per_layer * CIRCLE_SEGMENTS)
            th = np.linspace(0.0, 2 * np.pi * self.turns_per_layer, n + 1)
            r = r0 - self.pitch * th / (2 * np.pi)
            xy = np.column_stack([r * np.cos(th), r * np.sin(th)])
            mirror = np.array([1.0, -1.0])            # about the x axis, where the trace starts
        else:
            hx = self.outer_size[0] / 2 - self.trace_width / 2
            hy = self.outer_size[-1] / 2 - self.trace_width / 2
            xy = _rect_spiral(hx, hy, self.pitch, round(4 * self.turns_per_layer))
            mirror = None                             # about the diagonal through the start
        top = np.column_stack([xy, np.full(len(xy), z[0])])
        if self.layers == 1:
            return np.vstack([top, top[:1]])
        if mirror is None:
            # reflect about the line through the start (hx, -hy) with direction (1, -1) * (hx, hy)
            d = np.array([hx, -hy]) / math.hypot(hx, hy)
            rel = xy - xy[0]
            refl = 2 * (rel @ d)[:, None] * d - rel + xy[0]
        else:
            refl = xy * mirror
        bottom = np.column_stack([refl[::-1], np.full(len(xy), z[1])])
        return np.vstack([top, bottom, top[:1]])

    def segments(self) -> np.ndarray:
        """Straight current segments ``(S, 2, 3)`` (start, end) in the board frame."""
        return self._segments.copy()

    @functools.cached_property
    def _segments(self) -> np.ndarray:
        # a fit builds the board model at every evaluation: the coil's path, once per coil
        v = self.local_path() @ self.rotation.T + self.center
        return np.stack([v[:-1], v[1:]], axis=1)

    @property
    def area_turns(self) -> float:
        """Summed turn area (m^2) about the normal: ``(1/2) sum v_k x v_{k+1} . n``."""
        v = self.local_path()
        return float(0.5 * np.cross(v[:-1], v[1:]).sum(axis=0)[2])

    def to_dict(self) -> dict:
        return {"name": self.name, "center": self.center.tolist(),
                "normal": self.normal.tolist(), "angle": self.angle, "shape": self.shape,
                "turns_per_layer": self.turns_per_layer, "layers": self.layers,
                "layer_spacing": self.layer_spacing,
                "outer_size": (self.outer_size[0] if len(self.outer_size) == 1
                               else list(self.outer_size)),
                "trace_width": self.trace_width, "trace_spacing": self.trace_spacing}


@dataclass(frozen=True, eq=False)
class SensorCoils:
    """The sensor: ``kind`` (``single``, ``dual`` or ``triad``), coil ``length`` and
    ``diameter`` (m); a ``dual`` sensor's two coils are ``angle`` (rad) apart and ``separation``
    (m) apart (docs/planar.md#board-file)."""

    kind: str = "single"
    length: float = 0.0
    diameter: float = 0.0
    angle: float = 0.0
    separation: float = 0.0

    @property
    def n_coils(self) -> int:
        return {"single": 1, "dual": 2, "triad": 3}[self.kind]

    def coil_axes(self) -> np.ndarray:
        """Unit axes ``(n_coils, 3)`` of the coils in the sensor frame: ``single`` along z;
        ``dual`` in the x-z plane at ``-angle/2`` and ``+angle/2`` from z (turned about y);
        ``triad`` along x, y, z."""
        if self.kind == "single":
            return np.array([[0.0, 0.0, 1.0]])
        if self.kind == "triad":
            return np.eye(3)
        h = self.angle / 2
        return np.array([[-math.sin(h), 0.0, math.cos(h)], [math.sin(h), 0.0, math.cos(h)]])

    def coil_positions(self) -> np.ndarray:
        """Coil centres ``(n_coils, 3)`` in the sensor frame (m): a ``dual`` sensor's at
        ``y = -separation/2`` and ``+separation/2``, otherwise at the origin."""
        if self.kind == "dual":
            h = self.separation / 2
            return np.array([[0.0, -h, 0.0], [0.0, h, 0.0]])
        return np.zeros((self.n_coils, 3))

    def to_dict(self) -> dict:
        d = {"kind": self.kind, "length": self.length, "diameter": self.diameter}
        if self.kind == "dual":
            d.update(angle=self.angle, separation=self.separation)
        return d


@dataclass(frozen=True, eq=False)
class Board:
    """Source coils and sensor of a tracker, in the board (source) frame."""

    name: str
    coils: tuple
    sensor: SensorCoils = field(default_factory=SensorCoils)
    description: str = ""

    @property
    def n_coils(self) -> int:
        return len(self.coils)

    def segments(self) -> tuple[np.ndarray, np.ndarray]:
        """All coils' segments: starts/ends ``(S, 2, 3)`` and the coil offsets ``(n_coils+1,)``
        (coil ``i`` owns segments ``offsets[i]:offsets[i+1]``)."""
        segs = [c.segments() for c in self.coils]
        off = np.concatenate([[0], np.cumsum([len(s) for s in segs])]).astype(np.int64)
        return np.concatenate(segs), off

    def to_dict(self) -> dict:
        return {"name": self.name, "description": self.description,
                "coils": [c.to_dict() for c in self.coils], "sensor": self.sensor.to_dict()}


def _coil(d: dict, defaults: dict, k: int, src: str) -> CoilSpec:
    if not isinstance(d, dict):
        raise InputError(f"{_where(src)}expected coil {k + 1} to be a table, got {d!r}")
    d = {**defaults, **d}
    unknown = sorted(set(d) - _COIL_KEYS)
    if unknown:
        raise InputError(f"{_where(src)}expected coil keys {sorted(_COIL_KEYS)}, got unknown "
                         f"{unknown}")
    name = str(d.get("name", f"coil{k + 1}"))
    w = f"{src}: coil {name!r}" if src else f"coil {name!r}"
    for key in ("center", "outer_size", "turns_per_layer"):
        if key not in d:
            raise InputError(f"{w}: expected key {key!r}, got none")
    shape = d.get("shape", "square_spiral")
    if shape not in SHAPES:
        raise InputError(f"{w}: expected shape in {list(SHAPES)}, got {shape!r}")
    center = _vec(d["center"], "center", w, limit=MAX_POSITION_M)
    normal = _vec(d.get("normal", [0.0, 0.0, 1.0]), "normal", w)
    if np.linalg.norm(normal) == 0:
        raise InputError(f"{w}: expected a non-zero normal, got [0, 0, 0]")
    normal = normal / np.linalg.norm(normal)
    angle = _num(d.get("angle", 0.0), "angle (rad)", w, lo=-math.inf, unit="rad")
    size = d["outer_size"]
    size = [size] if not isinstance(size, (list, tuple)) else list(size)
    n_size = 2 if shape == "rectangular" else 1
    if len(size) != n_size and not (shape == "rectangular" and len(size) == 1):
        raise InputError(f"{w}: expected {n_size} value(s) for outer_size, got {size!r}")
    size = tuple(_num(s, "outer_size", w, positive=True, limit=MAX_COIL_SIZE_M) for s in size)
    turns = _num(d["turns_per_layer"], "turns_per_layer", w, positive=True, unit="turns",
                 limit=10_000)
    layers = d.get("layers", 1)
    if isinstance(layers, bool) or layers not in (1, 2):
        raise InputError(f"{w}: expected layers 1 or 2, got {layers!r}")
    gap = _num(d.get("layer_spacing", 0.0), "layer_spacing", w, limit=MAX_COIL_SIZE_M)
    if layers == 2 and gap <= 0:
        raise InputError(f"{w}: expected a positive layer_spacing for 2 layers, got {gap!r}")
    tw = _num(d.get("trace_width", 0.0), "trace_width", w, limit=MAX_COIL_SIZE_M)
    ts = _num(d.get("trace_spacing", 0.0), "trace_spacing", w, limit=MAX_COIL_SIZE_M)
    if shape != "circular" and abs(4 * turns - round(4 * turns)) > 1e-9:
        raise InputError(f"{w}: expected turns_per_layer a multiple of 0.25, got {turns!r}")
    half = min(size) / 2 - tw / 2
    if half - turns * (tw + ts) <= 0:
        raise InputError(f"{w}: expected the spiral to fit its outer_size ({turns:g} turns of "
                         f"pitch {(tw + ts) * 1e3:g} mm in {min(size) * 1e3:g} mm), got too many "
                         f"turns")
    return CoilSpec(name, center, normal, angle, shape, turns, int(layers), gap, size, tw, ts)


def board_from_dict(doc: dict, src: str = "") -> Board:
    """A :class:`Board` from the dict of a board file (validated; ``src`` names it in errors)."""
    if not isinstance(doc, dict):
        raise InputError(f"{_where(src)}expected a table at top level, got {type(doc).__name__}")
    coils = doc.get("coils")
    if not isinstance(coils, list) or not coils:
        raise InputError(f"{_where(src)}expected a non-empty list 'coils', got {coils!r}")
    defaults = doc.get("defaults", {})
    if not isinstance(defaults, dict):
        raise InputError(f"{_where(src)}expected 'defaults' to be a table, got {defaults!r}")
    if len(coils) > MAX_BOARD_COILS:
        raise InputError(f"{_where(src)}expected at most {MAX_BOARD_COILS} entries in 'coils', "
                         f"got {len(coils)}")
    specs = tuple(_coil(c, defaults, k, src) for k, c in enumerate(coils))
    n_segments = sum(c.layers * math.ceil(c.turns_per_layer * (
        CIRCLE_SEGMENTS if c.shape == "circular" else 4)) for c in specs)
    if n_segments > MAX_BOARD_SEGMENTS:
        raise InputError(f"{_where(src)}expected coils of at most {MAX_BOARD_SEGMENTS} straight "
                         f"segments together (turns_per_layer x layers), got {n_segments}")
    s = doc.get("sensor", {})
    if not isinstance(s, dict):
        raise InputError(f"{_where(src)}expected 'sensor' to be a table, got {s!r}")
    kind = s.get("kind", "single")
    if kind not in SENSOR_KINDS:
        raise InputError(f"{_where(src)}expected sensor kind in {list(SENSOR_KINDS)}, got {kind!r}")
    unknown = sorted(set(s) - {"kind", "length", "diameter", "angle", "separation"})
    if unknown:
        raise InputError(f"{_where(src)}expected sensor keys kind, length, diameter (and for a "
                         f"dual sensor angle, separation), got unknown {unknown}")
    angle = sep = 0.0
    if kind == "dual":
        angle = _num(s.get("angle", math.pi / 2), "sensor angle (rad)", src, unit="rad",
                     limit=math.pi)
        sep = _num(s.get("separation", 0.0), "sensor separation", src,
                   limit=MAX_SENSOR_LENGTH_M)
        if not math.radians(5.0) <= angle <= math.radians(175.0):
            raise InputError(f"{_where(src)}expected a dual sensor's coil angle between 5 and "
                             f"175 degrees (two parallel coils give no roll), got "
                             f"{math.degrees(angle):.3g} degrees")
    elif "angle" in s or "separation" in s:
        raise InputError(f"{_where(src)}expected sensor angle/separation only for kind 'dual', "
                         f"got them for kind {kind!r}")
    sensor = SensorCoils(kind, _num(s.get("length", 0.0), "sensor length", src,
                                   limit=MAX_SENSOR_LENGTH_M),
                        _num(s.get("diameter", 0.0), "sensor diameter", src,
                             limit=MAX_SENSOR_LENGTH_M), angle, sep)
    return Board(str(doc.get("name", "board")), specs, sensor, str(doc.get("description", "")))


def builtin_board(name: str | None = None) -> Board:
    """A board shipped with openemt (:data:`BUILTIN_BOARDS`; default ``anser``). Board files
    of your own are read by :func:`openemt.io.load_board` / :func:`openemt.io.read_board`."""
    name = "anser" if name is None else str(name)
    if name not in BUILTIN_BOARDS:
        raise InputError(f"expected a Board or a built-in board name {list(BUILTIN_BOARDS)}, got "
                         f"{name!r} (read a board file with openemt.io.load_board)")
    text = resources.files("openemt.board").joinpath(f"{name}.toml").read_text("utf-8")
    return board_from_dict(tomllib.loads(text), f"{name}.toml")


def as_board(board=None) -> Board:
    """``board`` if it is a :class:`Board`, else the built-in board of that name."""
    return board if isinstance(board, Board) else builtin_board(board)
