"""Live tracking: tracker description files, acquisition backends, the real-time pipeline (one
or several sensors, optional tracking filter) and OpenIGTLink output."""

from ._backends import (
    Backend,
    ReplayBackend,
    SimulatedBackend,
    SoundDeviceBackend,
    SourceStalled,
    StallWatch,
    default_model,
    default_trajectory,
)
from ._filter import filter_restarts, kalman_filter_poses, new_filter_state
from ._igtl import DEFAULT_IGTL_PORT, IgtlServer
from ._pipeline import (
    SensorSetup,
    TrackingPipeline,
    TrackLog,
    TrackStep,
    TrackSummary,
    lm_solver,
)
from ._record import (
    RawRecorder,
    TrackLogData,
    TrackLogWriter,
    read_track_log,
    track_log_dataset,
)
from ._session import tracker_backend, tracker_sensors
from ._tracker_file import (
    FilterSpec,
    SensorSpec,
    TrackerSpec,
    example_tracker,
    read_tracker,
    tracker_from_dict,
)

__all__ = [
    "DEFAULT_IGTL_PORT",
    "Backend",
    "FilterSpec",
    "IgtlServer",
    "RawRecorder",
    "ReplayBackend",
    "SensorSetup",
    "SensorSpec",
    "SimulatedBackend",
    "SoundDeviceBackend",
    "SourceStalled",
    "StallWatch",
    "TrackLog",
    "TrackLogData",
    "TrackLogWriter",
    "TrackStep",
    "TrackSummary",
    "TrackerSpec",
    "TrackingPipeline",
    "default_model",
    "default_trajectory",
    "example_tracker",
    "filter_restarts",
    "kalman_filter_poses",
    "lm_solver",
    "new_filter_state",
    "read_track_log",
    "track_log_dataset",
    "tracker_backend",
    "tracker_sensors",
    "read_tracker",
    "tracker_from_dict",
]
