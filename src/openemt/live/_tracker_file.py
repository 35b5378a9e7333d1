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
from dataclasses import dataclass, field, replace
from pathlib import Path

from .._constants import OUTPUT_RATE_HZ
from .._errors import InputError
from .._result import Result

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
    "StreamSpec",
    "device_from",
    "example_tracker",
    "read_registration_transform",
    "read_tracker",
    "relative_device_name",
    "sensor_device_name",
    "state_device_name",
    "status_device_name",
    "tip_device_name",
    "tracker_from_dict",
]

#: The ``format`` value of a tracker description file.
TRACKER_FORMAT = "openemt-tracker"
_VERSION = 1
_MISSING = object()
_FILTER_KINDS = ("none", "kalman")
#: Default of ``[igtl] stale_after``: seconds without a valid pose before a sensor is stale.
DEFAULT_STALE_AFTER = 0.5


#: The most characters of an OpenIGTLink device name (the header's 20-byte field).
MAX_DEVICE_NAME = 20


def _split_from_to(device: str):
    """``("Probe", "Tracker")`` of ``"ProbeToTracker"`` (the last ``To`` between two names),
    else None."""
    k = device.rfind("To")
    if 0 < k < len(device) - 2:
        return device[:k], device[k + 2:]
    return None


def sensor_device_name(sensor_name: str, frame: str = "Tracker") -> str:
    """The default OpenIGTLink device name of a sensor: ``<sensor name>To<frame>``
    (``ProbeToTracker``; ``ProbeToImage`` with a registration), the ``FromTo`` form PLUS and
    3D Slicer read as a transform from the sensor to the frame."""
    return f"{sensor_name}To{frame}"


def device_from(device: str) -> str:
    """The ``From`` part of a ``FromTo`` device name (``Probe`` of ``ProbeToTracker``), else
    the whole name."""
    parts = _split_from_to(device)
    return device if parts is None else parts[0]


def tip_device_name(device: str) -> str:
    """The device of a tool's tip: ``<Tool>TipTo<frame>`` for a ``FromTo`` tool device
    (``ProbeTipToTracker``), else ``<device>Tip``."""
    parts = _split_from_to(device)
    return f"{device}Tip" if parts is None else f"{parts[0]}TipTo{parts[1]}"


def relative_device_name(sensor_name: str, reference: str = "Reference") -> str:
    """The OpenIGTLink device name of a sensor streamed relative to the reference sensor:
    ``<sensor name>To<reference sensor name>``."""
    return f"{sensor_name}To{reference}"


def state_device_name(device: str) -> str:
    """The device of a stream's state STRING messages: ``<From>State`` of a ``FromTo`` device
    (``ProbeState`` for ``ProbeToTracker``), else ``<device>State``; whole names, never cut
    (a name too long for 20 bytes is refused where the streams are set up)."""
    return device_from(device) + "State"


def status_device_name(device: str) -> str:
    """The device of a stream's periodic status STRING: ``<From>Status`` (``ProbeStatus``)."""
    return device_from(device) + "Status"


def check_device_names(names, what: str = "OpenIGTLink device names") -> None:
    """Refuse names that do not fit the protocol (1-20 ASCII characters) or collide."""
    seen: set = set()
    for dev in names:
        if not (isinstance(dev, str) and 1 <= len(dev) <= MAX_DEVICE_NAME and dev.isascii()):
            raise InputError(f"expected {what} of 1-{MAX_DEVICE_NAME} ASCII characters, got "
                             f"{dev!r} (shorten the sensor name or set its device_name)")
        if dev in seen:
            raise InputError(f"expected distinct {what}, got {dev!r} twice")
        seen.add(dev)


@dataclass(frozen=True)
class StreamSpec(Result):
    """One OpenIGTLink device a tracking session streams.

    Attributes
    ----------
    device : str
        Device name (the Slicer transform node).
    sensor : str
        The sensor it comes from.
    kind : str
        ``"tool"`` (the sensor's pose), ``"tip"`` (the tool tip, ``pose @ tip``),
        ``"relative"`` or ``"tip-relative"`` (the same relative to the reference sensor).
    frame : str
        The frame the pose is given in: ``"Tracker"`` (the source), ``"Image"`` (through the
        registration) or the reference sensor's name.
    units : str
        Translation units on the wire (``"mm"``; rotations are unit-free matrices).
    state_device, status_device : str
        Devices of its state changes and periodic status STRINGs (tool streams only).
    """

    device: str
    sensor: str
    kind: str
    frame: str
    units: str = "mm"
    state_device: str | None = None
    status_device: str | None = None


