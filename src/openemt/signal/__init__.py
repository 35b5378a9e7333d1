"""Signal processing: raw-signal simulation of an FDM tracker and demodulation to couplings."""

from ._demod import (
    Demodulated,
    Demodulator,
    demodulate,
    frame_length,
    frame_window,
    phase_calibration,
)
from ._rawsim import (
    ILEMT_FREQUENCIES,
    RAW_FORMAT,
    ChannelLayout,
    RawSignal,
    RawSignalConfig,
    RawSimulator,
    eddy_factor,
    read_raw,
    simulate_raw,
    write_raw,
)

__all__ = [
    "ILEMT_FREQUENCIES",
    "RAW_FORMAT",
    "ChannelLayout",
    "Demodulated",
    "Demodulator",
    "RawSignal",
    "RawSignalConfig",
    "RawSimulator",
    "demodulate",
    "eddy_factor",
    "frame_length",
    "frame_window",
    "phase_calibration",
    "read_raw",
    "simulate_raw",
    "write_raw",
]
