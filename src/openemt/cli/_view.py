"""``openemt view``: the live view in the browser of a recorded session (a ``track --log``
file replayed at its pace) or of a raw recording tracked again (``--raw``), served on this
machine until Ctrl-C or ``--hold`` (the workflow is :func:`openemt.view.view_recording`; this
module parses, calls and prints). A running session has the same view: ``openemt track
--view``."""

from __future__ import annotations

__all__ = ["register", "run"]


def register(subparsers) -> None:
    from ..view import ViewRecordingOptions
    from ._common import add_command

    add_command(
        subparsers, "view", run, ViewRecordingOptions,
        description="Serve the live view (carriers, spectra, coupling matrix, sensors, "
                    "trail; docs/live.md#live-view) of a session log or a raw recording on "
                    "http://127.0.0.1:PORT/ (printed on stderr).")


def run(args) -> int:
    from ..view import ViewRecordingOptions, view_recording
    from ._common import emit, options_from

    result = view_recording(options_from(ViewRecordingOptions, args, quiet=args.quiet))
    emit(args, result.to_dict(), result.human())
    return 0
