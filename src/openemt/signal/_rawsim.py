"""Raw-signal simulator of a frequency-multiplexed (FDM) AC tracker, and the raw HDF5 file.

Each source coil ``i`` carries a sinusoidal current at its own carrier frequency ``f_i``
(ILEMT: 7.5, 10.5 and 13.5 kHz, MacLachlan et al. 2025, §VIII-E). Sensor coil ``j`` sees

    v_j(t) = sensor_gain * sum_i Re{ Ct[i, j](t) * I_i(t - delay) } + mains(t) + noise

where ``I_i(t) = A_i (1 + drift(t)) exp(j (2 pi f_i t + phi_i))`` is the analytic drive
current and ``Ct = C * (1 + eddy_i)`` is the coupling of the field model, perturbed by the
eddy currents of a conductive object (first-order response ``kappa * j w tau / (1 + j w tau)``,
which adds an in-phase error and a quadrature part). The sensor front end is taken to return
a voltage proportional to coupling times current (the induction's ``j w`` is equalised by the
preamplifier), optionally delayed by ``delay`` seconds (anti-alias filter group delay), which
appears as a per-carrier phase that a "Ref cal" removes (:func:`openemt.signal.phase_calibration`).
Reference channel ``i`` records ``reference_gain * Re I_i(t)`` plus its own noise, so the
demodulator takes amplitude, sign and phase of each carrier from the measured current.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._constants import OUTPUT_RATE_HZ
from .._errors import InputError

__all__ = [
    "ILEMT_FREQUENCIES",
    "RAW_FORMAT",
    "ChannelLayout",
    "RawSignal",
    "RawSignalConfig",
    "RawSimulator",
    "eddy_factor",
    "read_raw",
    "simulate_raw",
    "write_raw",
]

#: ILEMT's high-rate carrier frequencies for source X, Y, Z (Hz), MacLachlan et al. 2025, §VIII-E.
ILEMT_FREQUENCIES = (7500.0, 10500.0, 13500.0)
#: The ``format`` attribute of a raw HDF5 file written by :func:`write_raw`.
RAW_FORMAT = "openemt-raw"
_RAW_VERSION = 1


@dataclass(frozen=True)
class ChannelLayout:
    """Where the carriers and channels are in a raw sample array.

    Attributes
    ----------
    frequencies : tuple of float, length n_source
        Carrier frequency of source coil i (Hz).
    sample_rate : float
        ADC rate (samples per second).
    sensor_channels : tuple of int, length n_sensor
        Column of the raw array holding sensor coil j.
    reference_channels : tuple of int, length n_source
        Column holding the drive-current reference of source coil i.
    sensor_gain : float
        Volts per (coupling x ampere) of the sensor chain.
    reference_gain : float
        Volts per ampere of the current-sense chain.
    bands : tuple of tuples, each of length n_source
        Further carrier bands: every source coil is also driven at ``bands[b][i]`` (ILEMT:
        274/334/370 Hz beside 7.5/10.5/13.5 kHz), sensed on the same reference channel.
        ``frequencies`` is band 0. Empty (the default): one carrier per coil.
    """

    frequencies: tuple = ILEMT_FREQUENCIES
    sample_rate: float = 96000.0
    sensor_channels: tuple = (0, 1, 2)
    reference_channels: tuple = (3, 4, 5)
    sensor_gain: float = 1.0
    reference_gain: float = 1.0
    bands: tuple = ()

    def __post_init__(self):
        f = tuple(float(x) for x in np.atleast_1d(self.frequencies))
        extra = tuple(tuple(float(x) for x in np.atleast_1d(b)) for b in self.bands)
        if any(len(b) != len(f) for b in extra):
            raise InputError(f"expected every carrier band to have one frequency per source "
                             f"coil ({len(f)}), got bands {[list(b) for b in extra]}")
        object.__setattr__(self, "bands", extra)
        se = tuple(int(x) for x in np.atleast_1d(self.sensor_channels))
        ref = tuple(int(x) for x in np.atleast_1d(self.reference_channels))
        fs = float(self.sample_rate)
        if not (np.isfinite(fs) and fs > 0):
            raise InputError(f"expected a positive `sample_rate`, got {self.sample_rate!r}")
        every = f + sum(extra, ())
        if not f or any(not (0 < x < fs / 2) for x in every) or len(set(every)) != len(every):
            raise InputError(f"expected distinct carrier `frequencies` in (0, {fs / 2:g}) Hz, "
                             f"got {every}")
        if len(ref) != len(f):
            raise InputError(f"expected one reference channel per carrier ({len(f)}), "
                             f"got {len(ref)}")
        if not se:
            raise InputError("expected at least one sensor channel, got none")
        chans = se + ref
        if min(chans) < 0 or len(set(chans)) != len(chans):
            raise InputError(f"expected distinct non-negative channel indices, got sensor {se} "
                             f"and reference {ref}")
        for name in ("sensor_gain", "reference_gain"):
            g = float(getattr(self, name))
            if not np.isfinite(g) or g == 0:
                raise InputError(f"expected a finite non-zero `{name}`, got {g!r}")
            object.__setattr__(self, name, g)
        object.__setattr__(self, "frequencies", f)
        object.__setattr__(self, "sensor_channels", se)
        object.__setattr__(self, "reference_channels", ref)
        object.__setattr__(self, "sample_rate", fs)

    @property
    def n_source(self) -> int:
        return len(self.frequencies)

    @property
    def n_bands(self) -> int:
        return 1 + len(self.bands)

    @property
    def carriers(self) -> tuple:
        """Every carrier, band by band: ``frequencies`` then each of ``bands``; carrier ``c``
        drives source coil ``c % n_source``."""
        return self.frequencies + sum(self.bands, ())

    @property
    def band_frequencies(self) -> np.ndarray:
        """``(n_bands, n_source)`` carrier frequencies (Hz)."""
        return np.asarray(self.carriers).reshape(self.n_bands, self.n_source)

    @property
    def n_sensor(self) -> int:
        return len(self.sensor_channels)

    @property
    def n_channels(self) -> int:
        return max(self.sensor_channels + self.reference_channels) + 1


@dataclass(frozen=True)
class RawSignalConfig:
    """Drive, front end and error sources of the raw-signal simulator (SI units, volts).

    Attributes
    ----------
    layout : ChannelLayout
        Carriers, ADC rate and channel order (default: 3 sensor then 3 reference channels).
    drive_amplitude : float
        Peak drive current of every source coil (A).
    drive_phase : tuple of float or None
        Start phase of each carrier (rad); None draws them from the seed (the demodulator
        must not depend on them).
    noise_rms : float
        White noise on each sensor channel (V rms).
    reference_noise_rms : float
        White noise on each reference channel (V rms).
    mains_frequency : float
        50 or 60 Hz.
    mains_amplitudes : tuple of float
        Peak amplitude (V) on the sensor channels of mains harmonics 1, 2, 3, ...
    drift_amplitude, drift_period : float
        Slow relative drive-gain drift ``a sin(2 pi t / T)`` common to a coil's current (it
        appears in the reference too, so normalisation cancels it).
    eddy_strength, eddy_time_constant : float
        Conductive-object perturbation ``kappa`` and time constant ``tau`` (s); see the module
        docstring.
    delay : float
        Sensor-chain delay relative to the reference chain (s).
    """

    layout: ChannelLayout = field(default_factory=ChannelLayout)
    drive_amplitude: float = 1.0
    drive_phase: tuple | None = None
    noise_rms: float = 1.5e-5
    reference_noise_rms: float = 1.5e-6
    mains_frequency: float = 50.0
    mains_amplitudes: tuple = ()
    drift_amplitude: float = 0.0
    drift_period: float = 10.0
    eddy_strength: float = 0.0
    eddy_time_constant: float = 20e-6
    delay: float = 0.0

    def __post_init__(self):
        if not isinstance(self.layout, ChannelLayout):
            raise TypeError(f"expected `layout` to be a ChannelLayout, got "
                            f"{type(self.layout).__name__}")
        for name in ("noise_rms", "reference_noise_rms", "drift_amplitude", "eddy_strength",
                     "eddy_time_constant", "delay"):
            v = float(getattr(self, name))
            if not np.isfinite(v) or v < 0:
                raise InputError(f"expected a finite non-negative `{name}`, got {v!r}")
        if not (float(self.drive_amplitude) > 0):
            raise InputError(f"expected a positive `drive_amplitude`, got "
                             f"{self.drive_amplitude!r}")
        if self.drive_phase is not None and len(self.drive_phase) != self.layout.n_source:
            raise InputError(f"expected {self.layout.n_source} drive phases, got "
                             f"{len(self.drive_phase)}")
        object.__setattr__(self, "mains_amplitudes",
                           tuple(float(a) for a in self.mains_amplitudes))


def eddy_factor(frequencies, strength: float, time_constant: float) -> np.ndarray:
    """Complex factor ``kappa j w tau / (1 + j w tau)`` per carrier, shape ``(n_source,)``.

    The coupling seen through a conductive object is ``C * (1 + eddy_factor)``: its real part
    shifts the in-phase coupling, its imaginary part is the quadrature distortion indicator.
    """
    jwt = 1j * 2 * np.pi * np.asarray(frequencies, dtype=np.float64) * float(time_constant)
    return float(strength) * jwt / (1 + jwt)


@dataclass(frozen=True, eq=False)
class RawSignal:
    """Raw ADC samples plus their layout and (for simulations) the truth.

    Attributes
    ----------
    samples : ndarray, shape (n_samples, n_channels)
        Volts.
    layout : ChannelLayout
    t0 : float
        Time of the first sample (s).
    truth_times : ndarray, shape (n_truth,) or None
        Times (s) at which the truth is tabulated.
    truth_couplings : ndarray, shape (n_truth, n_source, n_sensor), complex, or None
        Couplings at ``truth_times`` including the eddy perturbation (real part = coupling,
        imaginary part = quadrature).
    truth_poses : ndarray, shape (n_truth, 4, 4) or None
        Sensor poses (m) at ``truth_times``.
    complete : bool
        False for the file of a live session (``track --save-raw``) that was killed before
        it closed the file (its samples end at the last flush).
    """

    samples: np.ndarray
    layout: ChannelLayout
    t0: float = 0.0
    truth_times: np.ndarray | None = None
    truth_couplings: np.ndarray | None = None
    truth_poses: np.ndarray | None = None
    complete: bool = True

    @property
    def n_samples(self) -> int:
        return self.samples.shape[0]

    @property
    def duration(self) -> float:
        return self.n_samples / self.layout.sample_rate


class RawSimulator:
    """Stateful generator of consecutive raw chunks along a pose trajectory.

    Parameters
    ----------
    model : object with ``coupling(poses (N, 4, 4)) -> (N, n_source, n_sensor)``
        A coupling model, e.g. :class:`openemt.field.DipoleModel`.
    trajectory : callable or ndarray
        ``trajectory(times (N,)) -> poses (N, 4, 4)`` in metres, or a fixed pose ``(4, 4)``.
    config : RawSignalConfig
    seed : int
        Seeds the noise and (if not given) the drive phases.
    coupling_stride : int
        Couplings are evaluated every ``coupling_stride`` samples and interpolated linearly
        in between (1 = every sample). Motion is slow against the 96 kS/s rate.
    metal : MetalScene, optional
        Metal objects near the tracker (:class:`openemt.simulate.MetalScene`, in the
        source frame, at the samples' times): their response at every carrier (complex, its
        own per band) is added to the couplings; evaluated every millisecond and
        interpolated.
    """

    def __init__(self, model, trajectory, config: RawSignalConfig | None = None, *, seed=0,
                 coupling_stride: int = 4, metal=None):
        self.config = RawSignalConfig() if config is None else config
        if not isinstance(self.config, RawSignalConfig):
            raise TypeError(f"expected `config` to be a RawSignalConfig, got "
                            f"{type(self.config).__name__}")
        lay = self.config.layout
        if (model.n_source, model.n_sensor) != (lay.n_source, lay.n_sensor):
            raise InputError(f"expected a model with {lay.n_source} sources and {lay.n_sensor} "
                             f"sensors (the layout), got {model.n_source} and {model.n_sensor}")
        self.model = model
        if callable(trajectory):
            self._trajectory = trajectory
        else:
            fixed = np.asarray(trajectory, dtype=np.float64)
            if fixed.shape != (4, 4):
                raise InputError(f"expected `trajectory` to be callable or a (4, 4) pose, got "
                                 f"shape {fixed.shape}")
            self._trajectory = lambda t: np.broadcast_to(fixed, (len(t), 4, 4))
        self.coupling_stride = max(1, int(coupling_stride))
        self._rng = np.random.default_rng(seed)
        c = self.config
        n_carr = len(lay.carriers)
        self._phase = (self._rng.uniform(0, 2 * np.pi, n_carr) if c.drive_phase is None
                       else np.tile(np.asarray(c.drive_phase, dtype=np.float64), lay.n_bands))
        self._omega = 2 * np.pi * np.asarray(lay.carriers)
        self._eddy = 1 + eddy_factor(lay.carriers, c.eddy_strength, c.eddy_time_constant)
        self._coil = np.arange(n_carr) % lay.n_source          # carrier -> source coil
        self.metal = metal
        self._mains_phase = self._rng.uniform(0, 2 * np.pi, max(1, len(c.mains_amplitudes)))
        self.sample_index = 0

    @property
    def layout(self) -> ChannelLayout:
        return self.config.layout

    def poses(self, times) -> np.ndarray:
        """Trajectory poses ``(N, 4, 4)`` at ``times`` (s)."""
        return np.asarray(self._trajectory(np.asarray(times, dtype=np.float64)), dtype=np.float64)

    def true_couplings(self, times, *, bands: bool = False) -> np.ndarray:
        """Complex truth couplings ``(N, n_source, n_sensor)`` at ``times`` (with the eddy
        term and the metal scene) of band 0; with ``bands``, ``(N, n_bands, n_source,
        n_sensor)``."""
        t = np.asarray(times, dtype=np.float64)
        C = self._carrier_couplings(t, self.model.coupling(np.ascontiguousarray(self.poses(t))))
        lay = self.layout
        C = C.reshape(len(t), lay.n_bands, lay.n_source, -1)
        return C if bands else C[:, 0]

    def _carrier_couplings(self, t, C):
        """Couplings per carrier ``(N, n_carriers, n_sensor)`` from the model's ``C``."""
        out = C[:, self._coil] * self._eddy[None, :, None]
        if self.metal is not None:
            out = out + self._metal_part(t)
        return out

    def _metal_part(self, t):
        lay = self.layout
        step = max(1e-3, 1.0 / lay.sample_rate)
        knots = t if len(t) < 2 else np.arange(t[0], t[-1] + step, step)
        P = np.ascontiguousarray(self.poses(knots))
        own = getattr(self.model, "metal_couplings", None)   # a model of several sensors
        parts = [own(self.metal, P, f, knots) if own is not None else
                 self.metal.induced_couplings(self.model, P, f, t=knots)
                 for f in lay.band_frequencies]
        Mk = np.concatenate(parts, axis=1)                          # (k, n_carr, n_se)
        if len(knots) == len(t) and np.array_equal(knots, t):
            return Mk
        flat = Mk.reshape(len(knots), -1)
        out = np.empty((len(t), flat.shape[1]), dtype=complex)
        for k in range(flat.shape[1]):
            out[:, k] = (np.interp(t, knots, flat[:, k].real)
                         + 1j * np.interp(t, knots, flat[:, k].imag))
        return out.reshape(len(t), *Mk.shape[1:])

    def _couplings_per_sample(self, t):
        s = self.coupling_stride
        if s == 1 or len(t) < 2:
            return self.model.coupling(np.ascontiguousarray(self.poses(t)))
        knots = np.append(t[::s], t[-1])
        Ck = self.model.coupling(np.ascontiguousarray(self.poses(knots)))
        flat = Ck.reshape(len(knots), -1)
        out = np.empty((len(t), flat.shape[1]))
        for k in range(flat.shape[1]):
            out[:, k] = np.interp(t, knots, flat[:, k])
        return out.reshape(len(t), *Ck.shape[1:])

    def read(self, n: int) -> np.ndarray:
        """The next ``n`` samples, shape ``(n, n_channels)`` (volts)."""
        c, lay = self.config, self.layout
        n = int(n)
        t = (self.sample_index + np.arange(n)) / lay.sample_rate
        self.sample_index += n
        out = np.zeros((n, lay.n_channels))
        amp = c.drive_amplitude * (1 + c.drift_amplitude * np.sin(2 * np.pi * t / c.drift_period))
        arg = self._omega[None, :] * t[:, None] + self._phase[None, :]          # (n, n_carr)
        drive = np.cos(arg)
        if lay.n_bands > 1:                     # a coil's current: all its bands together
            drive = drive.reshape(n, lay.n_bands, lay.n_source).sum(axis=1)
        out[:, list(lay.reference_channels)] = (lay.reference_gain * amp[:, None] * drive
                                                + c.reference_noise_rms
                                                * self._rng.standard_normal((n, lay.n_source)))
        # sensor: Re{Ct I(t - delay)}; delay acts on the carrier phase (slow envelopes)
        arg_d = arg - self._omega[None, :] * c.delay
        cur = amp[:, None] * np.exp(1j * arg_d)                                  # (n, n_carr)
        Ct = self._carrier_couplings(t, self._couplings_per_sample(t))           # (n, carr, se)
        v = lay.sensor_gain * np.einsum("nij,ni->nj", Ct, cur).real
        for h, a in enumerate(c.mains_amplitudes, start=1):
            if a:
                v += a * np.cos(2 * np.pi * h * c.mains_frequency * t
                                + self._mains_phase[(h - 1) % len(self._mains_phase)])[:, None]
        v += c.noise_rms * self._rng.standard_normal(v.shape)
        out[:, list(lay.sensor_channels)] = v
        return out


