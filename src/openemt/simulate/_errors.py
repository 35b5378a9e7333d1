"""Error sources of the simulated apparatus: measurement noise, source drift, field distortion.

All functions are pure array functions; the randomness comes from a ``np.random.Generator``
passed in. Stage position error is applied in :func:`openemt.simulate.simulate` (it changes the
true pose, not the couplings' model).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ..field import DipoleModel, coupling
from ..geometry import pose_from_rt
from ._metal_physics import MU0, sphere_polarizability

__all__ = [
    "MU0",
    "Distortion",
    "add_noise",
    "distortion_coupling",
    "drift_factors",
    "noise_sigma",
    "polarizability",
]



def noise_sigma(C, *, snr_db=None, noise_abs=None) -> np.ndarray:
    """Per-sample noise standard deviation, shape (N,).

    With ``snr_db``: ``sigma_k = rms(C[k]) / 10**(snr_db / 20)``, where ``rms(C[k])`` is the root
    mean square of the magnitudes of the sample's noise-free couplings (all n_source x n_sensor
    entries). With ``noise_abs``: ``sigma_k = noise_abs`` for every sample. Exactly one of the two
    must be given.
    """
    C = np.asarray(C)
    if (snr_db is None) == (noise_abs is None):
        raise ValueError(f"expected exactly one of snr_db and noise_abs, got snr_db={snr_db!r}, "
                         f"noise_abs={noise_abs!r}")
    if snr_db is not None:
        snr = float(snr_db)
        if not np.isfinite(snr):
            raise ValueError(f"expected a finite snr_db, got {snr_db!r}")
        rms = np.sqrt(np.mean(np.abs(C) ** 2, axis=(1, 2)))
        return rms / 10.0 ** (snr / 20.0)
    s = float(noise_abs)
    if not np.isfinite(s) or s < 0:
        raise ValueError(f"expected a finite noise_abs >= 0, got {noise_abs!r}")
    return np.full(C.shape[0], s)


def add_noise(C, sigma, rng: np.random.Generator) -> np.ndarray:
    """``C`` plus white Gaussian noise of standard deviation ``sigma[k]`` on every entry.

    For complex couplings the in-phase (real) and quadrature (imaginary) parts each get
    independent noise of standard deviation ``sigma`` (as two demodulator channels would).
    """
    C = np.asarray(C)
    s = np.asarray(sigma, dtype=np.float64)[:, None, None]
    out = C + s * rng.standard_normal(C.shape)
    if np.iscomplexobj(C):
        out = out + 1j * s * rng.standard_normal(C.shape)
    return out


def drift_factors(drift, n_samples: int, n_source: int) -> np.ndarray:
    """Source gain factors ``1 + drift_i * k / (N - 1)`` for rows k of the run, shape (N, n_source).

    ``drift`` is the relative change of each source coil's gain between the first and the last
    row of the run (acquisition order): a scalar for all coils or an array (n_source,).
    """
    d = np.asarray(drift, dtype=np.float64)
    if d.ndim == 0:
        d = np.full(n_source, float(d))
    if d.shape != (n_source,) or not np.all(np.isfinite(d)):
        raise ValueError(f"expected a finite drift scalar or array of shape ({n_source},), "
                         f"got {np.asarray(drift).shape}")
    ramp = np.linspace(0.0, 1.0, n_samples) if n_samples > 1 else np.zeros(n_samples)
    return 1.0 + ramp[:, None] * d[None, :]


@dataclass(frozen=True)
class Distortion:
    """A small object near the tracker that distorts the field (an induced magnetic dipole).

    Attributes
    ----------
    kind : str
        ``"conductive"`` (non-magnetic metal, eddy currents: complex polarizability, gives an
        in-phase change and a quadrature component) or ``"ferromagnetic"`` (non-conducting
        permeable material such as ferrite: real positive polarizability).
    position : tuple of float
        Centre of the object (m) in the bench frame, i.e. the base frame of the source fixture
        (the frame into which ``F_so . so_J`` maps source coordinates). The object stays put when
        the source fixture is turned.
    radius : float
        Radius of the equivalent sphere (m).
    conductivity : float
        Electrical conductivity (S/m) for ``conductive`` (default aluminium, 3.5e7).
    mu_r : float
        Relative permeability for ``ferromagnetic`` (default 1000).
    """

    kind: str
    position: tuple[float, float, float]
    radius: float
    conductivity: float = 3.5e7
    mu_r: float = 1000.0

    def __post_init__(self):
        if self.kind not in ("conductive", "ferromagnetic"):
            raise ValueError(f"expected distortion kind 'conductive' or 'ferromagnetic', "
                             f"got {self.kind!r}")
        pos = np.asarray(self.position, dtype=np.float64)
        if pos.shape != (3,) or not np.all(np.isfinite(pos)):
            raise ValueError(f"expected a finite distortion position of shape (3,), got "
                             f"{self.position!r}")
        object.__setattr__(self, "position", tuple(float(v) for v in pos))
        for name in ("radius", "conductivity", "mu_r"):
            v = float(getattr(self, name))
            if not np.isfinite(v) or v <= 0:
                raise ValueError(f"expected a positive finite distortion {name}, got "
                                 f"{getattr(self, name)!r}")
            object.__setattr__(self, name, v)

    @classmethod
    def from_any(cls, obj) -> Distortion:
        """A ``Distortion`` from itself or a dict of its fields."""
        if isinstance(obj, cls):
            return obj
        if isinstance(obj, dict):
            try:
                return cls(**obj)
            except TypeError as exc:
                raise TypeError(f"expected distortion keys kind, position, radius[, "
                                f"conductivity, mu_r], got {sorted(obj)}") from exc
        raise TypeError(f"expected a Distortion or a dict, got {type(obj).__name__}")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["position"] = list(self.position)
        return d


def polarizability(d: Distortion, frequency) -> np.ndarray:
    """Dimensionless magnetic polarizability ``kappa`` of the object's sphere at ``frequency``.

    The induced moment is ``m = kappa * a**3 * B`` in the units of the dipole model (where the
    field of moment M is ``(3 (M.u) u - M) / d**3``). For a permeable sphere
    ``kappa = (mu_r - 1) / (mu_r + 2)``. For a non-magnetic conducting sphere (time dependence
    ``exp(+i w t)``, skin depth ``delta = sqrt(2 / (w mu0 sigma))``, ``k = (1 - i) / delta``)
    ``kappa = -(1/2) [1 - 3/(ka)^2 + 3 cot(ka)/(ka)]``: about ``-i w mu0 sigma a^2 / 30`` at low
    frequency and ``-1/2`` (perfect conductor) when the skin depth is small.

    Returns complex ``kappa`` with the shape of ``frequency``.

    References
    ----------
    J. D. Jackson, *Classical Electrodynamics*, 3rd ed., problems 5.34/8.x (eddy-current sphere);
    L. D. Landau and E. M. Lifshitz, *Electrodynamics of Continuous Media*, §59.
    """
    f = np.asarray(frequency, dtype=np.float64)
    if d.kind == "ferromagnetic":
        return np.full(f.shape, (d.mu_r - 1.0) / (d.mu_r + 2.0), dtype=np.complex128)
    return sphere_polarizability(d.radius, d.conductivity, 1.0, f)


def distortion_coupling(model: DipoleModel, poses, position, kappa, radius) -> np.ndarray:
    """Coupling change from an induced dipole at ``position`` (source frame), (N, n_so, n_se).

    Source coil i's field at the object, ``B_i``, induces ``m_i = kappa[i] * radius**3 * B_i``
    (``kappa`` per source coil: it depends on the coil's drive frequency); its field at sensor
    coil j adds ``gain * m_sensor_j . B(m_i)``. ``position`` is ``(3,)`` or ``(N, 3)`` (the object
    is fixed in the bench frame, so its source-frame position depends on the source fixture).
    Coils are taken as their dipole equivalents (the object is a small perturbation). Both
    fields come from the dipole model of :mod:`openemt.field` (docs/field-models.md): ``B_i`` as
    the coupling of the source coils into three unit coils at the object, and the induced
    dipole's field as the coupling of three unit coils at the object into the sensor coils,
    combined linearly in the induced moment.
    """
    P = np.asarray(poses, dtype=np.float64)
    n = P.shape[0]
    q = np.broadcast_to(np.asarray(position, dtype=np.float64), (n, 3))
    kappa = np.asarray(kappa, dtype=np.complex128)
    unit = np.eye(3)
    at_object = pose_from_rt(unit, q)
    # field of each source coil at the object, B[k, i, a] (N, n_so, 3)
    B = coupling(DipoleModel(model.L_so, model.M_so, np.zeros((3, 3)), unit, 1.0), at_object)
    m_ind = kappa[None, :, None] * radius**3 * B
    # coupling of a unit moment along axis a at the object into sensor coil j: (N, 3, n_se)
    rel = P.copy()
    rel[:, :3, 3] = P[:, :3, 3] - q
    T = coupling(DipoleModel(np.zeros((3, 3)), unit, model.L_se, model.M_se, model.gain), rel)
    return np.einsum("kia,kaj->kij", m_ind, T)
