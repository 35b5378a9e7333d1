"""Physics of metal objects in a tracker's field: materials, and the responses of a sphere, a
sheet (half-space or slab), an eddy-current loop network and a magnetised thin body.

Every response is quasi-static (sizes and distances far below the wavelength) with time
dependence ``exp(+i w t)``: a response ``X`` multiplies the phasor of the source current, so a
coupling change ``dC = X C0`` has in-phase part ``Re X`` and quadrature part ``Im X``. None of
these formulas is used by any compensation in openemt: they are the simulator's truth.

Skin depth ``delta = sqrt(2 / (w mu0 mu_r sigma))``, propagation constant ``k = (1 + i) / delta``
(``k**2 = i w mu0 mu_r sigma``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import special

from .._errors import InputError

__all__ = [
    "MATERIALS",
    "MU0",
    "Material",
    "coaxial_mutual_inductance",
    "get_material",
    "loop_self_inductance",
    "magnetised_susceptibility",
    "sheet_impedance",
    "sheet_reflection",
    "skin_depth",
    "sphere_polarizability",
    "wire_impedance",
]

MU0 = 4e-7 * np.pi  # vacuum permeability (H/m)


def _float(v) -> float:
    if isinstance(v, bool):
        return float("nan")
    try:
        return float(v)
    except (TypeError, ValueError):
        return float("nan")


@dataclass(frozen=True)
class Material:
    """A metal (or ferrite): conductivity ``sigma`` (S/m) and relative permeability ``mu_r``."""

    name: str
    conductivity: float
    mu_r: float = 1.0

    def __post_init__(self):
        s, m = _float(self.conductivity), _float(self.mu_r)
        if not (np.isfinite(s) and s >= 0):
            raise InputError(f"expected a finite conductivity >= 0 (S/m) for material "
                             f"{self.name!r}, got {self.conductivity!r}")
        if not (np.isfinite(m) and m >= 1):
            raise InputError(f"expected a finite relative permeability mu_r >= 1 for material "
                             f"{self.name!r}, got {self.mu_r!r}")
        object.__setattr__(self, "conductivity", s)
        object.__setattr__(self, "mu_r", m)

    def to_dict(self) -> dict:
        return {"name": self.name, "conductivity": self.conductivity, "mu_r": self.mu_r}


# Room-temperature values. Conductivities are 1 / resistivity from the sources named:
# - aluminium: 6061-T6 alloy, resistivity 3.99e-8 Ohm m -> 2.5e7 S/m (ASM Handbook vol. 2;
#   pure Al is 3.77e7 S/m, CRC Handbook of Chemistry and Physics, 97th ed., 12-41); mu_r 1.
# - copper: annealed, 1.68e-8 Ohm m -> 5.96e7 S/m (CRC Handbook 12-41); mu_r 1.
# - stainless steel: austenitic AISI 304, 7.2e-7 Ohm m -> 1.39e6 S/m (ASM Handbook vol. 1);
#   mu_r about 1.01 annealed (ASM; cold work raises it), taken as 1.
# - carbon steel: AISI 1010, 1.43e-7 Ohm m -> 6.99e6 S/m (ASM Handbook vol. 1); initial
#   relative permeability of the order of 100 at the weak fields of a tracker (Bozorth,
#   Ferromagnetism, 1951, ch. 2, low-carbon steels: initial mu_r 100-250); 100 taken.
# - titanium: commercially pure grade 2, 5.2e-7 Ohm m -> 1.92e6 S/m (ASM Handbook vol. 2);
#   mu_r 1 (paramagnetic, chi ~ 1.8e-4).
# - ferrite: MnZn power ferrite (e.g. TDK N87 datasheet: resistivity ~10 Ohm m, initial
#   permeability 2200) -> sigma 0.1 S/m, mu_r 2200.
_MATERIALS = (
    Material("aluminium", 2.5e7, 1.0),
    Material("copper", 5.96e7, 1.0),
    Material("stainless_steel", 1.39e6, 1.0),
    Material("carbon_steel", 6.99e6, 100.0),
    Material("titanium", 1.92e6, 1.0),
    Material("ferrite", 0.1, 2200.0),
)
#: Named materials of metal scenes (``name -> Material``), values and sources above.
MATERIALS = {m.name: m for m in _MATERIALS}
_ALIASES = {"aluminum": "aluminium", "stainless": "stainless_steel", "steel": "carbon_steel",
            "stainless steel": "stainless_steel", "carbon steel": "carbon_steel"}


def get_material(spec) -> Material:
    """A :class:`Material` from a name of :data:`MATERIALS` (``"stainless steel"`` and
    ``"stainless_steel"`` alike), a dict ``{conductivity, mu_r[, name]}`` or a Material."""
    if isinstance(spec, Material):
        return spec
    if isinstance(spec, str):
        key = _ALIASES.get(spec.strip().lower(), spec.strip().lower().replace(" ", "_"))
        if key not in MATERIALS:
            raise InputError(f"expected a material in {sorted(MATERIALS)} or a table with "
                             f"conductivity and mu_r, got {spec!r}")
        return MATERIALS[key]
    if isinstance(spec, dict):
        unknown = set(spec) - {"name", "conductivity", "mu_r"}
        if unknown or "conductivity" not in spec:
            raise InputError(f"expected a material table with keys conductivity[, mu_r, name], "
                             f"got {sorted(spec)}")
        return Material(str(spec.get("name", "custom")), spec["conductivity"],
                        spec.get("mu_r", 1.0))
    raise InputError(f"expected a material name or table, got {type(spec).__name__}")


def _omega(frequency) -> np.ndarray:
    f = np.asarray(frequency, dtype=np.float64)
    if not np.all(np.isfinite(f)) or np.any(f <= 0):
        raise InputError(f"expected positive finite frequencies (Hz), got {f.tolist()}")
    return 2.0 * np.pi * f


def skin_depth(frequency, conductivity, mu_r=1.0) -> np.ndarray:
    """``delta = sqrt(2 / (w mu0 mu_r sigma))`` (m); ``inf`` for an insulator."""
    w = _omega(frequency)
    with np.errstate(divide="ignore"):
        return np.sqrt(2.0 / (w * MU0 * mu_r * conductivity))


def _k(frequency, conductivity, mu_r):
    """``k = sqrt(i w mu0 mu_r sigma) = (1 + i) / delta`` (complex, 1/m)."""
    return np.sqrt(1j * _omega(frequency) * MU0 * mu_r * conductivity)


def sphere_polarizability(radius, conductivity, mu_r, frequency) -> np.ndarray:
    """Normalised magnetic polarizability ``kappa`` of a conducting, permeable sphere in a
    uniform alternating field (Wait 1951): the induced moment is ``m = 4 pi a^3 kappa H0``, so
    its field is ``kappa a^3 (3 (B0.u) u - B0) / r^3``.

    With ``x = k a``, ``S - xC = sinh x - x cosh x`` and ``Q = S - xC + x^2 sinh x``::

        kappa = (1/2) [2 mu_r (S - xC) + Q] / [mu_r (S - xC) - Q]

    Limits (tested): ``(mu_r - 1) / (mu_r + 2)`` at ``w -> 0`` (permeable sphere), ``-1/2`` at
    ``a / delta -> inf`` (perfect conductor: ``m = -2 pi a^3 H0``), and for ``mu_r = 1`` at low
    frequency ``-i w mu0 sigma a^2 / 30 + (w mu0 sigma a^2)^2 / 315 ...``. Valid for a source
    far from the sphere compared with its radius (a uniform field over the sphere).

    References
    ----------
    J. R. Wait, "A conducting sphere in a time varying magnetic field", Geophysics 16 (1951)
    666-672; J. D. Jackson, *Classical Electrodynamics*, 3rd ed., problem 5.34 (perfect
    conductor limit).
    """
    a = float(radius)
    mu = float(mu_r)
    f = np.asarray(frequency, dtype=np.float64)
    static = (mu - 1.0) / (mu + 2.0)
    if conductivity == 0:
        return np.full(f.shape, static, dtype=np.complex128)
    x = _k(f, float(conductivity), mu) * a
    small = np.abs(x) < 0.2
    xs = np.where(small, 1.0, x)
    t = np.tanh(xs)                     # everything divided by cosh x: stable for large |x|
    s = t - xs                          # (sinh x - x cosh x) / cosh x
    q = s + xs**2 * t
    exact = 0.5 * (2 * mu * s + q) / (mu * s - q)
    # series for small x: s = -x^3/3 + 2 x^5/15 - 17 x^7/315, q = s + x^2 tanh x
    x2 = x * x
    s_ = -x2 / 3 + 2 * x2**2 / 15 - 17 * x2**3 / 315 + 62 * x2**4 / 2835
    q_ = s_ + x2 * (1 - x2 / 3 + 2 * x2**2 / 15 - 17 * x2**3 / 315)
    series = 0.5 * (2 * mu * s_ + q_) / (mu * s_ - q_)
    return np.where(small, series, exact)


def sheet_reflection(lam, frequency, conductivity, mu_r, thickness) -> np.ndarray:
    """Quasi-static reflection factor ``R`` of a conducting, permeable slab (thickness ``d``)
    for a field of transverse wavenumber ``lam`` (1/m), in the sign of the image method used
    by :mod:`openemt.simulate._metal`: the image of a source coil is its mirror image times
    ``R`` (:math:`R = (\\mu_r-1)/(\\mu_r+1)` for a non-conducting permeable half-space, ``-1``
    for a perfect conductor).

    With ``u = sqrt(lam^2 + k^2)`` and the interface factor ``r = (mu_r lam - u) / (mu_r lam +
    u)``::

        R = r (1 - exp(-2 u d)) / (1 - r^2 exp(-2 u d))

    (a thick slab tends to the half-space ``r``; a thin non-magnetic sheet to
    ``-i w mu0 sigma d / (2 lam + i w mu0 sigma d)``, the thin-sheet (receding image) factor).
    Reference: J. R. Wait, *Geo-Electromagnetism* (Academic Press, 1982), ch. 3 (layered
    half-space, TE reflection coefficient).
    """
    lam = np.asarray(lam, dtype=np.float64)
    mu = float(mu_r)
    k2 = 1j * _omega(frequency) * MU0 * mu * float(conductivity)
    u = np.sqrt(lam**2 + k2)
    r = (mu * lam - u) / (mu * lam + u)
    e = np.exp(-2.0 * u * float(thickness)) if np.isfinite(thickness) else 0.0
    return r * (1.0 - e) / (1.0 - r**2 * e)


def sheet_impedance(frequency, conductivity, mu_r, thickness) -> np.ndarray:
    """Internal impedance per square (Ohm) of a conducting sheet carrying current along it,
    ``Z = (k / sigma) coth(k d)``: ``1 / (sigma d)`` for ``d << delta``, the surface impedance
    ``(1 + i) / (sigma delta)`` for ``d >> delta`` (current on the side facing the source)."""
    sigma = float(conductivity)
    k = _k(frequency, sigma, float(mu_r))
    kd = k * float(thickness)
    small = np.abs(kd) < 1e-3
    kds = np.where(small, 1.0, kd)
    coth = np.where(np.real(kds) > 30, 1.0, 1.0 / np.tanh(kds))
    return np.where(small, 1.0 / (sigma * float(thickness)) * (1 + kd**2 / 3), k / sigma * coth)


def wire_impedance(frequency, conductivity, mu_r, radius) -> np.ndarray:
    """Internal impedance per metre (Ohm/m) of a round wire of ``radius`` with skin effect:
    ``Z' = (k / (2 pi a sigma)) I0(k a) / I1(k a)`` (Ramo, Whinnery and Van
    Duzer, *Fields and Waves in Communication Electronics*, §5.12); ``1 / (pi a^2 sigma)`` at
    low frequency, ``(1 + i) / (2 pi a sigma delta)`` when ``a >> delta``."""
    sigma, a = float(conductivity), float(radius)
    k = _k(frequency, sigma, float(mu_r))
    ka = k * a
    small = np.abs(ka) < 1e-3
    kas = np.where(small, 1.0, ka)
    ratio = special.ive(0, kas) / special.ive(1, kas)   # scaled: no overflow for large |ka|
    dc = 1.0 / (np.pi * a**2 * sigma)
    return np.where(small, dc * (1 + ka**2 / 8), k / (2 * np.pi * a * sigma) * ratio)


def coaxial_mutual_inductance(r1, r2, z=0.0) -> np.ndarray:
    """Mutual inductance (H) of two coaxial circular filaments of radii ``r1``, ``r2`` at axial
    distance ``z`` (Maxwell): ``mu0 sqrt(r1 r2) [(2/k - k) K(k) - (2/k) E(k)]`` with
    ``k^2 = 4 r1 r2 / ((r1 + r2)^2 + z^2)`` (scipy's ``ellipk(m)`` takes ``m = k^2``)."""
    r1, r2, z = (np.asarray(v, dtype=np.float64) for v in (r1, r2, z))
    m = 4 * r1 * r2 / ((r1 + r2) ** 2 + z**2)
    k = np.sqrt(m)
    return MU0 * np.sqrt(r1 * r2) * ((2 / k - k) * special.ellipk(m) - 2 / k * special.ellipe(m))


def loop_self_inductance(shape: str, size, gmd: float) -> float:
    """External self inductance (H) of a loop of conductor with geometric mean distance
    ``gmd`` (m) of its cross-section (a round wire of radius a: ``a``, with all the current
    on its surface; a rectangular strip w x d: ``0.2235 (w + d)``; Grover, *Inductance
    Calculations*, 1946): the internal part is in :func:`sheet_impedance` /
    :func:`wire_impedance`.

    ``circle`` (size = radius R): ``mu0 R (ln(8 R / g) - 2)``; ``rectangle`` (size = full side
    lengths A, B): ``(mu0/pi) [A ln(2A/g) + B ln(2B/g) + 2 sqrt(A^2+B^2) - A asinh(A/B) -
    B asinh(B/A) - 2 (A + B)]`` (Grover, ch. 14).
    """
    g = float(gmd)
    if shape == "circle":
        R = float(size)
        return MU0 * R * (np.log(8 * R / g) - 2.0)
    A, B = (float(v) for v in size)
    D = np.hypot(A, B)
    return MU0 / np.pi * (A * np.log(2 * A / g) + B * np.log(2 * B / g) + 2 * D
                          - A * np.arcsinh(A / B) - B * np.arcsinh(B / A) - 2 * (A + B))


def magnetised_susceptibility(frequency, conductivity, mu_r, thickness, demag) -> np.ndarray:
    """Apparent susceptibility ``chi = (mu_eff - 1) / (1 + N (mu_eff - 1))`` of a permeable
    plate (or wire) magnetised along a direction of demagnetising factor ``N`` (``demag``),
    with the eddy-current screening of the field inside a conducting sheet of ``thickness``
    (the lamination formula ``mu_eff = mu_r tanh(k d / 2) / (k d / 2)``; Bozorth,
    *Ferromagnetism*, ch. 17; ``mu_eff -> mu_r`` at low frequency). Moment per volume
    ``M = chi H``: a uniformly magnetised ellipsoid's demagnetisation applied to the whole body
    (an approximation for a plate: uniform-ish field over it)."""
    f = np.asarray(frequency, dtype=np.float64)
    mu = float(mu_r)
    if conductivity > 0 and thickness > 0:
        h = _k(f, float(conductivity), mu) * float(thickness) / 2
        small = np.abs(h) < 1e-3
        hs = np.where(small, 1.0, h)
        factor = np.where(small, 1 - h**2 / 3, np.tanh(hs) / hs)
        mu_eff = mu * factor
    else:
        mu_eff = np.full(f.shape, mu, dtype=np.complex128)
    return (mu_eff - 1) / (1 + float(demag) * (mu_eff - 1))
