"""``openemt devices``: list the audio inputs a sound-card tracker can read from (needs the
optional package sounddevice: pip install sounddevice). Use the index or name with openemt
track --source sound --device."""

from __future__ import annotations

from .._errors import InputError
from ._common import add_command, emit


def register(sub) -> None:
    add_command(sub, "devices", run)


def run(args) -> int:
    from ..live import list_audio_inputs

    try:
        devices = list_audio_inputs()
    except ImportError as exc:
        raise InputError(str(exc)) from None
    human = [f"{d['index']:>3}  {d['name']}  ({d['max_input_channels']} in, "
             f"{d['default_samplerate']:g} Hz, {d['hostapi']})" for d in devices]
    emit(args, {"devices": devices, "n_devices": len(devices)},
         human or ["no audio input devices found"])
    return 0
