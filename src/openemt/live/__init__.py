"""Live tracking: tracker description files, acquisition backends, the real-time pipeline (one
or several sensors, optional tracking filter) and OpenIGTLink output."""

from ._acquire import SerialBackend, TcpBackend
from ._backends import (
    Backend,
    ReplayBackend,
    SimulatedBackend,
    SoundDeviceBackend,
    SourceStalled,
    StallWatch,
    default_model,
    default_trajectory,
    list_audio_inputs,
)
from ._devices import DevicesOptions, DevicesResult, list_devices
from ._filter import filter_restarts, kalman_filter_poses, new_filter_state
from ._igtl import DEFAULT_IGTL_PORT, IgtlServer
from ._igtl_meta import distortion_level
from ._igtl_wire import frame_messages, pack_transforms, transform_bodies
from ._pipeline import (
    PipelineConfig,
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
from ._session import (
    TrackingSession,
    TrackOptions,
    TrackResult,
    tracker_backend,
    tracker_sensors,
)
from ._tdata import pack_tdata
from ._tracker_file import (
    FilterSpec,
    SensorSpec,
    StreamSpec,
    TrackerSpec,
    example_tracker,
    read_registration_transform,
    read_tracker,
    tracker_from_dict,
)

__all__ = [
    "frame_messages",
    "pack_tdata",
    "pack_transforms",
    "transform_bodies",
    "DEFAULT_IGTL_PORT",
    "Backend",
    "DevicesOptions",
    "DevicesResult",
    "FilterSpec",
    "IgtlServer",
    "PipelineConfig",
    "RawRecorder",
    "ReplayBackend",
    "SensorSetup",
    "SensorSpec",
    "SerialBackend",
    "SimulatedBackend",
    "SoundDeviceBackend",
    "SourceStalled",
    "StallWatch",
    "StreamSpec",
    "TrackLog",
    "TrackLogData",
    "TrackLogWriter",
    "TrackOptions",
    "TrackResult",
    "TrackStep",
    "TrackSummary",
    "TcpBackend",
    "TrackerSpec",
    "TrackingPipeline",
    "TrackingSession",
    "default_model",
    "default_trajectory",
    "distortion_level",
    "example_tracker",
    "filter_restarts",
    "kalman_filter_poses",
    "list_audio_inputs",
    "list_devices",
    "lm_solver",
    "new_filter_state",
    "read_registration_transform",
    "read_track_log",
    "read_tracker",
    "track_log_dataset",
    "tracker_backend",
    "tracker_from_dict",
    "tracker_sensors",
]
