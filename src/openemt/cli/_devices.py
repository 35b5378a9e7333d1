"""``openemt devices``: list what a live session can read from: sound cards (with the optional
package sounddevice), serial ports (pyserial; each opened once to say whether it can be used,
and why not) and the tracker file's network or serial source (the workflow is
:func:`openemt.live.list_devices`; this module parses, calls and prints)."""

from __future__ import annotations

from ._common import add_command, emit


def register(sub) -> None:
    from ..live import DevicesOptions

    add_command(sub, "devices", run, options=DevicesOptions)


def run(args) -> int:
    from ..live import DevicesOptions, list_devices
    from ._common import options_from

    result = list_devices(options_from(DevicesOptions, args))
    emit(args, result.to_dict(), result.human())
    return 0
