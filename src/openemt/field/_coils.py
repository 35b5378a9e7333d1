"""Finite-size coil geometry: circular and square windings, square spiral PCB coils.

A :class:`Coil` describes one winding in some parent frame (source or sensor coordinates). It
knows two discretisations of itself, both cached on first use:

- as a **field source**: a few magpylib current objects (filament loops placed by a
  Gauss-Legendre quadrature over the winding cross-section, or the actual spiral trace) whose
  summed field, divided by the physical area-turns product N*A and multiplied by ``4 pi / mu0``
  and the coil's ``gain``, is the field in the project's dipole gain units (see
  ``docs/field-models.md``);
- as a **sensor**: quadrature points over the area enclosed by each turn, with weights summing
  to one, so that ``sum_q w_q B(x_q) . axis`` is the flux-weighted mean field.

With this normalisation a coil's far field is exactly the dipole field of moment
``gain * axis`` in the convention of :class:`~openemt.field.DipoleModel`
(``B = (3 (M.u) u - M) / d^3``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.constants import mu_0

from .._errors import InputError

__all__ = [
    "ANSER_COIL_CENTERS",
    "ANSER_ROTATED_COILS",
    "COIL_KINDS",
    "Coil",
    "anser_field_generator",
    "circular_coil",
    "coil_fields",
    "square_coil",
    "square_spiral_coil",
]

#: Supported coil kinds.
COIL_KINDS = ("circular", "square", "spiral")

#: Scale from SI flux density (T, for 1 A) to the dipole model's units, where mu0/(4 pi) -> 1.
SI_TO_MODEL = 4.0 * np.pi / mu_0

#: Anser field-generator coil centres (x, y) in metres, coils 1..8 (Jaeger et al. 2017).
ANSER_COIL_CENTERS = np.array([
    (-93.543, 93.543), (0.0, 68.55), (93.543, 93.543), (-68.55, 0.0),
    (68.55, 0.0), (-93.543, -93.543), (0.0, -68.55), (93.543, -93.543),
]) * 1e-3
ANSER_COIL_CENTERS.setflags(write=False)

#: 0-based indices of the Anser coils rotated 45 degrees in plane (coils 2, 4, 5, 7).
ANSER_ROTATED_COILS = (1, 3, 4, 6)


# --------------------------------------------------------------------------- validation

def _vec3(v, name: str) -> np.ndarray:
    arr = np.asarray(v)
    if arr.dtype.kind not in "iuf":
        raise TypeError(f"expected `{name}` to be real numbers, got dtype {arr.dtype}")
    if arr.shape != (3,):
        raise InputError(f"expected `{name}` to have shape (3,), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"expected finite `{name}`, got {arr.tolist()}")
    return arr.astype(np.float64)


def _nonneg(x, name: str, positive: bool = False) -> float:
    try:
        v = float(x)
    except (TypeError, ValueError):
        raise TypeError(f"expected `{name}` to be a number, got {type(x).__name__}") from None
    if not np.isfinite(v) or v < 0 or (positive and v == 0):
        kind = "a finite positive" if positive else "a finite non-negative"
        raise InputError(f"expected {kind} `{name}`, got {x!r}")
    return v


def _count(n, name: str, minimum: int = 1) -> int:
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)):
        raise TypeError(f"expected `{name}` to be an integer, got {type(n).__name__}")
    if n < minimum:
        raise InputError(f"expected `{name}` >= {minimum}, got {n}")
    return int(n)


def _gain(g) -> float:
    """A coil's or a coil model's ``gain``: a finite non-zero number (not a bool)."""
    if isinstance(g, bool) or not isinstance(g, (int, float, np.integer, np.floating)) \
            or not np.isfinite(g) or g == 0:
        raise InputError(f"expected a finite non-zero `gain`, got {g!r}")
    return float(g)


def coil_frame(axis, angle: float = 0.0) -> np.ndarray:
    """Right-handed rotation whose third column is ``axis``; the first column is the global
    axis least aligned with ``axis`` (x, then y, then z on ties) projected into the coil plane,
    then turned by ``angle`` (rad) about ``axis``."""
    a = _vec3(axis, "axis")
    n = np.linalg.norm(a)
    if n == 0:
        raise InputError("expected a non-zero `axis`, got [0, 0, 0]")
    a = a / n
    e = np.eye(3)[int(np.argmin(np.abs(a)))]
    x = e - (e @ a) * a
    x /= np.linalg.norm(x)
    c, s = np.cos(angle), np.sin(angle)
    x = c * x + s * np.cross(a, x)
    return np.column_stack([x, np.cross(a, x), a])


def _check_rotation(R) -> np.ndarray:
    arr = np.asarray(R)
    if arr.dtype.kind not in "iuf":
        raise TypeError(f"expected `rotation` to be real numbers, got dtype {arr.dtype}")
    if arr.shape != (3, 3) or not np.all(np.isfinite(arr)):
        raise InputError(f"expected `rotation` to be a finite (3, 3) matrix, got shape {arr.shape}")
    arr = arr.astype(np.float64)
    if not (np.allclose(arr.T @ arr, np.eye(3), atol=1e-9) and np.linalg.det(arr) > 0):
        raise InputError("expected `rotation` to be a proper rotation matrix, got a non-orthonormal "
                         "or reflecting matrix")
    return arr


def _gauss(n: int, lo: float, hi: float) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre nodes on [lo, hi] and weights summing to one."""
    if n == 1 or hi == lo:
        return np.array([(lo + hi) / 2.0]), np.array([1.0])
    x, w = np.polynomial.legendre.leggauss(n)
    return (lo + hi) / 2.0 + (hi - lo) / 2.0 * x, w / 2.0


