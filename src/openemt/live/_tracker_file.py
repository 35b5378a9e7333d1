"""The tracker description file: one TOML file that says how a tracker is wired.

It names the ADC (sample rate, number of channels, gains), the carriers and which channel
records each source coil's current reference, every sensor (its coil channels, its calibration
file, the OpenIGTLink device name it is streamed under), the demodulation settings, an
optional tracking filter and, for ``--source sim``, the simulated set-up. The schema, with
every key, is in docs/live.md#tracker-file; :func:`read_tracker` validates a file and raises
:class:`~openemt._errors.InputError` with one line naming the file, the key, what was expected
and what arrived.

Units are SI (Hz, V, m, s, rad). Calibration paths are relative to the TOML file.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path

from .._constants import OUTPUT_RATE_HZ
from .._errors import InputError

__all__ = [
    "MAX_ADC_CHANNELS",
    "MAX_CARRIERS",
    "MAX_FRAME_VALUES",
    "MAX_LIST_ITEMS",
    "MAX_SAMPLE_RATE_HZ",
    "MAX_SAMPLE_VALUES_PER_S",
    "MAX_SENSORS",
    "TRACKER_FORMAT",
    "FilterSpec",
    "SensorSpec",
    "TrackerSpec",
    "example_tracker",
    "read_tracker",
    "relative_device_name",
    "tracker_from_dict",
]

#: The ``format`` value of a tracker description file.
TRACKER_FORMAT = "openemt-tracker"
_VERSION = 1
_MISSING = object()
_FILTER_KINDS = ("none", "kalman")
#: Default of ``[igtl] stale_after``: seconds without a valid pose before a sensor is stale.
DEFAULT_STALE_AFTER = 0.5


def relative_device_name(sensor_name: str) -> str:
    """The OpenIGTLink device name of a sensor streamed relative to the reference sensor:
    ``<sensor name>ToReference``."""
    return f"{sensor_name}ToReference"

# Limits of a tracker file (docs/robustness.md, "Bounded work"): far above any real tracker,
# low enough that a careless or hostile value is an error instead of an exhausted memory.
#: highest ADC sample rate (Hz)
MAX_SAMPLE_RATE_HZ = 10e6
#: most ADC input channels
MAX_ADC_CHANNELS = 256
#: most samples per second over all channels (adc.sample_rate x adc.channels)
MAX_SAMPLE_VALUES_PER_S = 1e8
#: most values in one demodulation frame (frame length x adc.channels)
MAX_FRAME_VALUES = 1 << 25
#: most source carriers
MAX_CARRIERS = 64
#: most sensors
MAX_SENSORS = 64
#: most items in any list of the file
MAX_LIST_ITEMS = 256


@dataclass(frozen=True)
class FilterSpec:
    """Tracking filter settings (see :mod:`openemt.live._filter` and docs/live.md#filter).

    Attributes
    ----------
    kind : str
        ``"none"`` or ``"kalman"`` (constant-velocity Kalman filter per sensor).
    process_noise : float
        Position process noise: white-acceleration spectral density ``q`` (m/s^2/sqrt(Hz)).
    measurement_noise : float
        Position measurement noise per axis (m, standard deviation).
    rotation_process_noise : float
        Orientation process noise: white angular-acceleration density (rad/s^2/sqrt(Hz)).
    rotation_measurement_noise : float
        Orientation measurement noise per axis (rad, standard deviation).
    max_gap : float
        A gap between valid samples longer than this (s) restarts the filter.
    """

    kind: str = "none"
    process_noise: float = 0.01
    measurement_noise: float = 2e-6
    rotation_process_noise: float = 0.1
    rotation_measurement_noise: float = 2e-5
    max_gap: float = 0.02

    @property
    def enabled(self) -> bool:
        return self.kind != "none"


@dataclass(frozen=True)
class SensorSpec:
    """One sensor of a tracker.

    Attributes
    ----------
    name : str
        Sensor name, also its OpenIGTLink device name unless ``device_name`` differs
        (1-20 characters).
    channels : tuple of int
        ADC channel of each sensor coil (X, Y, Z order of the calibration's model).
    calibration : Path or None
        Calibration file (JSON or ILEMT .mat), absolute; None = the simulated preset's model.
    device_name : str
        OpenIGTLink device name (Slicer transform node name).
    hemisphere : str
        Hemisphere for acquisition with the closed-form start.
    simulation_offset : tuple of 3 float
        ``--source sim`` only: this sensor follows the default trajectory shifted by this
        vector (m) in the source frame.
    filter : FilterSpec or None
        This sensor's own filter settings (``[filter.sensors.<name>]``); None = the
        tracker's ``[filter]``.
    tip : ndarray (4, 4) or None
        Tip transform of the tool the sensor is mounted in (key ``tip``: a pivot calibration
        from ``openemt pivot``, relative to the tracker file): the stream shows
        ``pose @ tip``, the tool tip.
    """

    name: str
    channels: tuple
    calibration: Path | None = None
    device_name: str = ""
    hemisphere: str = "+x"
    simulation_offset: tuple = (0.0, 0.0, 0.0)
    filter: FilterSpec | None = None
    tip: object = None

    def filter_or(self, default: FilterSpec) -> FilterSpec:
        return default if self.filter is None else self.filter


@dataclass(frozen=True)
class TrackerSpec:
    """A validated tracker description (see :func:`read_tracker`)."""

    sample_rate: float
    n_channels: int
    frequencies: tuple
    reference_channels: tuple
    sensors: tuple
    sensor_gain: float = 1.0
    reference_gain: float = 1.0
    output_rate: float = OUTPUT_RATE_HZ
    window: str = "hann"
    distortion_threshold: float = 1e-3
    filter: FilterSpec = field(default_factory=FilterSpec)
    simulation: dict = field(default_factory=dict)
    path: Path | None = None
    reference: str | None = None
    stale_after: float = DEFAULT_STALE_AFTER
    tdata: bool = False
    metadata: bool = True

    @property
    def sensor_names(self) -> tuple:
        return tuple(s.name for s in self.sensors)

    def layout(self):
        """The :class:`~openemt.signal.ChannelLayout` of the whole ADC: the sensor channels of
        every sensor in order (sensor 0's coils first), then the references."""
        from ..signal import ChannelLayout

        chans = tuple(c for s in self.sensors for c in s.channels)
        return ChannelLayout(frequencies=self.frequencies, sample_rate=self.sample_rate,
                             sensor_channels=chans, reference_channels=self.reference_channels,
                             sensor_gain=self.sensor_gain, reference_gain=self.reference_gain)

    def sensor_columns(self) -> list:
        """Per sensor, the columns of the layout's coupling matrix that hold its coils."""
        out, k = [], 0
        for s in self.sensors:
            out.append(tuple(range(k, k + len(s.channels))))
            k += len(s.channels)
        return out

    def calibrations(self) -> list:
        """Per sensor, its calibration (read from the file), or None when it names none."""
        from ..io import read_calibration

        cals = []
        for s in self.sensors:
            if s.calibration is None:
                cals.append(None)
                continue
            try:
                cal = read_calibration(s.calibration)
            except (ValueError, OSError) as exc:
                raise InputError(f"{self._where()}: expected a readable calibration for sensor "
                                 f"{s.name!r}, got {' '.join(str(exc).split())}") from None
            n_se, n_so = cal.n_sensor, cal.n_source       # dipole or board calibration
            if n_se != len(s.channels):
                raise InputError(
                    f"{self._where()}: expected sensor {s.name!r} to list one channel per coil "
                    f"of its calibration ({n_se}), got {len(s.channels)}")
            if n_so != len(self.frequencies):
                raise InputError(
                    f"{self._where()}: expected the calibration of sensor {s.name!r} to have "
                    f"{len(self.frequencies)} source coils, got {n_so}")
            cals.append(cal)
        return cals

    def with_filter(self, **changes) -> TrackerSpec:
        """A copy with filter settings changed (command-line overrides, applied to the
        tracker's ``[filter]`` and to every sensor's own settings), validated."""
        merged = {k: v for k, v in changes.items() if v is not None}
        if not merged:
            return self
        spec = replace(self.filter, **merged)
        _check_filter(spec, "command line")
        sensors = tuple(s if s.filter is None else replace(s, filter=replace(s.filter, **merged))
                        for s in self.sensors)
        return replace(self, filter=spec, sensors=sensors)

    def _where(self) -> str:
        return str(self.path) if self.path is not None else "tracker"


# --------------------------------------------------------------------------- validation

class _Reader:
    """Typed access to a TOML table with one-line errors naming file and key."""

    def __init__(self, where: str):
        self.where = where

    def fail(self, key: str, expected: str, got) -> InputError:
        return InputError(f"{self.where}: expected `{key}` to be {expected}, got {got}")

    def get(self, table: dict, prefix: str, key: str, kind: str, default=_MISSING):
        full = f"{prefix}.{key}" if prefix else key
        if key not in table:
            if default is _MISSING:
                raise InputError(f"{self.where}: expected key `{full}` ({kind}), got it missing")
            return default
        v = table[key]
        if kind == "number":
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise self.fail(full, "a number", _show(v))
            return float(v)
        if kind == "integer":
            if isinstance(v, bool) or not isinstance(v, int):
                raise self.fail(full, "an integer", _show(v))
            return int(v)
        if kind == "string":
            if not isinstance(v, str):
                raise self.fail(full, "a string", _show(v))
            return v
        if kind == "boolean":
            if not isinstance(v, bool):
                raise self.fail(full, "true or false", _show(v))
            return v
        if kind == "table":
            if not isinstance(v, dict):
                raise self.fail(full, "a table", _show(v))
            return v
        if kind.startswith("list of "):
            item = kind[len("list of "):]
            if not isinstance(v, list) or not v:
                raise self.fail(full, f"a non-empty list of {item}", _show(v))
            if len(v) > MAX_LIST_ITEMS:
                raise self.fail(full, f"a list of at most {MAX_LIST_ITEMS} {item}",
                                f"{len(v)} items")
            return [self._item(full, x, item) for x in v]
        raise AssertionError(kind)  # pragma: no cover

    def _item(self, full, x, item):
        if item == "numbers":
            if isinstance(x, bool) or not isinstance(x, (int, float)):
                raise self.fail(full, "a list of numbers", f"an item {_show(x)}")
            return float(x)
        if item == "integers":
            if isinstance(x, bool) or not isinstance(x, int):
                raise self.fail(full, "a list of integers", f"an item {_show(x)}")
            return int(x)
        if item == "tables":
            if not isinstance(x, dict):
                raise self.fail(full, "a list of tables", f"an item {_show(x)}")
            return x
        raise AssertionError(item)  # pragma: no cover


def _show(v) -> str:
    s = repr(v)
    return f"{type(v).__name__} {s[:60]}"


def _unknown_keys(r: _Reader, table: dict, prefix: str, allowed) -> None:
    extra = sorted(set(table) - set(allowed))
    if extra:
        name = f"{prefix}.{extra[0]}" if prefix else extra[0]
        raise InputError(f"{r.where}: expected only the keys {sorted(allowed)} in "
                         f"[{prefix or 'top level'}], got unknown key `{name}`")


def _check_filter(f: FilterSpec, where: str, prefix: str = "filter") -> None:
    if f.kind not in _FILTER_KINDS:
        raise InputError(f"{where}: expected `{prefix}.kind` in {list(_FILTER_KINDS)}, got "
                         f"{f.kind!r}")
    for key in ("process_noise", "measurement_noise", "rotation_process_noise",
                "rotation_measurement_noise", "max_gap"):
        v = float(getattr(f, key))
        if not (v > 0 and v < float("inf")):
            raise InputError(f"{where}: expected `{prefix}.{key}` to be a positive number, "
                             f"got {v!r}")


def tracker_from_dict(doc: dict, path=None) -> TrackerSpec:
    """Validate a parsed tracker description (see :func:`read_tracker`)."""
    path = None if path is None else Path(path)
    where = str(path) if path is not None else "tracker"
    base = path.parent if path is not None else Path(".")
    r = _Reader(where)
    _unknown_keys(r, doc, "", ("format", "version", "adc", "source", "demodulation", "sensors",
                               "filter", "simulation", "igtl"))
    fmt = r.get(doc, "", "format", "string")
    if fmt != TRACKER_FORMAT:
        raise r.fail("format", repr(TRACKER_FORMAT), repr(fmt))
    version = r.get(doc, "", "version", "integer")
    if not 1 <= version <= _VERSION:
        raise r.fail("version", f"1..{_VERSION}", version)

    adc = r.get(doc, "", "adc", "table")
    _unknown_keys(r, adc, "adc", ("sample_rate", "channels", "sensor_gain", "reference_gain"))
    fs = r.get(adc, "adc", "sample_rate", "number")
    if not (fs > 0 and fs < float("inf")):
        raise r.fail("adc.sample_rate", "a positive number (Hz)", fs)
    if fs > MAX_SAMPLE_RATE_HZ:
        raise r.fail("adc.sample_rate", f"at most {MAX_SAMPLE_RATE_HZ:g} Hz", fs)
    n_ch = r.get(adc, "adc", "channels", "integer")
    if n_ch < 1:
        raise r.fail("adc.channels", "a positive integer", n_ch)
    if n_ch > MAX_ADC_CHANNELS:
        raise r.fail("adc.channels", f"at most {MAX_ADC_CHANNELS}", n_ch)
    if fs * n_ch > MAX_SAMPLE_VALUES_PER_S:
        raise r.fail("adc.sample_rate", f"at most {MAX_SAMPLE_VALUES_PER_S:g} samples per "
                     f"second over all channels (adc.channels = {n_ch})", fs)
    gains = {}
    for g in ("sensor_gain", "reference_gain"):
        v = r.get(adc, "adc", g, "number", 1.0)
        if v == 0 or not math.isfinite(v):
            raise r.fail(f"adc.{g}", "a finite non-zero number", v)
        gains[g] = v

    src = r.get(doc, "", "source", "table")
    _unknown_keys(r, src, "source", ("frequencies", "reference_channels"))
    freqs = r.get(src, "source", "frequencies", "list of numbers")
    if len(freqs) > MAX_CARRIERS:
        raise r.fail("source.frequencies", f"at most {MAX_CARRIERS} carriers",
                     f"{len(freqs)} carriers")
    for f in freqs:
        if not 0 < f < fs / 2:
            raise r.fail("source.frequencies", f"carriers in (0, {fs / 2:g}) Hz (below the "
                         f"Nyquist frequency of adc.sample_rate = {fs:g} Hz)", f)
    if len(set(freqs)) != len(freqs):
        raise r.fail("source.frequencies", "distinct carriers", freqs)
    refs = r.get(src, "source", "reference_channels", "list of integers")
    if len(refs) != len(freqs):
        raise r.fail("source.reference_channels", f"one channel per carrier ({len(freqs)})",
                     f"{len(refs)} channels")

    used: dict = {}

    def claim(ch, key, owner):
        if not 0 <= ch < n_ch:
            raise r.fail(key, f"channels in 0..{n_ch - 1} (adc.channels = {n_ch})", ch)
        if ch in used:
            raise r.fail(key, "each ADC channel used once", f"channel {ch} already used by "
                         f"{used[ch]}")
        used[ch] = owner

    for ch in refs:
        claim(ch, "source.reference_channels", "source.reference_channels")

    dem = r.get(doc, "", "demodulation", "table", {})
    _unknown_keys(r, dem, "demodulation", ("output_rate", "window", "distortion_threshold"))
    rate = r.get(dem, "demodulation", "output_rate", "number", OUTPUT_RATE_HZ)
    if not 0 < rate <= fs:
        raise r.fail("demodulation.output_rate", f"a rate in (0, {fs:g}] Hz", rate)
    window = r.get(dem, "demodulation", "window", "string", "hann")
    if window not in ("hann", "rect"):
        raise r.fail("demodulation.window", "'hann' or 'rect'", repr(window))
    thr = r.get(dem, "demodulation", "distortion_threshold", "number", 1e-3)
    if not thr > 0:
        raise r.fail("demodulation.distortion_threshold", "a positive number", thr)

    sensors = []
    tables = r.get(doc, "", "sensors", "list of tables")
    if len(tables) > MAX_SENSORS:
        raise r.fail("sensors", f"at most {MAX_SENSORS} sensors", f"{len(tables)} sensors")
    for i, t in enumerate(tables):
        pre = f"sensors[{i}]"
        _unknown_keys(r, t, pre, ("name", "channels", "calibration", "device_name",
                                  "hemisphere", "simulation_offset", "tip"))
        name = r.get(t, pre, "name", "string")
        if not name or any(s.name == name for s in sensors):
            raise r.fail(f"{pre}.name", "a unique non-empty sensor name", repr(name))
        chans = r.get(t, pre, "channels", "list of integers")
        for ch in chans:
            claim(ch, f"{pre}.channels", f"sensor {name!r}")
        device = r.get(t, pre, "device_name", "string", name)
        if not 1 <= len(device) <= 20 or not device.isascii():
            raise r.fail(f"{pre}.device_name" if "device_name" in t else f"{pre}.name",
                         "an ASCII OpenIGTLink device name of 1-20 characters", repr(device))
        if any(s.device_name == device for s in sensors):
            raise r.fail(f"{pre}.device_name", "a device name no other sensor uses",
                         repr(device))
        cal = r.get(t, pre, "calibration", "string", None)
        cal_path = None
        if cal is not None:
            cal_path = Path(cal)
            if not cal_path.is_absolute():
                cal_path = base / cal_path
            if not cal_path.is_file():
                raise r.fail(f"{pre}.calibration", "an existing calibration file (relative to "
                             "the tracker file)", f"missing {str(cal_path)!r}")
        hemi = r.get(t, pre, "hemisphere", "string", "+x")
        if hemi not in ("+x", "-x", "+y", "-y", "+z", "-z"):
            raise r.fail(f"{pre}.hemisphere", "one of +x, -x, +y, -y, +z, -z", repr(hemi))
        off = r.get(t, pre, "simulation_offset", "list of numbers", [0.0, 0.0, 0.0])
        if len(off) != 3:
            raise r.fail(f"{pre}.simulation_offset", "3 numbers (m)", f"{len(off)} numbers")
        tip = r.get(t, pre, "tip", "string", None)
        if tip is not None:
            from ..navigate import read_tip_transform

            tip_path = Path(tip) if Path(tip).is_absolute() else base / tip
            if not tip_path.is_file():
                raise r.fail(f"{pre}.tip", "an existing pivot calibration file from 'openemt "
                             "pivot' (relative to the tracker file)", f"missing {str(tip_path)!r}")
            tip = read_tip_transform(tip_path)
        sensors.append(SensorSpec(name=name, channels=tuple(chans), calibration=cal_path,
                                  device_name=device, hemisphere=hemi,
                                  simulation_offset=tuple(off), tip=tip))

    flt = r.get(doc, "", "filter", "table", {})
    keys = ("kind", "process_noise", "measurement_noise", "rotation_process_noise",
            "rotation_measurement_noise", "max_gap")
    _unknown_keys(r, flt, "filter", (*keys, "sensors"))

    def filter_settings(table, prefix, base):
        fkw = {}
        for k in keys:
            if k in table:
                fkw[k] = r.get(table, prefix, k, "string" if k == "kind" else "number")
        out = replace(base, **fkw)
        _check_filter(out, where, prefix)
        return out

    fspec = filter_settings(flt, "filter", FilterSpec())
    # per-sensor settings: [filter.sensors.<sensor name>] on top of [filter]
    per = r.get(flt, "filter", "sensors", "table", {})
    names = [s.name for s in sensors]
    for name, table in per.items():
        if name not in names:
            raise r.fail(f"filter.sensors.{name}", f"the name of a sensor in {names}",
                         f"unknown sensor {name!r}")
        if not isinstance(table, dict):
            raise r.fail(f"filter.sensors.{name}", "a table", _show(table))
        _unknown_keys(r, table, f"filter.sensors.{name}", keys)
        i = names.index(name)
        sensors[i] = replace(sensors[i], filter=filter_settings(
            table, f"filter.sensors.{name}", fspec))

    sim = r.get(doc, "", "simulation", "table", {})
    _unknown_keys(r, sim, "simulation", ("preset", "noise_rms", "eddy_strength", "seed",
                                         "mains_amplitudes"))
    simd = {"preset": r.get(sim, "simulation", "preset", "string", "concentric")}
    for k in ("noise_rms", "eddy_strength"):
        if k in sim:
            v = r.get(sim, "simulation", k, "number")
            if not v >= 0:
                raise r.fail(f"simulation.{k}", "a non-negative number", v)
            simd[k] = v
    simd["seed"] = r.get(sim, "simulation", "seed", "integer", 0)
    if not 0 <= simd["seed"] < 2**63:
        raise r.fail("simulation.seed", "an integer in 0..2**63-1", simd["seed"])
    if "mains_amplitudes" in sim:
        simd["mains_amplitudes"] = tuple(r.get(sim, "simulation", "mains_amplitudes",
                                               "list of numbers"))

    ig = r.get(doc, "", "igtl", "table", {})
    _unknown_keys(r, ig, "igtl", ("metadata", "reference", "stale_after", "tdata"))
    reference = r.get(ig, "igtl", "reference", "string", None)
    if reference is not None:
        if reference not in names:
            raise r.fail("igtl.reference", f"the name of a sensor in {names}",
                         f"unknown sensor {reference!r}")
        if len(names) < 2:
            raise r.fail("igtl.reference", "a sensor of a tracker with at least two sensors",
                         f"{reference!r}, the only sensor")
        devices = {s.device_name for s in sensors}
        for s in sensors:
            rel = relative_device_name(s.name)
            if s.name == reference:
                continue
            if not (len(rel) <= 20 and rel.isascii()):
                raise r.fail("igtl.reference", "sensors whose relative device names "
                             "<name>ToReference have 1-20 ASCII characters",
                             f"{rel!r} for sensor {s.name!r} (shorten its name)")
            if rel in devices:
                raise r.fail("igtl.reference", "relative device names no sensor uses",
                             f"{rel!r} already the device name of a sensor")
    stale = r.get(ig, "igtl", "stale_after", "number", DEFAULT_STALE_AFTER)
    if not (stale > 0 and stale < float("inf")):
        raise r.fail("igtl.stale_after", "a positive number of seconds", stale)
    tdata = r.get(ig, "igtl", "tdata", "boolean", False)
    metadata = r.get(ig, "igtl", "metadata", "boolean", True)

    spec = TrackerSpec(sample_rate=fs, n_channels=n_ch, frequencies=tuple(freqs),
                       reference_channels=tuple(refs), sensors=tuple(sensors),
                       sensor_gain=gains["sensor_gain"], reference_gain=gains["reference_gain"],
                       output_rate=rate, window=window, distortion_threshold=thr,
                       filter=fspec, simulation=simd, path=path, reference=reference,
                       stale_after=stale, tdata=tdata, metadata=metadata)
    try:                                       # the carrier plan must suit the demodulator
        from ..signal import frame_length

        _hop, frame = frame_length(spec.layout(), rate, window)
    except InputError as exc:
        raise InputError(f"{where}: expected carriers and demodulation.output_rate the "
                         f"demodulator accepts, got {' '.join(str(exc).split())}") from None
    if frame * n_ch > MAX_FRAME_VALUES:
        raise r.fail("demodulation.output_rate", f"a rate whose frames hold at most "
                     f"{MAX_FRAME_VALUES} values (frame length x adc.channels)",
                     f"{rate:g} Hz: frames of {frame} samples x {n_ch} channels")
    return spec


def read_tracker(path) -> TrackerSpec:
    """Read and validate a tracker description file (TOML, docs/live.md#tracker-file).

    Raises
    ------
    FileNotFoundError
        When ``path`` does not exist.
    InputError
        One line naming the file, the key, what was expected and what arrived.
    """
    from ..io._safefile import MAX_CONFIG_BYTES, check_text_nesting, read_limited

    path = Path(path)
    what = "a tracker description file (TOML)"
    data = read_limited(path, what, MAX_CONFIG_BYTES)
    try:
        text = data.decode("utf-8")
        check_text_nesting(text, "a tracker description", str(path))
        doc = tomllib.loads(text)
    except UnicodeDecodeError:
        raise InputError(f"{path}: expected a TOML text file, got binary data") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: expected valid TOML, got {exc}") from None
    return tracker_from_dict(doc, path)


def example_tracker(name: str = "simulated") -> Path:
    """Path of a tracker file shipped with openemt: ``"simulated"`` (one sensor) or
    ``"simulated-2"`` (two sensors on one source)."""
    p = Path(__file__).parent / "trackers" / f"{name}.toml"
    if not p.is_file():
        names = sorted(q.stem for q in p.parent.glob("*.toml"))
        raise InputError(f"expected a shipped tracker file name in {names}, got {name!r}")
    return p