def stream_specs(sensors, reference: str | None = None, frame: str = "Tracker") -> list:
    """The streams of ``sensors`` (objects with ``name``, ``device_name`` and ``tip``), in the
    order a pipeline sends them: every sensor's tool, the tips, then (with a ``reference``)
    every other sensor's tool and tip relative to it. Names are checked
    (:func:`check_device_names`)."""
    out = []
    for s in sensors:
        out.append(StreamSpec(s.device_name, s.name, "tool", frame,
                              state_device=state_device_name(s.device_name),
                              status_device=status_device_name(s.device_name)))
    for s in sensors:
        if s.tip is not None:
            out.append(StreamSpec(tip_device_name(s.device_name), s.name, "tip", frame))
    if reference is not None:
        for s in sensors:
            if s.name == reference:
                continue
            out.append(StreamSpec(relative_device_name(s.name, reference), s.name, "relative",
                                  reference))
            if s.tip is not None:
                out.append(StreamSpec(relative_device_name(s.name + "Tip", reference), s.name,
                                      "tip-relative", reference))
    check_device_names([d for st in out for d in (st.device, st.state_device,
                                                  st.status_device) if d is not None])
    return out


def read_registration_transform(path):
    """The image-from-tracker transform (4x4, m) of a registration written by
    ``openemt register -o`` (or its ITK transform; :func:`openemt.navigate.read_registration`),
    checked to be rigid: a similarity registration (``--scale``) would scale the tool."""
    import numpy as np

    from ..navigate import read_registration

    T, _ = read_registration(path)
    R = T[:3, :3]
    if not (np.allclose(R.T @ R, np.eye(3), atol=1e-6) and np.linalg.det(R) > 0):
        raise InputError(f"expected a rigid 4x4 registration (rotation and translation in m) in "
                         f"{path}, got a transform with scale {np.cbrt(np.linalg.det(R)):.6g}")
    return T


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
        Sensor name (log, summary; the ``From`` of its default device name).
    channels : tuple of int
        ADC channel of each sensor coil (X, Y, Z order of the calibration's model).
    calibration : Path or None
        Calibration file (JSON or ILEMT .mat), absolute; None = the simulated preset's model.
    device_name : str
        OpenIGTLink device name (Slicer transform node name): the file's ``device_name``,
        else ``<name>ToTracker`` (``<name>ToImage`` with a registration).
    device_given : bool
        Whether ``device_name`` was given (a registration then leaves it as it is).
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
    device_given: bool = False


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
    header_version: object = None
    rate: float | None = None
    registration: object = None
    registration_path: Path | None = None
    witnesses: tuple = ()
    bands: tuple = ()
    #: ``[solve] bands`` and ``band_time_constant`` (:class:`openemt.solve.BandStage`)
    solve_bands: str = "auto"
    band_time_constant: float = 0.1
    #: where the ADC's frames come from (``[adc] source``: ``serial:PORT[@BAUD]`` or
    #: ``tcp://HOST:PORT``, docs/live.md#serial-and-network-acquisition), the default of
    #: ``track --source``; None: none configured
    adc_source: str | None = None

    @property
    def sensor_names(self) -> tuple:
        return tuple(s.name for s in self.sensors)

    @property
    def frame(self) -> str:
        """The frame the sensors stream in: ``"Image"`` with a registration, else
        ``"Tracker"``."""
        return "Tracker" if self.registration is None else "Image"

    def streams(self) -> list:
        """The :class:`StreamSpec` of every device the tracker streams (tools, tips,
        reference-relative), in the order the pipeline sends them."""
        return stream_specs(self.sensors, self.reference, self.frame)

    def with_tip(self, path) -> TrackerSpec:
        """A copy whose one sensor carries the tool tip of the pivot calibration file ``path``
        (``openemt pivot -o``); a tracker of several sensors names each tip in its file."""
        from ..navigate import read_tip_transform

        if len(self.sensors) != 1:
            raise InputError(f"expected a one-sensor tracker for --tip (name each tool's tip "
                             f"in the tracker file, [sensors.NAME] tip), got "
                             f"{len(self.sensors)} sensors")
        return replace(self, sensors=(replace(self.sensors[0], tip=read_tip_transform(path)),))

    def with_registration(self, path) -> TrackerSpec:
        """A copy that streams in the image frame of the registration file ``path``
        (``openemt register -o``): its image-from-tracker transform is applied to every
        sensor's pose; default device names become ``<name>ToImage``, and so does a given
        ``<X>ToTracker`` (``<X>ToImage``: the name would state the wrong frame); other given
        names stay."""
        T = read_registration_transform(path)

        def in_image(s):
            if not s.device_given:
                return sensor_device_name(s.name, "Image")
            parts = _split_from_to(s.device_name)
            if parts is not None and parts[1] == "Tracker":
                return sensor_device_name(parts[0], "Image")
            return s.device_name

        sensors = tuple(replace(s, device_name=in_image(s)) for s in self.sensors)
        out = replace(self, registration=T, registration_path=Path(path), sensors=sensors)
        out.streams()                              # the new names fit
        return out

    def layout(self):
        """The :class:`~openemt.signal.ChannelLayout` of the whole ADC: the sensor channels of
        every sensor in order (sensor 0's coils first), then the references."""
        from ..signal import ChannelLayout

        chans = tuple(c for s in self.sensors for c in s.channels)
        return ChannelLayout(frequencies=self.frequencies, sample_rate=self.sample_rate,
                             sensor_channels=chans, reference_channels=self.reference_channels,
                             sensor_gain=self.sensor_gain, reference_gain=self.reference_gain,
                             bands=self.bands)

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
        if kind.startswith("list of "):
            item = kind[len("list of "):]
            if not isinstance(v, list) or not v:
                raise self.fail(full, f"a non-empty list of {item}", _show(v))
            if len(v) > MAX_LIST_ITEMS:
                raise self.fail(full, f"a list of at most {MAX_LIST_ITEMS} {item}",
                                f"{len(v)} items")
            return [self._typed(x, _ITEMS[item], full, f"a list of {item}", f"an item {_show(x)}")
                    for x in v]
        return self._typed(v, kind, full, _KINDS[kind][1], _show(v))

    def _typed(self, v, kind: str, full: str, expected: str, got: str):
        """``v`` as ``kind`` (a key of :data:`_KINDS`), else the error naming ``full``."""
        types, _ = _KINDS[kind]
        if not isinstance(v, types) or (isinstance(v, bool) and kind != "boolean"):
            raise self.fail(full, expected, got)
        return float(v) if kind == "number" else v

    def file(self, value: str, base: Path, key: str, what: str) -> Path:
        """``value`` as a path, relative to ``base`` (the tracker file's folder) unless
        absolute, refused unless it names an existing file (``what``: which file)."""
        path = Path(value)
        path = path if path.is_absolute() else base / path
        if not path.is_file():
            raise self.fail(key, f"{what} (relative to the tracker file)",
                            f"missing {str(path)!r}")
        return path


#: The value kinds of a tracker file: kind -> (Python types, what it should be); a bool is
#: no number (TOML's true is no 1); ``list of <items>`` reads a non-empty list of them.
_KINDS = {"number": ((int, float), "a number"), "integer": (int, "an integer"),
          "string": (str, "a string"), "boolean": (bool, "true or false"),
          "table": (dict, "a table")}
_ITEMS = {"numbers": "number", "integers": "integer", "tables": "table"}


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
    for key, (lo, hi, unit) in FILTER_LIMITS.items():
        v = float(getattr(f, key))
        if not lo <= v <= hi:
            raise InputError(f"{where}: expected `{prefix}.{key}` in [{lo:g}, {hi:g}] {unit}, "
                             f"got {v!r}")


#: The range of each filter setting (beyond them the filter's covariances under- or overflow
#: and no physical tracker needs them): key -> (lowest, highest, unit).
FILTER_LIMITS = {
    "process_noise": (1e-9, 1e4, "m/s^2/sqrt(Hz)"),
    "measurement_noise": (1e-12, 1.0, "m"),
    "rotation_process_noise": (1e-9, 1e5, "rad/s^2/sqrt(Hz)"),
    "rotation_measurement_noise": (1e-12, 3.2, "rad"),
    "max_gap": (1e-6, 3600.0, "s"),
}
#: The highest OpenIGTLink stream rate per client (``[igtl] rate``, ``--rate``), Hz.
MAX_IGTL_RATE_HZ = 1e5


def check_header_version(v, where: str):
    """``"auto"``, 1 or 2 (``[igtl] header_version``, ``--header-version``)."""
    if isinstance(v, str) and v.isdigit():
        v = int(v)
    if v not in ("auto", 1, 2) or isinstance(v, bool):
        raise InputError(f"{where}: expected the OpenIGTLink header version 'auto', 1 or 2, "
                         f"got {v!r}")
    return v


def check_rate(v, where: str) -> float:
    """A stream rate in (0, MAX_IGTL_RATE_HZ] Hz."""
    v = float(v)
    if not 0 < v <= MAX_IGTL_RATE_HZ:
        raise InputError(f"{where}: expected a stream rate in (0, {MAX_IGTL_RATE_HZ:g}] Hz, "
                         f"got {v!r}")
    return v


def tracker_from_dict(doc: dict, path=None) -> TrackerSpec:
    """Validate a parsed tracker description (see :func:`read_tracker`)."""
    path = None if path is None else Path(path)
    where = str(path) if path is not None else "tracker"
    base = path.parent if path is not None else Path(".")
    r = _Reader(where)
    _unknown_keys(r, doc, "", ("format", "version", "adc", "source", "demodulation", "sensors",
                               "filter", "simulation", "igtl", "navigation", "witness",
                               "solve"))
    fmt = r.get(doc, "", "format", "string")
    if fmt != TRACKER_FORMAT:
        raise r.fail("format", repr(TRACKER_FORMAT), repr(fmt))
    version = r.get(doc, "", "version", "integer")
    if not 1 <= version <= _VERSION:
        raise r.fail("version", f"1..{_VERSION}", version)

    adc = r.get(doc, "", "adc", "table")
    _unknown_keys(r, adc, "adc", ("sample_rate", "channels", "sensor_gain", "reference_gain",
                                  "source"))
    adc_source = r.get(adc, "adc", "source", "string", None)
    if adc_source is not None:
        from ._acquire import parse_source

        try:
            kind, _ = parse_source(adc_source)
        except InputError:
            kind = None
        if kind not in ("serial", "tcp"):
            raise r.fail("adc.source", "'serial:PORT[@BAUD]' or 'tcp://HOST:PORT'",
                         repr(adc_source))
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
    freqs, bands = _carriers(r, src)
    every = freqs + [f for b in bands for f in b]
    if len(every) > MAX_CARRIERS:
        raise r.fail("source.frequencies", f"at most {MAX_CARRIERS} carriers",
                     f"{len(every)} carriers")
    for f in every:
        if not 0 < f < fs / 2:
            raise r.fail("source.frequencies", f"carriers in (0, {fs / 2:g}) Hz (below the "
                         f"Nyquist frequency of adc.sample_rate = {fs:g} Hz)", f)
    if len(set(every)) != len(every):
        raise r.fail("source.frequencies", "distinct carriers", every)
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
    if not 0 < thr < math.inf:
        raise r.fail("demodulation.distortion_threshold", "a positive finite number", thr)

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
        device = r.get(t, pre, "device_name", "string", sensor_device_name(name))
        if not 1 <= len(device) <= 20 or not device.isascii():
            raise r.fail(f"{pre}.device_name" if "device_name" in t else f"{pre}.name",
                         "an ASCII OpenIGTLink device name of 1-20 characters (a name "
                         "without device_name streams as <name>ToTracker)", repr(device))
        if any(s.device_name == device for s in sensors):
            raise r.fail(f"{pre}.device_name", "a device name no other sensor uses",
                         repr(device))
        cal = r.get(t, pre, "calibration", "string", None)
        cal_path = None if cal is None else r.file(cal, base, f"{pre}.calibration",
                                                   "an existing calibration file")
        hemi = r.get(t, pre, "hemisphere", "string", "+x")
        if hemi not in ("+x", "-x", "+y", "-y", "+z", "-z"):
            raise r.fail(f"{pre}.hemisphere", "one of +x, -x, +y, -y, +z, -z", repr(hemi))
        off = r.get(t, pre, "simulation_offset", "list of numbers", [0.0, 0.0, 0.0])
        if len(off) != 3 or not all(abs(v) <= 10.0 for v in off):
            raise r.fail(f"{pre}.simulation_offset", "3 finite numbers (m) within 10 m",
                         f"{off}")
        tip = r.get(t, pre, "tip", "string", None)
        if tip is not None:
            from ..navigate import read_tip_transform

            tip = read_tip_transform(r.file(tip, base, f"{pre}.tip", "an existing pivot "
                                            "calibration file from 'openemt pivot'"))
        sensors.append(SensorSpec(name=name, channels=tuple(chans), calibration=cal_path,
                                  device_name=device, hemisphere=hemi,
                                  simulation_offset=tuple(off), tip=tip,
                                  device_given="device_name" in t))

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
                                         "mains_amplitudes", "metal"))
    simd = {"preset": r.get(sim, "simulation", "preset", "string", "concentric")}
    for k in ("noise_rms", "eddy_strength"):
        if k in sim:
            v = r.get(sim, "simulation", k, "number")
            if not 0 <= v < math.inf:
                raise r.fail(f"simulation.{k}", "a finite non-negative number", v)
            simd[k] = v
    simd["seed"] = r.get(sim, "simulation", "seed", "integer", 0)
    if not 0 <= simd["seed"] < 2**63:
        raise r.fail("simulation.seed", "an integer in 0..2**63-1", simd["seed"])
    if "mains_amplitudes" in sim:
        simd["mains_amplitudes"] = tuple(r.get(sim, "simulation", "mains_amplitudes",
                                               "list of numbers"))
        if not all(math.isfinite(v) for v in simd["mains_amplitudes"]):
            raise r.fail("simulation.mains_amplitudes", "finite numbers (V)",
                         list(simd["mains_amplitudes"]))

    if "metal" in sim:
        simd["metal"] = _metal_scene(r, sim["metal"], base)

    ig = r.get(doc, "", "igtl", "table", {})
    _unknown_keys(r, ig, "igtl", ("metadata", "reference", "stale_after", "tdata",
                                  "header_version", "rate"))
    reference = r.get(ig, "igtl", "reference", "string", None)
    if reference is not None:
        if reference not in names:
            raise r.fail("igtl.reference", f"the name of a sensor in {names}",
                         f"unknown sensor {reference!r}")
        if len(names) < 2:
            raise r.fail("igtl.reference", "a sensor of a tracker with at least two sensors",
                         f"{reference!r}, the only sensor")
    stale = r.get(ig, "igtl", "stale_after", "number", DEFAULT_STALE_AFTER)
    if not (stale > 0 and stale < float("inf")):
        raise r.fail("igtl.stale_after", "a positive number of seconds", stale)
    tdata = r.get(ig, "igtl", "tdata", "boolean", False)
    metadata = r.get(ig, "igtl", "metadata", "boolean", True)
    header_version = None
    if "header_version" in ig:
        header_version = check_header_version(ig["header_version"],
                                              f"{where}: `igtl.header_version`")
    igtl_rate = None
    if "rate" in ig:
        igtl_rate = check_rate(r.get(ig, "igtl", "rate", "number"), f"{where}: `igtl.rate`")
    solve_bands, band_tc = _solve_section(r, doc, bands)
    witnesses = []
    for i, t in enumerate(r.get(doc, "", "witness", "list of tables", [])):
        pre = f"witness[{i}]"
        _unknown_keys(r, t, pre, ("sensor", "pose"))
        wname = r.get(t, pre, "sensor", "string")
        if wname not in names or any(w[0] == wname for w in witnesses):
            raise r.fail(f"{pre}.sensor", f"the name of a sensor in {names}, each witness "
                         f"once", repr(wname))
        pose = r.get(t, pre, "pose", "list of numbers")
        if len(pose) != 6 or not all(math.isfinite(v) for v in pose) \
                or max(abs(v) for v in pose[:3]) > 10.0:
            raise r.fail(f"{pre}.pose", "[x, y, z, rx, ry, rz]: 6 finite numbers (m, rad; "
                         "within 10 m)", pose)
        witnesses.append((wname, tuple(float(v) for v in pose)))

    nav = r.get(doc, "", "navigation", "table", {})
    _unknown_keys(r, nav, "navigation", ("registration",))
    registration = r.get(nav, "navigation", "registration", "string", None)
    if registration is not None:
        registration = r.file(registration, base, "navigation.registration", "an existing "
                              "registration file from 'openemt register -o'")

    spec = TrackerSpec(sample_rate=fs, n_channels=n_ch, frequencies=tuple(freqs),
                       reference_channels=tuple(refs), sensors=tuple(sensors),
                       sensor_gain=gains["sensor_gain"], reference_gain=gains["reference_gain"],
                       output_rate=rate, window=window, distortion_threshold=thr,
                       filter=fspec, simulation=simd, path=path, reference=reference,
                       stale_after=stale, tdata=tdata, metadata=metadata,
                       header_version=header_version, rate=igtl_rate,
                       bands=tuple(tuple(b) for b in bands), witnesses=tuple(witnesses),
                       solve_bands=solve_bands, band_time_constant=band_tc,
                       adc_source=adc_source)
    try:
        if registration is not None:
            spec = spec.with_registration(registration)
        spec.streams()
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None
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


