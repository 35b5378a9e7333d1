"""The live view in the browser: what a tracking session (or a recorded log) shows while it
runs, served on the local machine with Bokeh (docs/live.md#live-view).

:class:`LiveFeed` is the read-only observer a :class:`~openemt.live.TrackingSession` publishes
to; :class:`ViewServer` serves its panels, in a process of its own with
:class:`ViewProcess`; :func:`track_with_view` is ``openemt track --view``,
:func:`collect_with_view` ``openemt collect --view`` (the collect panel: dwell count and
coverage) and :func:`view_recording` ``openemt view`` (a session log replayed, or a raw
recording tracked again, into the view).
"""

from ._feed import LiveFeed, carrier_levels, collect_panel, coupling_snr_db, spectrum_db
from ._process import ViewProcess
from ._server import ViewServer
from ._workflow import (
    ViewOptions,
    ViewRecordingOptions,
    ViewResult,
    collect_with_view,
    replay_log,
    track_with_view,
    view_recording,
)

__all__ = ["LiveFeed", "ViewOptions", "ViewRecordingOptions", "ViewProcess", "ViewResult", "ViewServer",
           "carrier_levels", "collect_panel", "collect_with_view", "coupling_snr_db",
           "replay_log", "spectrum_db", "track_with_view", "view_recording"]