# --------------------------------------------------------------------------- the coil

@dataclass(frozen=True, eq=False)
class Coil:
    """One finite coil in a parent frame (source or sensor coordinates). SI units.

    Build coils with :func:`circular_coil`, :func:`square_coil` or :func:`square_spiral_coil`.

    Attributes
    ----------
    kind : {"circular", "square", "spiral"}
    center : ndarray, shape (3,)
        Winding centre (m): mid-length of the winding; mid-plane between the two layers of a
        spiral.
    rotation : ndarray, shape (3, 3)
        Columns are the coil's local x, y and z (= ``axis``) in the parent frame; local x is
        parallel to a side of square coils.
    size : float
        Circular: mean winding radius. Square: mean side of the square turns. Spiral: outer
        side of the trace (outer edge to outer edge).
    length : float
        Axial winding length (circular/square); the spiral's layer gap.
    depth : float
        Radial winding depth (circular/square, outer minus inner radius or half-side).
    turns : int
        Number of turns (per layer for a spiral).
    gain : float
        Dimensionless gain: the coil's dipole-equivalent moment is ``gain * axis``.
    trace_width, spacing : float
        Spiral trace width and gap between traces (0 for other kinds).
    layers : int
        Spiral layers (1 or 2), connected in series with the same sense of circulation.
    order : tuple of int
        Quadrature orders ``(n_depth, n_length, n_area)``: Gauss-Legendre loops across the
        winding depth and along its length, and the sensor-area order (a disk uses ``n_area``
        radial x ``2 n_area + 2`` angular points, a square ``n_area x n_area`` points; 0 = the
        loop centre only, a point sensor). For a spiral, ``n_depth`` only affects its use as a
        sensor.
    """

    kind: str
    center: np.ndarray
    rotation: np.ndarray
    size: float
    length: float = 0.0
    depth: float = 0.0
    turns: int = 1
    gain: float = 1.0
    trace_width: float = 0.0
    spacing: float = 0.0
    layers: int = 1
    order: tuple = (1, 1, 1)
    _cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self):
        if self.kind not in COIL_KINDS:
            raise InputError(f"expected `kind` in {COIL_KINDS}, got {self.kind!r}")
        object.__setattr__(self, "center", _vec3(self.center, "center"))
        object.__setattr__(self, "rotation", _check_rotation(self.rotation))
        self.center.setflags(write=False)
        self.rotation.setflags(write=False)
        for name in ("length", "depth", "trace_width", "spacing"):
            object.__setattr__(self, name, _nonneg(getattr(self, name), name))
        object.__setattr__(self, "size", _nonneg(self.size, "size", positive=True))
        object.__setattr__(self, "turns", _count(self.turns, "turns"))
        object.__setattr__(self, "layers", _count(self.layers, "layers"))
        object.__setattr__(self, "gain", _gain(self.gain))
        order = tuple(self.order) if np.ndim(self.order) == 1 else ()
        if len(order) != 3:
            raise InputError(f"expected `order` = (n_depth, n_length, n_area), got {self.order!r}")
        object.__setattr__(self, "order", tuple(_count(n, "order", minimum=m)
                                                for n, m in zip(order, (1, 1, 0))))
        if self.kind == "spiral":
            if self.layers > 2:
                raise InputError(f"expected `layers` 1 or 2 for a spiral, got {self.layers}")
            if self.trace_width <= 0:
                raise InputError(f"expected a positive `trace_width`, got {self.trace_width}")
            if self._inner_half <= 0:
                raise InputError(f"expected {self.turns} turns of pitch "
                                 f"{self.trace_width + self.spacing} m to fit in a "
                                 f"{self.size} m spiral, got an inner half-side of "
                                 f"{self._inner_half:.3g} m")
        elif self.depth >= (2 * self.size if self.kind == "circular" else self.size):
            raise InputError(f"expected `depth` smaller than the coil's mean diameter/side, "
                             f"got depth {self.depth} for size {self.size}")

    # ---------------------------------------------------------------- derived geometry
    @property
    def axis(self) -> np.ndarray:
        """Unit coil axis in the parent frame, shape (3,)."""
        return self.rotation[:, 2]

    @property
    def moment(self) -> np.ndarray:
        """Dipole-equivalent moment ``gain * axis`` in DipoleModel gain units, shape (3,)."""
        return self.gain * self.axis

    @property
    def diameter(self) -> float:
        """Largest outer dimension across the axis (m): outer diameter or outer side."""
        if self.kind == "circular":
            return 2 * self.size + self.depth
        if self.kind == "square":
            return self.size + self.depth
        return self.size

    @property
    def _pitch(self) -> float:
        return self.trace_width + self.spacing

    @property
    def _outer_half(self) -> float:
        return (self.size - self.trace_width) / 2.0

    @property
    def _inner_half(self) -> float:
        return self._outer_half - self.turns * self._pitch

    def _layer_z(self) -> np.ndarray:
        if self.kind == "spiral":
            return np.array([0.0]) if self.layers == 1 else np.array([0.5, -0.5]) * self.length
        return _gauss(self.order[1] if self.length > 0 else 1, -self.length / 2, self.length / 2)[0]

    def _loops(self):
        """Filament loops ``(sizes, z, weights)`` with weights summing to one: radii (circular)
        or full sides (square) across the depth, positions along the length."""
        nd, nl, _ = self.order
        if self.kind == "circular":
            lo, hi = self.size - self.depth / 2, self.size + self.depth / 2
        elif self.kind == "square":
            lo, hi = self.size - self.depth, self.size + self.depth
        else:  # spiral: full sides 2h_k, k = 0..n-1, spaced 2*pitch; midpoint-rule interval
            lo = 2 * (self._inner_half + self._pitch) - self._pitch
            hi = 2 * self._outer_half + self._pitch
        s, ws = _gauss(nd if hi > lo else 1, lo, hi)
        if self.kind == "spiral":
            z, wz = self._layer_z(), np.full(self.layers, 1.0 / self.layers)
        else:
            z, wz = _gauss(nl if self.length > 0 else 1, -self.length / 2, self.length / 2)
        S, Z = np.meshgrid(s, z, indexing="ij")
        W = np.outer(ws, wz)
        return S.ravel(), Z.ravel(), W.ravel()

    def spiral_path(self) -> np.ndarray:
        """Closed current path of a spiral coil in local coordinates, shape (n_vertices, 3).

        Layer 1 (z = +gap/2) runs inward counter-clockwise from ``(h0, 0)`` to ``(h_n, 0)``
        (``h_k = h0 - k * pitch``, ``h0`` the centreline half-side of the outer turn); a via
        drops to layer 2 (z = -gap/2), the mirror image (y -> -y) of layer 1 run outward, so
        both layers circulate counter-clockwise about +z; the feed returns to the start.
        A single layer is closed by a straight return lead along +x.
        """
        if self.kind != "spiral":
            raise InputError(f"expected a spiral coil, got kind {self.kind!r}")
        h0, p, n = self._outer_half, self._pitch, self.turns
        xy = [(h0, 0.0)]
        for k in range(n):
            hk = h0 - k * p
            xy += [(hk, hk), (-hk, hk), (-hk, -hk), (hk - p, -hk)]
        xy.append((h0 - n * p, 0.0))
        xy = np.array(xy)
        z = self._layer_z()
        top = np.column_stack([xy, np.full(len(xy), z[0])])
        if self.layers == 1:
            return np.vstack([top, top[:1]])
        bottom = np.column_stack([xy[::-1, 0], -xy[::-1, 1], np.full(len(xy), z[1])])
        return np.vstack([top, bottom, top[:1]])

    @property
    def vector_area(self) -> np.ndarray:
        """Area-turns vector ``sum over turns of the vector area`` (m^2) in the parent frame.

        For circular and square windings it is ``area_turns * axis``; a spiral's via and feed
        add a small in-plane part (~1e-4 of the axial part for the Anser coil).
        """
        if "vector_area" not in self._cache:
            if self.kind == "spiral":
                v = self.spiral_path()
                local = 0.5 * np.cross(v[:-1], v[1:]).sum(axis=0)
            else:
                s, _, w = self._loops()
                area = np.pi * s**2 if self.kind == "circular" else s**2
                local = np.array([0.0, 0.0, self.turns * np.sum(w * area)])
            self._cache["vector_area"] = self.rotation @ local
        return self._cache["vector_area"].copy()

    @property
    def area_turns(self) -> float:
        """Physical area-turns product N*A (m^2): the axial component of :attr:`vector_area`."""
        return float(self.vector_area @ self.axis)

    # ---------------------------------------------------------------- discretisations
    def magpylib_sources(self) -> list:
        """The coil as magpylib current objects (parent frame, currents in A for 1 A of coil
        current: a filament loop of a thick winding carries its share of the turns)."""
        if "sources" not in self._cache:
            import magpylib  # here: magpylib and scipy.spatial cost every command's import
            from scipy.spatial.transform import Rotation

            rot = Rotation.from_matrix(self.rotation)
            if self.kind == "spiral":
                verts = self.spiral_path() @ self.rotation.T + self.center
                src = [magpylib.current.Polyline(current=1.0, vertices=verts)]
            else:
                s, z, w = self._loops()
                pos = self.center + np.outer(z, self.rotation[:, 2])
                if self.kind == "circular":
                    src = [magpylib.current.Circle(current=self.turns * wi, diameter=2 * si,
                                                   position=pi, orientation=rot)
                           for si, pi, wi in zip(s, pos, w)]
                else:
                    sq = np.array([(1, 1), (-1, 1), (-1, -1), (1, -1), (1, 1)], float) / 2
                    src = []
                    for si, zi, wi in zip(s, z, w):
                        loc = np.column_stack([sq * si, np.full(5, zi)])
                        src.append(magpylib.current.Polyline(
                            current=self.turns * wi, vertices=loc @ self.rotation.T + self.center))
            self._cache["sources"] = src
        return self._cache["sources"]

    @property
    def field_scale(self) -> float:
        """Factor from magpylib's B (T) to model units: ``(4 pi / mu0) * gain / (N*A)``."""
        return SI_TO_MODEL * self.gain / self.area_turns

    def sensor_quadrature(self) -> tuple[np.ndarray, np.ndarray]:
        """Points ``(M, 3)`` in the parent frame and weights ``(M,)`` summing to one, for the
        flux-weighted mean of a field over the area enclosed by every turn."""
        if "quadrature" not in self._cache:
            s, z, w = self._loops()
            na = self.order[2]
            if na == 0:
                area = np.pi * s**2 if self.kind == "circular" else s**2
                unit, wunit = np.zeros((1, 2)), np.ones(1)
            elif self.kind == "circular":
                area = np.pi * s**2
                u, wu = _gauss(na, 0.0, 1.0)            # u = (rho / r)^2: uniform in area
                nphi = 2 * na + 2
                phi = 2 * np.pi * (np.arange(nphi) + 0.5) / nphi
                unit = np.stack([np.sqrt(u)[:, None] * np.cos(phi), np.sqrt(u)[:, None]
                                 * np.sin(phi)], axis=-1).reshape(-1, 2)
                wunit = np.repeat(wu, nphi) / nphi
            else:
                area = s**2
                g, wg = _gauss(na, -0.5, 0.5)
                X, Y = np.meshgrid(g, g, indexing="ij")
                unit = np.column_stack([X.ravel(), Y.ravel()])
                wunit = np.outer(wg, wg).ravel()
            wl = w * area / np.sum(w * area)
            pts = np.concatenate([np.column_stack([unit * si, np.full(len(unit), zi)])
                                  for si, zi in zip(s, z)])
            wts = np.concatenate([wi * wunit for wi in wl])
            pts = pts @ self.rotation.T + self.center
            pts.setflags(write=False)
            wts.setflags(write=False)
            self._cache["quadrature"] = (pts, wts)
        return self._cache["quadrature"]

    def field(self, points) -> np.ndarray:
        """Field in dipole gain units at points ``(N, 3)`` (parent frame, m) -> ``(N, 3)``."""
        return coil_fields([self], points)[0]


