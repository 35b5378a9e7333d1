"""``openemt track``: live tracking from a simulated device, a raw recording or a sound card to
OpenIGTLink, for the sensors of a tracker description file (the workflow is
:class:`openemt.live.TrackingSession`; this module parses, calls and prints)."""

from __future__ import annotations

import sys

__all__ = ["register", "run"]


def register(subparsers) -> None:
    from ..live import TrackOptions
    from ..view import ViewOptions
    from ._common import add_command

    add_command(
        subparsers, "track", run, (TrackOptions, ViewOptions),
        description="Demodulate raw samples (simulated device, an HDF5 recording, a sound "
                    "card, or an ADC streaming openemt frames over a serial port or TCP), solve every sensor's pose with a warm-started LM solver, optionally "
                    "filter it and map it into an image through a registration, and serve each "
                    "sensor (and tool tip) as an OpenIGTLink TRANSFORM device in millimetres "
                    "for 3D Slicer (OpenIGTLinkIF, client connector to the host and port "
                    "below; several clients at once). It says at start-up what it streams: "
                    "devices <Sensor>ToTracker, <Sensor>TipToTracker, <Sensor>To<Reference>, "
                    "<Sensor>ToImage with a registration (docs/live.md#what-track-streams). "
                    "Stops at --duration, at the end of a recording, or on Ctrl-C.")


def run(args) -> int:
    # on a terminal, a first line before the heavy imports (a second or two; elsewhere bad
    # input stays one `error:` line)
    if not args.quiet and sys.stderr.isatty():
        print(f"openemt track: starting (--source {args.source or 'default'}; loading the "
              f"solver and the source)", file=sys.stderr, flush=True)
    from ..live import TrackingSession, TrackOptions
    from ..view import ViewOptions, track_with_view
    from ._common import emit, options_from

    options = options_from(TrackOptions, args)
    view = options_from(ViewOptions, args)
    if view.view:                                 # the live view in the browser
        result = track_with_view(options, view)
    else:
        with TrackingSession.from_tracker(options.tracker, options) as session:
            result = session.run()
    emit(args, result.to_dict(), result.human())
    return result.exit_code

