"""``openemt devices``: list the audio inputs a sound-card tracker can read from."""

from __future__ import annotations

from .._errors import InputError
from . import command_help
from ._common import add_common, emit

__all__ = ["register", "run"]


def register(sub) -> None:
    p = sub.add_parser("devices", help=command_help("devices"),
                       description=__doc__.splitlines()[0] + " (needs the optional package "
                       "sounddevice: pip install sounddevice). Use the index or name with "
                       "openemt track --source sound --device.")
    add_common(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..live._backends import list_audio_inputs

    try:
        devices = list_audio_inputs()
    except ImportError as exc:
        raise InputError(str(exc)) from None
    human = [f"{d['index']:>3}  {d['name']}  ({d['max_input_channels']} in, "
             f"{d['default_samplerate']:g} Hz, {d['hostapi']})" for d in devices]
    if not devices:
        human = ["no audio input devices found"]
    emit(args, {"devices": devices, "n_devices": len(devices)}, human)
    return 0