def simulate_raw(model, trajectory, duration: float, config: RawSignalConfig | None = None, *,
                 seed=0, truth_rate: float = OUTPUT_RATE_HZ, coupling_stride: int = 4,
                 metal=None) -> RawSignal:
    """Simulate ``duration`` seconds of raw samples along a trajectory.

    Parameters
    ----------
    model, trajectory, config, seed, coupling_stride, metal
        See :class:`RawSimulator`.
    duration : float
        Seconds of signal (rounded down to whole samples).
    truth_rate : float
        Rate (Hz) of the tabulated truth (poses and complex couplings).

    Returns
    -------
    RawSignal
    """
    sim = RawSimulator(model, trajectory, config, seed=seed, coupling_stride=coupling_stride,
                       metal=metal)
    fs = sim.layout.sample_rate
    n = int(np.floor(float(duration) * fs + 1e-9))
    if n < 1:
        raise InputError(f"expected a `duration` of at least one sample, got {duration!r}")
    samples = sim.read(n)
    tt = np.arange(0.0, n / fs, 1.0 / float(truth_rate))
    return RawSignal(samples=samples, layout=sim.layout, t0=0.0, truth_times=tt,
                     truth_couplings=sim.true_couplings(tt), truth_poses=sim.poses(tt))


# --------------------------------------------------------------------------- HDF5 raw file