def coil_fields(coils, points, *, chunk: int = 200_000) -> np.ndarray:
    """Fields of several coils at points ``(N, 3)`` (m) -> ``(n_coils, N, 3)``, in the dipole
    model's units: ``(4 pi / mu0) * B_SI(1 A) * gain / (N*A)``; one ``magpylib.getB`` call per
    chunk of about ``chunk`` filament-point evaluations."""
    coils = _check_coils(coils, "coils")
    pts = np.asarray(points)
    if pts.dtype.kind not in "iuf":
        raise TypeError(f"expected `points` to be real numbers, got dtype {pts.dtype}")
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InputError(f"expected `points` to have shape (N, 3), got {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise InputError("expected finite `points`, got NaN or inf")
    return _coil_fields(coils, pts.astype(np.float64), chunk)


def _coil_fields(coils, pts: np.ndarray, chunk: int = 200_000) -> np.ndarray:
    """Unvalidated :func:`coil_fields`."""
    srcs, owner, weight = [], [], []
    for i, c in enumerate(coils):
        for s in c.magpylib_sources():
            srcs.append(s)
            owner.append(i)
            weight.append(len(getattr(s, "vertices", [0, 0])) - 1)
    out = np.zeros((len(coils), len(pts), 3))
    if len(pts) == 0:
        return out
    member = np.zeros((len(coils), len(srcs)))
    member[owner, np.arange(len(srcs))] = 1.0
    step = max(1, chunk // max(1, sum(weight)))
    import magpylib

    for a in range(0, len(pts), step):
        B = magpylib.getB(srcs, pts[a:a + step], squeeze=False)[:, 0, 0]  # (n_src, n, 3)
        out[:, a:a + step] = np.einsum("is,snk->ink", member, B)
    return out * np.array([c.field_scale for c in coils])[:, None, None]


def _check_coils(coils, name: str) -> tuple:
    if isinstance(coils, Coil):
        coils = (coils,)
    try:
        coils = tuple(coils)
    except TypeError:
        raise TypeError(f"expected `{name}` to be a sequence of Coil, got "
                        f"{type(coils).__name__}") from None
    if not coils:
        raise InputError(f"expected at least one coil in `{name}`, got none")
    for c in coils:
        if not isinstance(c, Coil):
            raise TypeError(f"expected `{name}` to contain Coil objects, got {type(c).__name__}")
    return coils


# --------------------------------------------------------------------------- builders

def _auto_order(order, depth: float, length: float):
    """Default quadrature orders: 2 loops across a winding depth, 2 along a length up to
    10 mm and 3 beyond, and the 4-point area rule (exact for cubic fields). For a 40 mm coil
    at 150 mm this is within ~3e-6 of a converged quadrature (docs/field-models.md)."""
    if order is not None:
        return tuple(order)
    n_length = 1 if length == 0 else (2 if length <= 0.010 else 3)
    return (2 if depth > 0 else 1, n_length, 1)


def circular_coil(center, axis, *, radius, length=0.0, turns=1, gain=1.0, depth=0.0,
                  order=None) -> Coil:
    """A multi-turn circular coil (solenoid winding) of mean ``radius`` (m).

    Parameters
    ----------
    center : array_like, shape (3,)
        Winding centre (m).
    axis : array_like, shape (3,)
        Coil axis (any length; normalised).
    radius : float
        Mean winding radius (m).
    length, depth : float
        Axial winding length and radial winding depth (m); the winding cross-section is
        represented by Gauss-Legendre loops, uniform turn density.
    turns : int
    gain : float
        Dipole-equivalent moment is ``gain * axis``.
    order : (int, int, int), optional
        ``(n_depth, n_length, n_area)``; default: 2 across a depth (else 1), 2 along a length
        up to 10 mm, 3 beyond (else 1), and 1 (the 4-point area rule).
    """
    return Coil("circular", center, coil_frame(axis), radius, length=length, depth=depth,
                turns=turns, gain=gain, order=_auto_order(order, depth, length))


def square_coil(center, axis, *, side, length=0.0, turns=1, gain=1.0, depth=0.0, angle=0.0,
                order=None) -> Coil:
    """A multi-turn square winding of mean ``side`` (m), e.g. a winding around a cube core.

    The square's local x side is the global axis least aligned with ``axis`` projected into
    the coil plane (for ``axis`` = x: sides along y and z; for z: along x and y), turned by
    ``angle`` (rad) about ``axis``. ``depth`` is the radial build-up: the turns' sides run
    from ``side - depth`` to ``side + depth``. Other parameters as :func:`circular_coil`.
    Corners are sharp; no core is modelled (air-core field).
    """
    return Coil("square", center, coil_frame(axis, float(angle)), side, length=length, depth=depth,
                turns=turns, gain=gain, order=_auto_order(order, depth, length))


def square_spiral_coil(center, rotation=0.0, *, turns=25, outer_side=0.070, trace_width=0.0005,
                       spacing=0.00025, layers=2, layer_gap=0.0016, gain=1.0, axis=(0, 0, 1),
                       order=(2, 1, 2)) -> Coil:
    """A square spiral PCB coil (defaults: the Anser field-generator coil).

    Parameters
    ----------
    center : array_like, shape (3,)
        Centre of the coil (mid-plane between the layers), m.
    rotation : float or array_like, shape (3, 3)
        In-plane rotation angle (rad) about ``axis``, or a full rotation matrix whose columns
        are the coil's local x, y, z (then ``axis`` is ignored).
    turns : int
        Turns per layer.
    outer_side, trace_width, spacing, layer_gap : float
        Outer side (outer trace edge to outer trace edge), trace width, gap between traces,
        distance between the two layers (m).
    layers : {1, 2}
    gain : float
    axis : array_like, shape (3,)
        Coil normal when ``rotation`` is an angle.
    """
    if np.ndim(rotation) == 0:
        R = coil_frame(axis, float(rotation))
    else:
        R = rotation
    return Coil("spiral", center, R, outer_side, length=layer_gap, turns=turns, gain=gain,
                trace_width=trace_width, spacing=spacing, layers=layers, order=order)


def anser_field_generator(gain=1.0, *, z=0.0, **spiral) -> tuple[Coil, ...]:
    """The 8 square spiral coils of the Anser EMT field generator, axes +z.

    Coil centres (``ANSER_COIL_CENTERS``) on a 3x3 grid without its centre, coils 2, 4, 5, 7
    (1-based) turned 45 degrees in plane; mid-planes at height ``z`` (m). ``gain`` is a scalar
    or 8 values; extra keywords go to :func:`square_spiral_coil`.

    References
    ----------
    Jaeger et al., "Anser EMT: the first open-source electromagnetic tracking platform for
    image-guided interventions", IJCARS 12 (2017).
    """
    g = np.broadcast_to(np.asarray(gain, dtype=np.float64), (8,))
    out = []
    for k, (x, y) in enumerate(ANSER_COIL_CENTERS):
        ang = np.pi / 4 if k in ANSER_ROTATED_COILS else 0.0
        out.append(square_spiral_coil((x, y, float(z)), ang, gain=float(g[k]), **spiral))
    return tuple(out)
