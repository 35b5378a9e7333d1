"""The binary framing of a raw ADC stream over a serial port or TCP (docs/live.md#adc-framing).

One frame = a 32-byte little-endian header, the payload, a CRC-32::

    offset size  field
    0      4     sync word EB 90 5A A5
    4      1     version (1)
    5      1     sample format: 1 = int16, 2 = int32, 3 = float32
    6      2     flags: bit 0 = first frame since the emitter (re)started
    8      8     sample counter: index of the frame's first sample (uint64)
    16     8     sample clock, Hz (float64, nominal)
    24     4     scale, V per count (float32; 1.0 for float32 samples)
    28     2     channels per sample (uint16)
    30     2     samples per channel in this frame (uint16)
    32     P     payload: samples x channels values, sample-major (s0c0 s0c1 ... s1c0 ...)
    32+P   4     CRC-32 (IEEE 802.3, zlib's) of bytes 4 .. 32+P-1 (all but the sync word)

:func:`pack_frame` writes one (the reference emitter, :mod:`openemt.live.emitter`, and the
tests); :class:`FrameDecoder` finds, checks and decodes frames in a byte stream, resyncing on
the next sync word after a bad CRC or dropped bytes, and counts what it threw away.
"""

from __future__ import annotations

import struct
import zlib

import numpy as np

from .._errors import InputError

__all__ = ["FLAG_START", "FORMATS", "FRAME_VERSION", "HEADER", "MAX_FRAME_SAMPLES", "SYNC",
           "FrameDecoder", "pack_frame"]

#: The sync word that starts every frame.
SYNC = b"\xeb\x90\x5a\xa5"
#: The framing version this reader understands.
FRAME_VERSION = 1
#: ``<4sBBHQdfHH``: sync, version, format, flags, counter, sample clock, scale, channels, n.
HEADER = struct.Struct("<4sBBHQdfHH")
_CRC = struct.Struct("<I")
#: Sample format code -> (numpy dtype, name).
FORMATS = {1: ("<i2", "int16"), 2: ("<i4", "int32"), 3: ("<f4", "float32")}
_CODES = {name: code for code, (_, name) in FORMATS.items()}
#: Flag bit: the first frame since the emitter (re)started (its counter restarts).
FLAG_START = 1
#: The most samples per channel in one frame (a larger count is a corrupted header).
MAX_FRAME_SAMPLES = 4096


def format_code(name) -> int:
    """The format code of ``"int16"``, ``"int32"`` or ``"float32"`` (or a code)."""
    if name in FORMATS:
        return int(name)
    if name not in _CODES:
        raise InputError(f"expected a sample format in {sorted(_CODES)}, got {name!r}")
    return _CODES[name]


def pack_frame(values, counter: int, sample_rate: float, *, fmt="int32", scale: float = 1.0,
               flags: int = 0) -> bytes:
    """One frame of ``values`` (n, channels): counts for the integer formats (volts =
    counts x ``scale``), volts for float32."""
    code = format_code(fmt)
    dtype = FORMATS[code][0]
    x = np.asarray(values)
    n, ch = x.shape
    header = HEADER.pack(SYNC, FRAME_VERSION, code, int(flags), int(counter),
                         float(sample_rate), float(scale), ch, n)
    payload = np.ascontiguousarray(x, dtype=dtype).tobytes()
    crc = zlib.crc32(payload, zlib.crc32(header[4:]))
    return header + payload + _CRC.pack(crc)


class FrameDecoder:
    """Frames out of a byte stream: ``feed(bytes) -> [(counter, flags, samples (n, ch) V)]``.

    A frame is accepted only with the sync word, a plausible header (version, format,
    ``n_channels`` channels, 1..:data:`MAX_FRAME_SAMPLES` samples) and a matching CRC-32;
    anything else is skipped up to the next sync word and counted: ``crc_errors`` (complete
    frames whose CRC did not match), ``bad_headers`` (a sync word followed by an impossible
    header) and ``bytes_skipped`` (bytes outside accepted frames). A frame with a valid CRC but
    another channel count or sample clock than expected is a wiring error: InputError.
    """

    def __init__(self, n_channels: int, sample_rate: float):
        self.n_channels = int(n_channels)
        self.sample_rate = float(sample_rate)
        self._buf = bytearray()
        self.frames = 0
        self.crc_errors = 0
        self.bad_headers = 0
        self.bytes_skipped = 0
        self.bytes_read = 0

    @property
    def pending(self) -> int:
        """Bytes held for a frame not yet complete (a damaged size field makes the decoder
        wait for at most one largest frame before the CRC sends it on)."""
        return len(self._buf)

    def drop_buffer(self) -> None:
        """Forget a partial frame (the connection it came on is gone)."""
        self.bytes_skipped += len(self._buf)
        self._buf.clear()

    def _check_config(self, ch, fs) -> None:
        if ch != self.n_channels or abs(fs - self.sample_rate) > 1e-6 * self.sample_rate:
            raise InputError(f"expected ADC frames of {self.n_channels} channels at "
                             f"{self.sample_rate:g} Hz (the tracker's adc.channels and "
                             f"adc.sample_rate), got {ch} channels at {fs:g} Hz")

    def feed(self, data) -> list:
        buf = self._buf
        buf += data
        self.bytes_read += len(data)
        out = []
        pos, hs = 0, HEADER.size
        while True:
            k = buf.find(SYNC, pos)
            if k < 0:
                keep = max(pos, len(buf) - (len(SYNC) - 1))   # a sync word cut in two
                self.bytes_skipped += keep - pos
                pos = keep
                break
            self.bytes_skipped += k - pos
            pos = k
            if len(buf) - pos < hs:
                break
            _, ver, code, flags, counter, fs, scale, ch, n = HEADER.unpack_from(buf, pos)
            if (ver != FRAME_VERSION or code not in FORMATS or not 1 <= n <= MAX_FRAME_SAMPLES
                    or not 1 <= ch <= 1024 or not np.isfinite(scale)):
                self.bad_headers += 1
                self.bytes_skipped += 1
                pos += 1
                continue
            dtype = FORMATS[code][0]
            size = hs + n * ch * int(dtype[-1]) + _CRC.size
            if len(buf) - pos < size:
                break
            (crc,) = _CRC.unpack_from(buf, pos + size - _CRC.size)
            view = memoryview(buf)
            ok = zlib.crc32(view[pos + len(SYNC):pos + size - _CRC.size]) == crc
            if not ok:
                view.release()
                self.crc_errors += 1
                self.bytes_skipped += 1
                pos += 1                      # resync on the next sync word
                continue
            self._check_config(ch, fs)
            x = np.frombuffer(view[pos + hs:pos + size - _CRC.size], dtype=dtype)
            x = x.reshape(n, ch) * float(scale)      # a float64 copy
            view.release()
            out.append((counter, flags, x))
            self.frames += 1
            pos += size
        del buf[:pos]
        return out
