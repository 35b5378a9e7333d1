"""Signal processing: raw-signal simulation of an FDM tracker and demodulation to couplings."""

from .._lazy import lazy_exports

#: where each public name lives; a module is imported on first use of one of its names
_SOURCES = {
    "._demod": ("Demodulated", "Demodulator", "demodulate", "distortion_ratio", "frame_length",
                "frame_window", "phase_calibration"),
    "._rawsim": ("ILEMT_FREQUENCIES", "RAW_FORMAT", "ChannelLayout", "RawSignal", "RawSignalConfig",
                 "RawSimulator", "eddy_factor", "read_raw", "simulate_raw", "write_raw"),
}
__all__, __getattr__, __dir__ = lazy_exports(__name__, _SOURCES)
