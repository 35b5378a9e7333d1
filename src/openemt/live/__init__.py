"""Live tracking: acquisition backends, the real-time pipeline and OpenIGTLink output."""

from ._backends import (
    Backend,
    ReplayBackend,
    SimulatedBackend,
    SoundDeviceBackend,
    default_model,
    default_trajectory,
)
from ._igtl import DEFAULT_IGTL_PORT, IgtlServer
from ._pipeline import TrackingPipeline, TrackLog, TrackStep, TrackSummary, lm_solver

__all__ = [
    "DEFAULT_IGTL_PORT",
    "Backend",
    "IgtlServer",
    "ReplayBackend",
    "SimulatedBackend",
    "SoundDeviceBackend",
    "TrackLog",
    "TrackStep",
    "TrackSummary",
    "TrackingPipeline",
    "default_model",
    "default_trajectory",
    "lm_solver",
]
