"""The live view in the browser: what a tracking session (or a recorded log) shows while it
runs, served on the local machine with Bokeh (docs/live.md#live-view).

:class:`LiveFeed` is the read-only observer a :class:`~openemt.live.TrackingSession` publishes
to; :class:`ViewServer` serves its panels, in a process of its own with
:class:`ViewProcess`; :func:`track_with_view` is ``openemt track --view``,
:func:`collect_with_view` ``openemt collect --view`` (the collect panel: dwell count and
coverage) and :func:`view_recording` ``openemt view`` (a session log replayed, or a raw
recording tracked again, into the view).
"""

from .._lazy import lazy_exports

#: where each public name lives; a module is imported on first use of one of its names
_SOURCES = {
    "._feed": ("LiveFeed", "carrier_levels", "collect_panel", "compute_snapshot", "coupling_snr_db",
               "spectrum_db"),
    "._process": ("ViewProcess",),
    "._server": ("ViewServer",),
    "._workflow": ("ViewOptions", "ViewRecordingOptions", "ViewResult", "collect_with_view",
                   "replay_log", "track_with_view", "view_recording"),
}
__all__, __getattr__, __dir__ = lazy_exports(__name__, _SOURCES)