def _carriers(r, src) -> tuple[list, list]:
    """``source.frequencies``: one carrier per coil (``[7500, 10500, 13500]``), or per coil
    the carriers of its bands (``[[7500, 274], [10500, 334], [13500, 370]]``: band 0 is the
    first of each); returns band 0 and the further bands (each one frequency per coil)."""
    raw = src.get("frequencies")
    if not (isinstance(raw, list) and raw and all(isinstance(x, list) for x in raw)):
        return r.get(src, "source", "frequencies", "list of numbers"), []
    per_coil = [r.get({"frequencies": x}, "source", "frequencies", "list of numbers")
                for x in raw]
    n = len(per_coil[0])
    if any(len(c) != n for c in per_coil):
        raise r.fail("source.frequencies", "the same number of carrier bands for every coil",
                     [len(c) for c in per_coil])
    return [c[0] for c in per_coil], [[c[b] for c in per_coil] for b in range(1, n)]


def _solve_section(r, doc, bands) -> tuple[str, float]:
    """``[solve]``: ``bands`` (the couplings each sensor solves from the carrier bands,
    :data:`openemt.solve.LIVE_BAND_METHODS`) and ``band_time_constant`` (s, the fusion's
    low-pass)."""
    from ..solve import DEFAULT_BAND_TIME_CONSTANT_S, LIVE_BAND_METHODS

    sol = r.get(doc, "", "solve", "table", {})
    _unknown_keys(r, sol, "solve", ("bands", "band_time_constant"))
    method = r.get(sol, "solve", "bands", "string", "auto")
    if method not in LIVE_BAND_METHODS:
        raise r.fail("solve.bands", " or ".join(repr(m) for m in LIVE_BAND_METHODS),
                     repr(method))
    if not bands and method not in ("auto", "fast"):
        raise r.fail("solve.bands", "'auto' or 'fast' for carriers of one band (several bands: "
                     "source.frequencies as [[fast, slow], ...] per coil)", repr(method))
    tc = r.get(sol, "solve", "band_time_constant", "number", DEFAULT_BAND_TIME_CONSTANT_S)
    if not 0 <= tc < 3600:
        raise r.fail("solve.band_time_constant", "a number of seconds in [0, 3600)", tc)
    return method, float(tc)


