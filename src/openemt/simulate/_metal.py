"""Metal scenes: conducting and permeable objects near a tracker, and the coupling changes they
cause at every carrier frequency (docs/simulator.md#metal-scenes).

A scene is a list of objects (sphere, disk, plate, sheet, ring) of a named material or a given
conductivity and permeability, each at a pose in the scene frame, fixed or moving with a stated
motion. :meth:`MetalScene.induced_couplings` returns the complex coupling change
``(N, n_source, n_sensor)`` to add to the clean couplings, for any coupling model whose coil
geometry it can read (a :class:`~openemt.field.DipoleModel`, a board model, or any model with a
``dipole_equivalent()``).

How each object responds (physics in :mod:`openemt.simulate._metal_physics`; all are
quasi-static and linear in the source field ``B_i`` of source coil ``i``):

- ``sphere``: the induced dipole of a conducting permeable sphere in a uniform field (Wait),
  valid for sources far from the sphere compared with its radius.
- ``sheet``: an infinite slab (thin sheet or thick plate, conducting and/or permeable), by the
  image method: every spectral component of the source coils' mirror image is scaled by the
  slab's reflection factor ``R(lam)``, which is a series of real images (the mirror image and
  copies moved further from the surface, with complex weights fitted to ``R(lam)`` over the
  wavenumbers the geometry needs: :func:`~openemt.simulate._metal_physics.image_series`), a
  discrete form of the Sommerfeld integral of an infinite slab (no edges); tested against
  that integral itself.
- ``disk`` / ``plate`` (finite, thin): an eddy-current loop network. The body is cut into
  ``filaments`` concentric strips (circles for a disk, rectangles for a plate); each is a
  circuit with the strip's resistance and internal inductance (sheet impedance with skin
  effect), its external self inductance (Grover) and mutual inductances to the others (Maxwell
  for coaxial circles, the flux of one strip's field through the other for rectangles). The
  source drives each by ``-i w Phi_l`` (the flux of ``B_i`` through the strip's loop):
  ``(Z_R + i w L) I = -i w Phi``. The loops' field at the sensor comes from the segment
  Biot-Savart kernel of :mod:`openemt.field`. Only currents that circulate about the body's
  centre are represented (exact by symmetry for a disk in a uniform axial field).
  A permeable (``mu_r > 1``) body is also magnetised: every area cell carries a dipole of
  susceptibility ``(mu_eff - 1) / (1 + N (mu_eff - 1))`` with the thin plate's demagnetising
  factors (``N = pi d / (4 D)`` in its plane, ``1 - 2 N`` along its normal) and the
  eddy-current screening of a sheet of its thickness (lamination formula for ``mu_eff``); an
  approximation of a uniformly magnetised ellipsoid, stated as such.
- ``ring``: one circular filament of round wire (skin-effect wire impedance, self inductance
  ``mu0 R (ln(8 R / a) - 2)``), the classic ``R / (R + i w L)`` circuit, plus (``mu_r > 1``)
  magnetised wire cells (tangential ``N = 0``, transverse ``N = 1/2``).

Objects do not interact with each other (each responds to the source field alone).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._errors import InputError
from ..geometry import pose_from_rt
from ._metal_physics import (
    Material,
    coaxial_mutual_inductance,
    get_material,
    image_series,
    loop_self_inductance,
    magnetised_susceptibility,
    sheet_impedance,
    sphere_polarizability,
    wire_impedance,
)

__all__ = ["METAL_KINDS", "METAL_SCENES", "MetalObject", "MetalScene", "Motion", "load_scene",
           "metal_scene", "rig_volume"]

#: Object kinds of a metal scene.
METAL_KINDS = ("sphere", "disk", "plate", "sheet", "ring")
#: Named scenes (:func:`metal_scene`), the metal benchmark's scenes: the four of the metal
#: benchmark's targets, then conductive-only objects whose eddy response the carrier bands
#: separate (thin or poorly conducting: stainless steel, titanium).
METAL_SCENES = ("clean", "aluminium_sheet", "steel_plate", "moving_ring", "stainless_sheet",
                "titanium_sheet", "titanium_disk", "stainless_ring")
MOTION_KINDS = ("fixed", "linear", "periodic", "waypoints")
#: Most objects of one scene (bounded work: each object is evaluated on every sample).
MAX_SCENE_OBJECTS = 100

_CIRCLE_VERTICES = 64
_RECT_VERTICES_PER_SIDE = 16
_GAUSS_S = np.polynomial.legendre.leggauss(3)
_GAUSS_T = np.polynomial.legendre.leggauss(2)


def _vec(v, name: str, n: int = 3) -> tuple:
    try:
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        a = np.full(0, np.nan)
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise InputError(f"expected `{name}` as {n} finite numbers, got {v!r}")
    return tuple(float(x) for x in a)


def _positive(v, name: str) -> float:
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise InputError(f"expected `{name}` as a positive number, got {v!r}") from None
    if not (np.isfinite(x) and x > 0):
        raise InputError(f"expected `{name}` as a positive finite number, got {v!r}")
    return x


# --------------------------------------------------------------------------------------------
# motion
@dataclass(frozen=True)
class Motion:
    """How an object moves: an offset ``(N, 3)`` (m, scene frame) added to its position at
    times ``t`` (s).

    ``fixed``; ``linear`` (``velocity`` m/s from the position at t = 0); ``periodic``
    (``amplitude * sin(2 pi t / period_s + phase)``, amplitude per axis in m, phase in rad);
    ``waypoints`` (offsets ``positions (n, 3)`` at ``times (n,)``, linear between them, held
    before the first and after the last).
    """

    kind: str = "fixed"
    velocity: tuple = (0.0, 0.0, 0.0)
    amplitude: tuple = (0.0, 0.0, 0.0)
    period_s: float = 1.0
    phase: float = 0.0
    times: tuple = ()
    positions: tuple = ()

    def __post_init__(self):
        if self.kind not in MOTION_KINDS:
            raise InputError(f"expected a motion kind in {list(MOTION_KINDS)}, got "
                             f"{self.kind!r}")
        object.__setattr__(self, "velocity", _vec(self.velocity, "motion.velocity"))
        object.__setattr__(self, "amplitude", _vec(self.amplitude, "motion.amplitude"))
        object.__setattr__(self, "period_s", _positive(self.period_s, "motion.period_s"))
        object.__setattr__(self, "phase", _vec([self.phase], "motion.phase", 1)[0])
        if self.kind == "waypoints":
            try:
                t = np.asarray(self.times, dtype=np.float64)
                p = np.asarray(self.positions, dtype=np.float64)
            except (TypeError, ValueError):
                t, p = np.zeros((0, 0)), np.zeros(0)
            if t.ndim != 1 or len(t) < 1 or p.shape != (len(t), 3) or np.any(np.diff(t) <= 0) \
                    or not (np.all(np.isfinite(t)) and np.all(np.isfinite(p))):
                raise InputError(f"expected motion waypoints as increasing `times` (n,) and "
                                 f"`positions` (n, 3), got times {t.shape}, positions {p.shape}")
            object.__setattr__(self, "times", tuple(t.tolist()))
            object.__setattr__(self, "positions", tuple(map(tuple, p.tolist())))

    @property
    def moving(self) -> bool:
        return self.kind != "fixed"

    def offset(self, t) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        if self.kind == "fixed":
            return np.zeros((len(t), 3))
        if self.kind == "linear":
            return t[:, None] * np.asarray(self.velocity)
        if self.kind == "periodic":
            return np.sin(2 * np.pi * t / self.period_s + self.phase)[:, None] * \
                np.asarray(self.amplitude)
        T, P = np.asarray(self.times), np.asarray(self.positions)
        return np.stack([np.interp(t, T, P[:, a]) for a in range(3)], axis=1)

    @classmethod
    def from_dict(cls, d) -> Motion:
        if d is None:
            return cls()
        if not isinstance(d, dict):
            raise InputError(f"expected a motion table, got {type(d).__name__}")
        unknown = set(d) - {"kind", "velocity", "amplitude", "period_s", "phase", "times",
                            "positions"}
        if unknown:
            raise InputError(f"expected motion keys kind, velocity, amplitude, period_s, phase, "
                             f"times, positions, got {sorted(unknown)}")
        return cls(**d)

    def to_dict(self) -> dict:
        out = {"kind": self.kind}
        if self.kind == "linear":
            out["velocity"] = list(self.velocity)
        elif self.kind == "periodic":
            out.update(amplitude=list(self.amplitude), period_s=self.period_s, phase=self.phase)
        elif self.kind == "waypoints":
            out.update(times=list(self.times), positions=[list(p) for p in self.positions])
        return out


# --------------------------------------------------------------------------------------------
# the tracker's coils, as the objects see them
class _Coils:
    """Source coils (field at points, their mirror image) and sensor coils (where they read
    a field) of a coupling model, in the units of its couplings: a sensor coil of "moment"
    ``v`` reading a field ``b`` gives ``v . b``."""

    def __init__(self, model):
        from ..board import BoardModel

        self.model = model
        if isinstance(model, BoardModel):
            self.kind = "segments"
            self.S = np.asarray(model.segments)
            self.off = np.asarray(model.segment_offsets)
            self.gains = np.asarray(model.gains, dtype=np.float64)
            self.centres = np.stack([c.center for c in model.board.coils]) + model.offsets
            self.n_source = model.n_source
        else:
            if getattr(model, "kind", None) != "dipole":     # the model says what it is
                if not hasattr(model, "dipole_equivalent"):
                    raise InputError(f"expected a dipole model, a board model or a model with "
                                     f"a dipole equivalent for a metal scene, got "
                                     f"{type(model).__name__}")
                model = model.dipole_equivalent()
            self.kind = "dipole"
            self.L = np.asarray(model.L_so, dtype=np.float64).T.copy()
            self.M = np.asarray(model.M_so, dtype=np.float64).T * model.gain
            self.centres = self.L
            self.n_source = model.n_source
        self._sensor_model = model

    def field(self, pts) -> np.ndarray:
        """Source fields ``(n_source, P, 3)`` at points ``(P, 3)``."""
        pts = np.ascontiguousarray(pts, dtype=np.float64).reshape(-1, 3)
        if self.kind == "dipole":
            from ..field import DipoleModel, coupling

            src = DipoleModel(self.L.T, self.M.T, np.zeros((3, 3)), np.eye(3), 1.0)
            return coupling(src, _at_points(pts)).transpose(1, 0, 2)
        from ..field._segments import segment_fields

        return segment_fields(self.S, self.off, pts) * self.gains[:, None, None]

    def mirrored(self, point, normal) -> _Coils:
        """The source coils mirrored in the plane (their image with factor 1)."""
        n = np.asarray(normal) / np.linalg.norm(normal)
        H = np.eye(3) - 2 * np.outer(n, n)
        c = np.asarray(point)
        out = object.__new__(_Coils)
        out.__dict__.update(self.__dict__)
        if self.kind == "dipole":
            out.L = (self.L - c) @ H + c
            out.M = -self.M @ H                     # mirrored loop: moment -H m
        else:
            out.S = np.ascontiguousarray((self.S - c) @ H + c)   # same traversal order
        out.centres = (self.centres - c) @ H + c
        return out

    def sensors(self, poses):
        """Where the sensor coils read: points ``(N, n_se, Q, 3)``, weights ``(n_se, Q)`` and
        the coil vectors ``(N, n_se, 3)``."""
        P = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
        R, t = P[:, :3, :3], P[:, :3, 3]
        if self.kind == "dipole":
            m = self._sensor_model
            p = np.einsum("nab,bj->nja", R, m.L_se) + t[:, None, :]
            v = np.einsum("nab,bj->nja", R, m.M_se)
            return p[:, :, None, :], np.ones((m.n_sensor, 1)), v
        from ..field._segments import sensor_rule

        m = self.model
        L = m.board.sensor.coil_positions()
        A = m.board.sensor.coil_axes()
        p = np.einsum("nab,kb->nka", R, L) + t[:, None, :]
        u = np.einsum("nab,kb->nka", R, A)
        nodes, weights = sensor_rule(float(m.sensor_length))
        pts = p[:, :, None, :] + nodes[None, None, :, None] * u[:, :, None, :]
        w = np.asarray(m.sensor_gains)[:, None] * weights[None, :]
        return pts, w, u


def _at_points(pts) -> np.ndarray:
    return pose_from_rt(np.eye(3), pts)


def dipole_fields(pos, mom, pts, chunk: int = 1_000_000) -> np.ndarray:
    """Fields ``(n_src, P, 3)`` of point dipoles at ``pos (C, 3)`` with moments
    ``mom (n_src, C, 3)`` (real or complex), summed over the dipoles, in the dipole model's
    convention ``(3 (m.u) u - m) / d^3`` (no mu0 / 4 pi): the dipole kernel of
    :mod:`openemt.field` with unit coils at the dipoles and at the points."""
    from ..field import DipoleModel, coupling

    pos = np.asarray(pos, dtype=np.float64).reshape(-1, 3)
    mom = np.asarray(mom)
    pts = np.asarray(pts, dtype=np.float64).reshape(-1, 3)
    C = len(pos)
    unit = DipoleModel(np.repeat(pos.T, 3, axis=1), np.tile(np.eye(3), C), np.zeros((3, 3)),
                       np.eye(3), 1.0)
    out = np.zeros((mom.shape[0], len(pts), 3), dtype=np.result_type(mom.dtype, np.float64))
    step = max(1, chunk // (9 * C))
    for a in range(0, len(pts), step):
        D = coupling(unit, _at_points(pts[a:a + step])).reshape(-1, C, 3, 3)   # (p, C, a, b)
        out[:, a:a + step] = np.einsum("pcab,nca->npb", D, mom)
    return out


# --------------------------------------------------------------------------------------------
# objects
_OBJECT_KEYS = {"kind", "name", "material", "position", "rotation", "radius", "size",
                "thickness", "wire_radius", "filaments", "motion"}


def _rotation(rv) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(np.asarray(rv)).as_matrix()


@dataclass(frozen=True, eq=False)
class MetalObject:
    """One object of a metal scene, in its local frame (symmetry axis / sheet normal = local
    +z) placed at ``position`` (m) turned by ``rotation`` (rotation vector, rad) in the scene
    frame.

    Attributes by kind: ``sphere``: ``radius``; ``disk``: ``radius``, ``thickness``;
    ``plate``: ``size`` (full side lengths along local x, y), ``thickness``; ``sheet``:
    ``thickness`` (infinite extent, its surface the local z = 0 plane, the metal below, the
    tracker on the +z side; ``inf`` for a half-space); ``ring``: ``radius`` (of the
    centreline) and ``wire_radius``. ``filaments``: strips of a disk or plate's loop network
    (default 8). ``material``: a :class:`~openemt.simulate._metal_physics.Material`, a name of
    ``MATERIALS`` or ``{conductivity, mu_r}``.
    """

    kind: str
    material: Material
    position: tuple = (0.0, 0.0, 0.0)
    rotation: tuple = (0.0, 0.0, 0.0)
    radius: float | None = None
    size: tuple | None = None
    thickness: float | None = None
    wire_radius: float | None = None
    filaments: int = 8
    motion: Motion = field(default_factory=Motion)
    name: str = ""

    def __post_init__(self):
        if self.kind not in METAL_KINDS:
            raise InputError(f"expected an object kind in {list(METAL_KINDS)}, got "
                             f"{self.kind!r}")
        object.__setattr__(self, "material", get_material(self.material))
        object.__setattr__(self, "position", _vec(self.position, "position"))
        object.__setattr__(self, "rotation", _vec(self.rotation, "rotation"))
        if not isinstance(self.motion, Motion):
            object.__setattr__(self, "motion", Motion.from_dict(self.motion))
        need = {"sphere": ("radius",), "disk": ("radius", "thickness"),
                "plate": ("size", "thickness"), "sheet": ("thickness",),
                "ring": ("radius", "wire_radius")}[self.kind]
        for key in need:
            if getattr(self, key) is None:
                raise InputError(f"expected `{key}` for a {self.kind} (needs "
                                 f"{', '.join(need)}), got none")
        for key in ("radius", "thickness", "wire_radius"):
            v = getattr(self, key)
            if v is not None:
                if key == "thickness" and self.kind == "sheet" and v == float("inf"):
                    continue
                object.__setattr__(self, key, _positive(v, key))
        if self.size is not None:
            s = _vec(self.size, "size", 2)
            if min(s) <= 0:
                raise InputError(f"expected a positive plate `size`, got {self.size!r}")
            object.__setattr__(self, "size", s)
        if self.kind == "ring" and self.wire_radius >= self.radius:
            raise InputError(f"expected a ring's wire_radius below its radius, got "
                             f"{self.wire_radius} and {self.radius}")
        n = self.filaments
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= n <= 64:
            raise InputError(f"expected `filaments` as an integer 1-64, got {n!r}")

    @classmethod
    def from_dict(cls, d) -> MetalObject:
        if not isinstance(d, dict):
            raise InputError(f"expected an object table, got {type(d).__name__}")
        unknown = set(d) - _OBJECT_KEYS
        if unknown or "kind" not in d or "material" not in d:
            raise InputError(f"expected object keys kind, material and some of "
                             f"{sorted(_OBJECT_KEYS - {'kind', 'material'})}, got {sorted(d)}")
        d = dict(d)
        if d.get("thickness") == "inf":
            d["thickness"] = float("inf")
        return cls(**d)

    def to_dict(self) -> dict:
        out = {"kind": self.kind, "material": self.material.to_dict(),
               "position": list(self.position), "rotation": list(self.rotation)}
        for key in ("radius", "thickness", "wire_radius", "name"):
            v = getattr(self, key)
            if v is not None and v != "":
                out[key] = "inf" if v == float("inf") else v
        if self.size is not None:
            out["size"] = list(self.size)
        if self.kind in ("disk", "plate"):
            out["filaments"] = self.filaments
        out["motion"] = self.motion.to_dict()
        return out

    def transforms(self, t) -> np.ndarray:
        """Object -> scene transforms ``(N, 4, 4)`` at times ``t`` (N,)."""
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        return pose_from_rt(_rotation(self.rotation),
                            np.asarray(self.position) + self.motion.offset(t))

    # -- local geometry ----------------------------------------------------------------------
    def _polygon(self) -> np.ndarray:
        """The outline (V, 3) in local coordinates (z = 0), counter-clockwise about +z."""
        if self.kind in ("disk", "ring"):
            a = np.linspace(0, 2 * np.pi, _CIRCLE_VERTICES, endpoint=False)
            return self.radius * np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1)
        A, B = self.size[0] / 2, self.size[1] / 2
        s = np.linspace(-1, 1, _RECT_VERTICES_PER_SIDE, endpoint=False)
        one = np.ones_like(s)
        sides = [np.stack([A * one, B * s], 1), np.stack([-A * s, B * one], 1),
                 np.stack([-A * one, -B * s], 1), np.stack([A * s, -B * one], 1)]
        xy = np.concatenate(sides)
        return np.concatenate([xy, np.zeros((len(xy), 1))], axis=1)

    def _scales(self) -> np.ndarray:
        """Centreline scales of the filaments (outline = 1)."""
        if self.kind == "ring":
            return np.array([1.0])
        K = self.filaments
        return (np.arange(K) + 0.5) / K

    def _network(self):
        """Filament segments (local), quadrature of their fluxes, and a function of the
        frequency giving the impedance matrix."""
        poly = self._polygon()
        s = self._scales()
        V = len(poly)
        seg = np.stack([poly, np.roll(poly, -1, axis=0)], axis=1)            # (V, 2, 3)
        S = np.concatenate([seg * sc for sc in s])
        off = np.arange(len(s) + 1) * V
        # flux quadrature: the fan of triangles (centre, v_m, v_m+1) cut at the centrelines
        breaks = np.concatenate([[0.0], s])
        pts, wts, band = _fan_quadrature(poly, breaks)
        # flux of filament l: the bands 0..l
        A = (band[None, :] <= np.arange(len(s))[:, None]).astype(float) * wts[None, :]
        return S, off, pts, A

    def _inductance(self, S, off, pts, A) -> np.ndarray:
        s = self._scales()
        K = len(s)
        L = np.zeros((K, K))
        if self.kind == "ring":
            L[0, 0] = loop_self_inductance("circle", self.radius, self.wire_radius)
            return L
        w = self._strip_width()
        g = 0.2235 * (w + self.thickness)
        for l_ in range(K):
            if self.kind == "disk":
                L[l_, l_] = loop_self_inductance("circle", s[l_] * self.radius, g)
            else:
                L[l_, l_] = loop_self_inductance(
                    "rectangle", (s[l_] * self.size[0], s[l_] * self.size[1]), g)
        if self.kind == "disk":
            r = s * self.radius
            for a in range(K):
                for b in range(a + 1, K):
                    L[a, b] = L[b, a] = coaxial_mutual_inductance(r[a], r[b])
        else:
            from ..field._segments import segment_fields

            # flux of the field of filament b (1 A) through the inner filament a
            B = segment_fields(S, off, pts)[..., 2]                            # (K, Q)
            for a in range(K):
                for b in range(a + 1, K):
                    L[a, b] = L[b, a] = A[a] @ B[b]
        return L

    def _strip_width(self) -> float:
        if self.kind == "disk":
            return self.radius / self.filaments
        return 0.5 * (self.size[0] + self.size[1]) / 2 / self.filaments

    def _resistance_factor(self, poly) -> np.ndarray:
        """Per filament: sum over its edges of length / strip width (squares in series)."""
        s = self._scales()
        K = len(s)
        e = np.roll(poly, -1, axis=0) - poly
        length = np.linalg.norm(e, axis=1)
        h = np.abs(np.cross(poly, e)[:, 2]) / length            # centre to edge line
        return s * K * np.sum(length / h)

    def _impedance(self, f, parts) -> np.ndarray:
        S, off, pts, A, L = parts
        mat = self.material
        w = 2 * np.pi * f
        if self.kind == "ring":
            Z = wire_impedance(f, mat.conductivity, mat.mu_r, self.wire_radius) * \
                2 * np.pi * self.radius
            return np.array([[Z + 1j * w * L[0, 0]]])
        zs = sheet_impedance(f, mat.conductivity, mat.mu_r, self.thickness)
        return np.diag(zs * self._resistance_factor(self._polygon())) + 1j * w * L

    def _cells(self, f):
        """Magnetised cells (local positions (C, 3), polarizability tensors (C, 3, 3) in the
        dipole units ``V chi / (4 pi)``) at frequency ``f``; none for mu_r = 1."""
        mat = self.material
        if mat.mu_r == 1.0 or self.kind in ("sphere", "sheet"):
            return None
        if self.kind == "ring":
            n = _CIRCLE_VERTICES
            a = (np.arange(n) + 0.5) * 2 * np.pi / n
            pos = self.radius * np.stack([np.cos(a), np.sin(a), np.zeros(n)], 1)
            tang = np.stack([-np.sin(a), np.cos(a), np.zeros(n)], 1)
            vol = np.pi * self.wire_radius**2 * 2 * np.pi * self.radius / n
            d = 2 * self.wire_radius
            chi_t = magnetised_susceptibility(f, mat.conductivity, mat.mu_r, d, 0.0)
            chi_n = magnetised_susceptibility(f, mat.conductivity, mat.mu_r, d, 0.5)
            T = chi_n * np.eye(3)[None] + (chi_t - chi_n) * tang[:, :, None] * tang[:, None, :]
            return pos, vol / (4 * np.pi) * T
        poly = self._polygon()
        pts, wts, _ = _fan_quadrature(poly, np.linspace(0, 1, 5))
        diam = 2 * self.radius if self.kind == "disk" else math.sqrt(self.size[0] * self.size[1])
        N_t = np.pi * self.thickness / (4 * diam)
        chi_t = magnetised_susceptibility(f, mat.conductivity, mat.mu_r, self.thickness, N_t)
        chi_n = magnetised_susceptibility(f, mat.conductivity, mat.mu_r, self.thickness,
                                          1 - 2 * N_t)
        T = np.diag([chi_t, chi_t, chi_n]).astype(np.complex128)
        return pts, (wts * self.thickness / (4 * np.pi))[:, None, None] * T[None]


def _fan_quadrature(poly, breaks):
    """Area quadrature of the star-shaped outline ``poly`` (V, 3; z = 0) cut into bands at the
    scales ``breaks`` (0 = centre, 1 = outline): points (Q, 3), weights (Q,) and band (Q,)."""
    xs, ws = _GAUSS_S
    xt, wt = _GAUSS_T
    v0, v1 = poly, np.roll(poly, -1, axis=0)
    jac = np.abs(np.cross(v0, v1)[:, 2])                        # (V,): 2 x triangle area
    pts, wts, band = [], [], []
    for b, (s0, s1) in enumerate(zip(breaks[:-1], breaks[1:])):
        s = 0.5 * (s1 - s0) * xs + 0.5 * (s1 + s0)
        w_s = 0.5 * (s1 - s0) * ws
        tau = 0.5 * xt + 0.5
        w_t = 0.5 * wt
        edge = v0[:, None, :] + tau[None, :, None] * (v1 - v0)[:, None, :]       # (V, T, 3)
        p = s[:, None, None, None] * edge[None]                                   # (S, V, T, 3)
        w = (w_s * s)[:, None, None] * jac[None, :, None] * w_t[None, None, :]
        pts.append(p.reshape(-1, 3))
        wts.append(w.reshape(-1))
        band.append(np.full(w.size, b))
    return np.concatenate(pts), np.concatenate(wts), np.concatenate(band)


# --------------------------------------------------------------------------------------------
# the scene
@dataclass(frozen=True, eq=False)
class MetalScene:
    """Metal objects near a tracker (docs/simulator.md#metal-scenes).

    ``sample_period_s`` is the time between consecutive rows when a simulation gives the
    samples no times of their own (the objects' motion is a function of time).
    """

    objects: tuple = ()
    sample_period_s: float = 0.1
    name: str = ""

    def __post_init__(self):
        if len(self.objects) > MAX_SCENE_OBJECTS:
            raise InputError(f"expected at most {MAX_SCENE_OBJECTS} objects in a metal scene, "
                             f"got {len(self.objects)}")
        objs = tuple(o if isinstance(o, MetalObject) else MetalObject.from_dict(o)
                     for o in self.objects)
        object.__setattr__(self, "objects", objs)
        object.__setattr__(self, "sample_period_s",
                           _positive(self.sample_period_s, "sample_period_s"))

    @property
    def moving(self) -> bool:
        return any(o.motion.moving for o in self.objects)

    @property
    def conductive_only(self) -> bool:
        """True when no object is permeable (``mu_r = 1``): the eddy-current response alone."""
        return all(o.material.mu_r == 1.0 for o in self.objects)

    @classmethod
    def from_dict(cls, d, name: str = "") -> MetalScene:
        if not isinstance(d, dict):
            raise InputError(f"expected a metal scene table, got {type(d).__name__}")
        unknown = set(d) - {"object", "objects", "sample_period_s", "name"}
        if unknown:
            raise InputError(f"expected metal scene keys object (an array of tables), "
                             f"sample_period_s, name, got {sorted(unknown)}")
        objs = d.get("object", d.get("objects", []))
        if isinstance(objs, dict):
            objs = [objs]
        if not isinstance(objs, list):
            raise InputError(f"expected `object` as an array of tables, got "
                             f"{type(objs).__name__}")
        if len(objs) > MAX_SCENE_OBJECTS:
            raise InputError(f"expected at most {MAX_SCENE_OBJECTS} objects in a metal scene, "
                             f"got {len(objs)}")
        return cls(tuple(MetalObject.from_dict(o) for o in objs),
                   d.get("sample_period_s", 0.1), str(d.get("name", name)))

    @classmethod
    def from_toml(cls, path) -> MetalScene:
        """A scene from a TOML file: ``[[object]]`` tables (docs/simulator.md#metal-scenes)."""
        from ..io._safefile import read_toml

        p = Path(path)
        try:
            d = read_toml(p, "a metal scene file (TOML)", "a metal scene")
        except FileNotFoundError:
            raise InputError(f"expected an existing metal scene file, got {str(p)!r}") from None
        try:
            return cls.from_dict(d, name=p.stem)
        except InputError as exc:
            raise InputError(f"{p}: {exc}") from None

    def to_dict(self) -> dict:
        return {"name": self.name, "sample_period_s": self.sample_period_s,
                "object": [o.to_dict() for o in self.objects]}

    def times(self, n: int) -> np.ndarray:
        """Times (s) of ``n`` consecutive rows: ``k * sample_period_s``."""
        return np.arange(n) * self.sample_period_s

    def induced_couplings(self, model, poses, frequency_hz, t=None, frame=None) -> np.ndarray:
        """Coupling change ``(N, n_source, n_sensor)`` (complex) caused by the scene, to be
        added to the clean couplings of ``model`` at sensor ``poses (N, 4, 4)`` (source frame).

        ``frequency_hz``: each source coil's carrier (scalar or ``(n_source,)``). ``t``: the
        samples' times (s, ``(N,)``; default 0: objects at their start positions). ``frame``:
        the scene -> source-frame transform, ``(4, 4)`` or per sample ``(N, 4, 4)`` (default
        identity: the scene is given in the source frame).
        """
        P = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
        n = P.shape[0]
        coils = _Coils(model)
        f = np.broadcast_to(np.asarray(frequency_hz, dtype=np.float64), (coils.n_source,))
        if not np.all(np.isfinite(f)) or np.any(f <= 0):
            raise InputError(f"expected positive carrier frequencies, got {f.tolist()}")
        t = np.zeros(n) if t is None else np.broadcast_to(np.asarray(t, np.float64), (n,))
        F = np.eye(4) if frame is None else np.asarray(frame, dtype=np.float64)
        F = np.broadcast_to(F, (n, 4, 4))
        pts, w, vec = coils.sensors(P)
        n_se = w.shape[0]
        C = np.zeros((n, coils.n_source, n_se), dtype=np.complex128)
        for obj in self.objects:
            G = F @ obj.transforms(t)                                   # object -> source
            key = np.round(G[:, :3, :].reshape(n, 12), 12)
            uniq, inv = np.unique(key, axis=0, return_inverse=True)
            resp = _Response(obj, coils, f)
            for g in range(len(uniq)):
                rows = np.flatnonzero(inv.ravel() == g)
                b = resp.field(G[rows[0]], pts[rows])                   # (n_so, k, n_se, Q, 3)
                C[rows] += np.einsum("ikjqa,jq,kja->kij", b, w, vec[rows])
        return C


class _Response:
    """One object's response to the source coils (per carrier), evaluated at sensor points."""

    def __init__(self, obj: MetalObject, coils: _Coils, f: np.ndarray):
        self.obj, self.coils, self.f = obj, coils, f
        self._net = None
        if obj.kind in ("disk", "plate", "ring") and obj.material.conductivity > 0:
            S, off, qp, A = obj._network()
            L = obj._inductance(S, off, qp, A)
            parts = (S, off, qp, A, L)
            uf, finv = np.unique(f, return_inverse=True)
            Zinv = [np.linalg.inv(obj._impedance(fu, parts)) for fu in uf]
            self._net = (S, off, qp, A, [Zinv[i] for i in finv.ravel()])
        self._cells = None
        if obj.kind in ("disk", "plate", "ring"):
            cells = [obj._cells(fi) for fi in f]
            if cells[0] is not None:
                self._cells = (cells[0][0], np.stack([c[1] for c in cells]))  # (C,3), (n,C,3,3)
        if obj.kind == "sphere":
            m = obj.material
            self._kappa = sphere_polarizability(obj.radius, m.conductivity, m.mu_r, f)

    def field(self, G, pts) -> np.ndarray:
        """Scattered fields ``(n_source, *pts.shape[:-1], 3)`` with the object at ``G``."""
        shape = pts.shape[:-1]
        X = pts.reshape(-1, 3)
        R, c = G[:3, :3], G[:3, 3]
        obj, coils = self.obj, self.coils
        ns = coils.n_source
        out = np.zeros((ns, len(X), 3), dtype=np.complex128)
        if obj.kind == "sphere":
            B0 = coils.field(c[None])[:, 0]                              # (n_so, 3)
            mom = (self._kappa * obj.radius**3)[:, None] * B0
            out += dipole_fields(c[None], mom[:, None, :], X)
        elif obj.kind == "sheet":
            out += self._sheet(c, R[:, 2], X)
        if self._net is not None:
            S, off, qp, A, Zinv = self._net
            from ..field._segments import segment_fields

            Q = qp @ R.T + c
            n = R[:, 2]
            flux = A @ (coils.field(Q) @ n).T                           # (K, n_so)
            w = 2 * np.pi * self.f
            cur = np.stack([Zinv[i] @ (-1j * w[i] * flux[:, i]) for i in range(ns)])  # (n_so, K)
            Sg = np.ascontiguousarray(S @ R.T + c)
            Bl = segment_fields(Sg, off, X)                             # (K, P, 3)
            out += np.einsum("ik,kpa->ipa", cur, Bl)
        if self._cells is not None:
            pos, T = self._cells
            Pc = pos @ R.T + c
            B0 = coils.field(Pc)                                         # (n_so, C, 3)
            Tg = np.einsum("ab,ncbd,ed->ncae", R, T, R)                  # rotate the tensors
            mom = np.einsum("ncab,ncb->nca", Tg, B0)
            out += dipole_fields(Pc, mom, X)
        return out.reshape((ns,) + shape + (3,))

    def _sheet(self, c, nrm, X) -> np.ndarray:
        obj, coils = self.obj, self.coils
        m = obj.material
        hs = (coils.centres - c) @ nrm                                   # (n_so,)
        hr = (X - c) @ nrm                                               # (P,)
        if np.any(hs <= 0):
            raise InputError(f"expected the source coils on the tracker's side (+z) of the "
                             f"sheet {obj.name or ''!s}, got source heights "
                             f"{np.round(hs, 4).tolist()} m")
        if np.any(hr <= 0):
            raise InputError(f"expected every sensor on the tracker's side (+z) of the sheet "
                             f"{obj.name or ''!s}, got a sensor {-hr.min():.4g} m behind it")
        h_min = float(hs.min() + hr.min())
        h_max = float(hs.max() + hr.max())
        out = np.zeros((coils.n_source, len(X), 3), dtype=np.complex128)
        series = {fi: image_series(fi, m.conductivity, m.mu_r, obj.thickness, h_min, h_max)
                  for fi in np.unique(self.f)}
        depths = series[self.f[0]][0]                  # the same depths for every carrier
        weights = np.stack([series[fi][1] for fi in self.f])             # (n_so, K)
        for k, s in enumerate(depths):
            # the mirror image moved s further from the surface: mirror in a plane s/2 deeper
            Bk = coils.mirrored(c - 0.5 * s * nrm, nrm).field(X)          # (n_so, P, 3)
            out += weights[:, k, None, None] * Bk
        return out


# --------------------------------------------------------------------------------------------
# named scenes
def rig_volume() -> tuple[np.ndarray, np.ndarray]:
    """The simulated ILEMT rig's sensor volume in the bench frame (m): the corners of the box
    of the stage patterns' sensor positions (the ``dipole-approx`` preset's true fixtures)."""
    return np.array([-0.051, 0.193, -0.034]), np.array([0.051, 0.295, 0.063])


def metal_scene(name: str, volume=None) -> MetalScene:
    """A named scene (:data:`METAL_SCENES`) placed about ``volume`` (the corners ``(lo, hi)``
    of the tracked volume in the scene frame, ``+z`` up; default :func:`rig_volume`, the
    simulated rig's bench frame):

    - ``clean``: nothing.
    - ``aluminium_sheet``: a 2 mm aluminium sheet (infinite) 100 mm under the volume.
    - ``steel_plate``: a 300 x 300 x 2 mm carbon-steel plate 100 mm beside the volume (+x),
      facing it.
    - ``moving_ring``: a C-arm-like carbon-steel ring (radius 0.3 m, 25 mm wire radius) in a
      plane 150 mm beside the volume (+x), its centre moving along y through +-0.3 m about
      the volume's centre (period 120 s).
    - ``stainless_sheet`` / ``titanium_sheet``: the aluminium sheet's geometry (2 mm,
      infinite, 100 mm under the volume) in stainless steel (AISI 304) / titanium (grade 2).
    - ``titanium_disk``: a titanium disk (grade 2), 200 mm across and 2 mm thick, 50 mm under
      the volume, centred under it.
    - ``stainless_ring``: a stainless-steel ring (radius 50 mm, 5 mm wire radius: the
      circulating eddy current of a short stainless tube as one loop, a stand-in for ILEMT's
      stainless-tube measurement) in a plane 50 mm beside the volume (+x), facing it.
    """
    lo, hi = rig_volume() if volume is None else (np.asarray(v, float) for v in volume)
    mid = 0.5 * (lo + hi)
    if name == "clean":
        objs = ()
    elif name == "aluminium_sheet":
        objs = (MetalObject("sheet", "aluminium", (mid[0], mid[1], lo[2] - 0.1),
                            thickness=0.002, name="aluminium sheet"),)
    elif name == "steel_plate":
        objs = (MetalObject("plate", "carbon_steel", (hi[0] + 0.1, mid[1], mid[2]),
                            (0.0, -np.pi / 2, 0.0), size=(0.3, 0.3), thickness=0.002,
                            name="steel plate"),)
    elif name == "moving_ring":
        objs = (MetalObject("ring", "carbon_steel", (hi[0] + 0.15, mid[1], mid[2]),
                            (0.0, np.pi / 2, 0.0), radius=0.3, wire_radius=0.025,
                            motion=Motion("periodic", amplitude=(0.0, 0.3, 0.0),
                                          period_s=120.0),
                            name="C-arm ring"),)
    elif name in ("stainless_sheet", "titanium_sheet"):
        mat = name.split("_")[0].replace("stainless", "stainless_steel")
        objs = (MetalObject("sheet", mat, (mid[0], mid[1], lo[2] - 0.1), thickness=0.002,
                            name=name.replace("_", " ")),)
    elif name == "titanium_disk":
        objs = (MetalObject("disk", "titanium", (mid[0], mid[1], lo[2] - 0.05), radius=0.1,
                            thickness=0.002, name="titanium disk"),)
    elif name == "stainless_ring":
        objs = (MetalObject("ring", "stainless_steel", (hi[0] + 0.05, mid[1], mid[2]),
                            (0.0, np.pi / 2, 0.0), radius=0.05, wire_radius=0.005,
                            name="stainless ring"),)
    else:
        raise InputError(f"expected a metal scene name in {list(METAL_SCENES)} or a scene "
                         f"file (.toml), got {name!r}")
    return MetalScene(objs, name=name)


def load_scene(spec, volume=None) -> MetalScene | None:
    """A scene from a :class:`MetalScene`, a name of :data:`METAL_SCENES`, a TOML file path
    or a dict (an inline table); ``None`` stays ``None``."""
    if spec is None or isinstance(spec, MetalScene):
        return spec
    if isinstance(spec, dict):
        return MetalScene.from_dict(spec)
    if isinstance(spec, (str, Path)):
        if str(spec) in METAL_SCENES:
            return metal_scene(str(spec), volume)
        return MetalScene.from_toml(spec)
    raise InputError(f"expected a metal scene (name, TOML file or table), got "
                     f"{type(spec).__name__}")