def raw_attrs(layout: ChannelLayout, t0: float = 0.0) -> dict:
    """The root attributes of a raw HDF5 file (see :func:`write_raw`)."""
    return {"format": RAW_FORMAT, "version": _RAW_VERSION, "sample_rate": layout.sample_rate,
            "frequencies": np.asarray(layout.frequencies),
            "sensor_channels": np.asarray(layout.sensor_channels, dtype=np.int64),
            "reference_channels": np.asarray(layout.reference_channels, dtype=np.int64),
            "sensor_gain": layout.sensor_gain, "reference_gain": layout.reference_gain,
            "t0": float(t0),
            **({"bands": np.asarray(layout.bands)} if layout.bands else {})}


def write_raw(raw: RawSignal, path) -> None:
    """Write a raw recording to HDF5 (schema below), atomically.

    Schema (``format = "openemt-raw"``, ``version = 1``)::

        /samples                  float32|float64 (n_samples, n_channels), volts
        attrs: format, version, sample_rate (Hz), frequencies (n_source,) Hz,
               sensor_channels (n_sensor,), reference_channels (n_source,),
               sensor_gain (V per coupling*A), reference_gain (V/A), t0 (s),
               bands (n_bands - 1, n_source) Hz -- only with several carrier bands
        /truth/times              (n_truth,) s            -- optional (simulations)
        /truth/couplings          complex (n_truth, n_source, n_sensor)
        /truth/poses              (n_truth, 4, 4) m, or (n_truth, K, 4, 4) for K sensors
    """
    from ..io import atomic_h5

    with atomic_h5(path) as f:
        for k, v in raw_attrs(raw.layout, raw.t0).items():
            f.attrs[k] = v
        f.create_dataset("samples", data=np.asarray(raw.samples), chunks=True)
        if raw.truth_times is not None:
            g = f.create_group("truth")
            g.create_dataset("times", data=raw.truth_times)
            if raw.truth_couplings is not None:
                g.create_dataset("couplings", data=raw.truth_couplings)
            if raw.truth_poses is not None:
                g.create_dataset("poses", data=raw.truth_poses)


