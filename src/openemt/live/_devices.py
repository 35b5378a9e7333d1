"""``openemt devices``: what a live session could read from, and why a device cannot be used.

:func:`list_devices` is the workflow: the sound cards (when the optional ``sounddevice`` is
installed), the serial ports pyserial sees plus any asked for (each opened once and closed,
with a one-line reason when it does not open: missing, busy, no permission and the group to
join), and the acquisition source configured in a tracker file (``[adc] source``), with what
openemt needs from each (channels and rate of the tracker's ADC).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from .._options import option
from .._result import Result

__all__ = ["DevicesOptions", "DevicesResult", "list_devices"]


@dataclass(frozen=True)
class DevicesOptions:
    """Options of ``openemt devices`` (one field per command-line option)."""

    tracker: Path | None = option(None, "tracker description file: check its [adc] source "
                                  "(serial port or network ADC) and say what its ADC needs "
                                  "(channels, sample rate)")
    serial: tuple[str, ...] = option((), "also check these serial ports (paths pyserial does "
                                     "not list, e.g. a pseudo-terminal)", metavar="PORT")
    timeout: float = option(1.0, "seconds to wait for a network source to answer (default 1)")


@dataclass(frozen=True)
class DevicesResult(Result):
    """What was found: ``devices`` (sound inputs, as before), ``sound`` (whether sound cards
    can be listed, and why not), ``serial_ports`` and ``network`` (each with ``opens`` and a
    one-line ``reason``) and ``needs`` (the tracker's ADC)."""

    devices: list
    sound: dict
    serial_ports: list
    network: list
    needs: dict

    def _items(self) -> dict:
        d = super()._items()
        return {"devices": d.pop("devices"), "n_devices": len(self.devices), **d}

    def human(self) -> list:
        n = self.needs
        lines = [f"openemt needs: {n['channels']} ADC channels at {n['sample_rate']:g} Hz "
                 f"({n['what']})"]
        if not self.sound["available"]:
            lines.append(f"sound: {self.sound['reason']}")
        elif not self.devices:
            lines.append("sound: no audio input devices found")
        for d in self.devices:
            lines.append(f"sound {d['index']:>3}  {d['name']}  ({d['max_input_channels']} in, "
                         f"{d['default_samplerate']:g} Hz, {d['hostapi']})"
                         + ("" if d["max_input_channels"] >= n["channels"] else
                            f"  too few inputs: needs {n['channels']}"))
        if not self.serial_ports:
            lines.append("serial: no serial ports found")
        for p in self.serial_ports:
            what = ", ".join(x for x in (p.get("description"), p.get("vid_pid")) if x
                             and x != "n/a")
            lines.append(f"serial {p['port']}" + (f"  ({what})" if what else "")
                         + f": {p['reason']}")
        for s in self.network:
            lines.append(f"{s['kind']} {s['source']} (tracker file): {s['reason']}")
        return lines


def list_devices(options: DevicesOptions | None = None) -> DevicesResult:
    """The devices a session could read from (see the module docstring)."""
    from ._acquire import list_serial_ports, parse_source, probe_serial, probe_tcp
    from ._backends import list_audio_inputs
    from ._session import TrackOptions, default_tracker
    from ._tracker_file import read_tracker

    o = DevicesOptions() if options is None else options
    spec = read_tracker(o.tracker) if o.tracker is not None else default_tracker(TrackOptions())
    needs = {"channels": spec.n_channels, "sample_rate": spec.sample_rate,
             "what": (f"tracker {o.tracker}" if o.tracker is not None
                      else "the default simulated tracker; --tracker FILE for yours") +
             "; serial and network sources send the frames of docs/live.md#adc-framing"}
    try:
        devices = list_audio_inputs()
        sound = {"available": True, "reason": None}
    except ImportError as exc:
        devices, sound = [], {"available": False, "reason": str(exc)}
    ports = list_serial_ports()
    listed = {p["port"] for p in ports}
    for path in o.serial:
        if path in listed:
            continue
        ok, why = probe_serial(path)
        ports.append({"port": path, "description": None, "vid_pid": None,
                      "serial_number": None, "manufacturer": None, "opens": ok,
                      "reason": why})
    network = []
    if spec.adc_source is not None:
        kind, where = parse_source(spec.adc_source)
        ok, why = probe_tcp(*where, timeout=o.timeout) if kind == "tcp" else probe_serial(*where)
        network.append({"source": spec.adc_source, "kind": kind, "opens": ok, "reason": why})
    return DevicesResult(devices=devices, sound=sound, serial_ports=ports, network=network,
                         needs=needs)
