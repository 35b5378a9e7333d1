"""Live tracking: tracker description files, acquisition backends, the real-time pipeline (one
or several sensors, optional tracking filter) and OpenIGTLink output."""

from .._lazy import lazy_exports

#: where each public name lives; a module is imported on first use of one of its names
_SOURCES = {
    "._acquire": ("SerialBackend", "TcpBackend"),
    "._backends": ("Backend", "ReplayBackend", "SimulatedBackend", "SoundDeviceBackend",
                   "SourceStalled", "StallWatch", "default_model", "default_trajectory",
                   "list_audio_inputs"),
    "._devices": ("DevicesOptions", "DevicesResult", "list_devices"),
    "._filter": ("filter_restarts", "kalman_filter_poses", "new_filter_state"),
    "._igtl": ("DEFAULT_IGTL_PORT", "IgtlServer"),
    "._igtl_meta": ("distortion_level",),
    "._igtl_wire": ("frame_messages", "pack_transforms", "transform_bodies"),
    "._pipeline": ("PipelineConfig", "SensorSetup", "TrackingPipeline", "TrackLog", "TrackStep",
                   "TrackSummary", "lm_solver"),
    "._record": ("RawRecorder", "TrackLogData", "TrackLogWriter", "read_track_log",
                 "track_log_dataset"),
    "._session": ("StopSignals", "TrackingSession", "TrackOptions", "TrackResult",
                  "tracker_backend", "tracker_sensors"),
    "._tdata": ("pack_tdata",),
    "._tracker_file": ("FilterSpec", "SensorSpec", "StreamSpec", "TrackerSpec", "example_tracker",
                       "read_registration_transform", "read_tracker", "tracker_from_dict"),
}
__all__, __getattr__, __dir__ = lazy_exports(__name__, _SOURCES)