def read_raw(path) -> RawSignal:
    """Read a raw HDF5 file written by :func:`write_raw`.

    Raises
    ------
    ValueError
        With a one-line message when the file is not a readable openemt raw file.
    FileNotFoundError
        When ``path`` does not exist.
    """
    from ..io._h5safe import check_rows, committed_rows, open_h5

    path = Path(path)
    f = open_h5(path, f"an openemt raw HDF5 file (format {RAW_FORMAT!r})")
    try:
        with f:
            fmt = f.attrs.get("format")
            fmt = fmt.decode() if isinstance(fmt, bytes) else fmt
            if fmt != RAW_FORMAT:
                raise InputError(f"expected an HDF5 file with format {RAW_FORMAT!r}, got "
                                 f"{fmt!r} in {str(path)!r}")
            version = int(f.attrs.get("version", -1))
            if version > _RAW_VERSION:
                raise InputError(f"expected raw file version <= {_RAW_VERSION}, got {version}")
            layout = ChannelLayout(frequencies=tuple(f.attrs["frequencies"]),
                                   sample_rate=float(f.attrs["sample_rate"]),
                                   sensor_channels=tuple(f.attrs["sensor_channels"]),
                                   reference_channels=tuple(f.attrs["reference_channels"]),
                                   sensor_gain=float(f.attrs["sensor_gain"]),
                                   reference_gain=float(f.attrs["reference_gain"]),
                                   bands=tuple(map(tuple, np.asarray(f.attrs.get(
                                       "bands", np.empty((0, 0)))).tolist())))
            samples = f["samples"]
            if getattr(samples, "ndim", None) != 2:
                raise InputError(f"expected `samples` of shape (n, >= {layout.n_channels}), "
                                 f"got {getattr(samples, 'shape', 'a group')} in {str(path)!r}")
            # a file streamed by a live session holds `rows` (committed rows) per group and
            # `complete` (False when the session was killed): read no more than committed
            samples = np.asarray(samples[:committed_rows(f, ("samples",))])
            truth = {}
            times = getattr(f.get("truth/times"), "shape", None)
            if times:
                check_rows(f, path.name, times[0], ("truth/couplings", "truth/poses"),
                           reference="truth/times")
                tail = getattr(f.get("truth/poses"), "shape", (0, 4, 4))[1:]
                if tail[-2:] != (4, 4) or len(tail) > 3:   # one sensor, or K: (n, K, 4, 4)
                    raise InputError(f"{path.name}: expected `truth/poses` of shape (n, 4, 4) or "
                                     f"(n, K, 4, 4), got rows of shape {tail}")
            if "truth" in f:
                g = f["truth"]
                keys = [k for k in ("times", "couplings", "poses") if k in g]
                n = committed_rows(g, keys)
                for key in keys:
                    truth[key] = np.asarray(g[key][:n])
            t0 = float(f.attrs.get("t0", 0.0))
            complete = bool(f.attrs.get("complete", True))
    except ValueError:
        raise
    except (OSError, KeyError, TypeError) as exc:
        msg = " ".join(str(exc).split())
        raise InputError(f"expected a readable openemt raw HDF5 file, got {str(path)!r} "
                         f"({msg})") from None
    if samples.ndim != 2 or samples.shape[1] < layout.n_channels:
        raise InputError(f"expected `samples` of shape (n, >= {layout.n_channels}), got "
                         f"{samples.shape} in {str(path)!r}")
    if samples.dtype.kind != "f" or not np.all(np.isfinite(samples)):
        raise InputError(f"expected finite float samples, got dtype {samples.dtype} or NaN/inf "
                         f"in {str(path)!r}")
    return RawSignal(samples=samples, layout=layout, t0=t0, truth_times=truth.get("times"),
                     truth_couplings=truth.get("couplings"), truth_poses=truth.get("poses"),
                     complete=complete)