def _metal_scene(r, spec, base: Path):
    """``simulation.metal``: a scene name, a scene file (relative to the tracker file) or an
    inline table (docs/simulator.md#metal-scenes), read now so a bad one fails here."""
    from ..simulate import METAL_SCENES, load_scene

    if isinstance(spec, str) and spec not in METAL_SCENES and not Path(spec).is_absolute():
        spec = str(base / spec)
    if not isinstance(spec, (str, dict)):
        raise r.fail("simulation.metal", "a scene name, a scene file or a table", _show(spec))
    try:
        return load_scene(spec)
    except InputError as exc:
        raise r.fail("simulation.metal", "a readable metal scene", str(exc)) from None


def read_tracker(path) -> TrackerSpec:
    """Read and validate a tracker description file (TOML, docs/live.md#tracker-file).

    Raises
    ------
    FileNotFoundError
        When ``path`` does not exist.
    InputError
        One line naming the file, the key, what was expected and what arrived.
    """
    from ..io._safefile import read_toml

    path = Path(path)
    doc = read_toml(path, "a tracker description file (TOML)", "a tracker description")
    return tracker_from_dict(doc, path)


def example_tracker(name: str = "simulated") -> Path:
    """Path of a tracker file shipped with openemt: ``"simulated"`` (one sensor) or
    ``"simulated-2"`` (two sensors on one source)."""
    p = Path(__file__).parent / "trackers" / f"{name}.toml"
    if not p.is_file():
        names = sorted(q.stem for q in p.parent.glob("*.toml"))
        raise InputError(f"expected a shipped tracker file name in {names}, got {name!r}")
    return p
