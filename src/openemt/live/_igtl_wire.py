"""OpenIGTLink messages as bytes: headers, time stamps and CRC-64 in compiled loops, TRANSFORM
bodies with version-2 metadata, the version-1 copy of version-2 messages, and single replies
(STATUS, RTS_TDATA) -- byte for byte what pyigtl packs. The server is :mod:`._igtl`."""

from __future__ import annotations

import functools
import struct
import time

import numpy as np
from numba import njit

from .._compile_notice import warm_up_with
from .._errors import InputError

__all__ = ["frame_messages", "pack_message", "pack_transforms", "status_content",
           "to_version_1", "transform_bodies"]


# An OpenIGTLink version-1 TRANSFORM message: a 58-byte header (version, type, device name,
# timestamp as seconds and 2^-32 fractions, body size, CRC-64 of the body) and a 48-byte body
# (the upper 3x4 of the matrix column by column, big-endian float32) -- the bytes pyigtl packs.
_MSG = 58 + 48


#: Multiplies a pose in metres into the matrix OpenIGTLink carries (translation in mm, as 3D
#: Slicer reads it; the rotation unchanged, bit for bit).
MM_SCALE = np.ones((4, 4))
MM_SCALE[:3, 3] = 1000.0


@njit(cache=True)
def packable(matrices, timestamps) -> bool:
    """Whether the compiled packers take these messages: every matrix entry finite and every
    time stamp in [0, 2**32) (else pyigtl's own checks apply, message by message)."""
    for x in matrices.ravel():
        if not np.isfinite(x):
            return False
    for t in timestamps:
        if not (0.0 <= t < 4294967296.0):
            return False
    return True


def _crc64_table() -> np.ndarray:
    """Table of the CRC-64 of OpenIGTLink (ECMA-182 polynomial, MSB first, no reflection)."""
    poly, top, mask = 0x42F0E1EBA9EA3693, 1 << 63, (1 << 64) - 1
    table = np.zeros(256, np.uint64)
    for i in range(256):
        c = i << 56
        for _ in range(8):
            c = ((c << 1) ^ poly) & mask if c & top else (c << 1) & mask
        table[i] = c
    return table


_CRC_TABLE = _crc64_table()


def _fraction_bases() -> np.ndarray:
    """The halving bases of OpenIGTLink's nanoseconds -> 2^-32 fraction conversion."""
    out, base = [], 1_000_000_000
    for _ in range(32):
        base = (base + 1) >> 1
        out.append(base)
    return np.array(out, dtype=np.int64)


_FRAC_BASES = _fraction_bases()


@njit(cache=True, inline="always")
def _put_stamp(out, o, sec, ns, bases):
    """The header's time stamp at ``out[o + 34:o + 42]``: seconds and 2^-32 fractions."""
    frac = np.uint64(0)
    for b in range(32):
        if ns >= bases[b]:
            frac |= np.uint64(1) << np.uint64(31 - b)
            ns -= bases[b]
    s = np.uint64(sec)
    for i in range(4):
        out[o + 34 + i] = (s >> np.uint64(8 * (3 - i))) & np.uint64(0xFF)
        out[o + 38 + i] = (frac >> np.uint64(8 * (3 - i))) & np.uint64(0xFF)


@njit(cache=True, inline="always")
def _split_stamp(t):
    """Seconds and nanoseconds of a time stamp t >= 0, as ``np.trunc`` and ``astype(int64)``
    of ``(t - trunc(t)) * 1e9`` give them (pyigtl's conversion)."""
    sec = np.int64(t)
    return sec, np.int64((t - np.float64(sec)) * 1e9)


@njit(cache=True)
def _pack_kernel(M, ts, device, table, bases, out):
    f = np.empty(12, np.float32)
    u = f.view(np.uint32)
    for k in range(M.shape[0]):
        o = k * 106
        out[o] = 0
        out[o + 1] = 1                                   # version 1
        name = "TRANSFORM"
        for i in range(12):
            out[o + 2 + i] = ord(name[i]) if i < 9 else 0
        for i in range(20):
            out[o + 14 + i] = device[i]
        sec, ns = _split_stamp(ts[k])
        _put_stamp(out, o, sec, ns, bases)
        for i in range(8):
            out[o + 42 + i] = 48 if i == 7 else 0          # body size
        for c in range(4):
            for r in range(3):
                f[3 * c + r] = M[k, r, c]
        crc = np.uint64(0)
        for i in range(12):
            w = u[i]
            for j in range(4):
                byte = (w >> np.uint32(8 * (3 - j))) & np.uint32(0xFF)
                out[o + 58 + 4 * i + j] = byte
                idx = ((crc >> np.uint64(56)) ^ np.uint64(byte)) & np.uint64(0xFF)
                crc = table[idx] ^ (crc << np.uint64(8))
        for i in range(8):
            out[o + 50 + i] = (crc >> np.uint64(8 * (7 - i))) & np.uint64(0xFF)


@njit(cache=True)
def _frame_kernel(body, offsets, version, tname, devices, ts, table, bases, out):
    """Frame message bodies: message k is ``body[offsets[k]:offsets[k + 1]]`` behind a
    58-byte header (``version``, type ``tname``, device ``devices[k]`` or ``devices[0]``,
    time stamp, body size, CRC-64 of the body)."""
    o = 0
    for k in range(offsets.shape[0] - 1):
        b0, b1 = offsets[k], offsets[k + 1]
        out[o] = (version >> 8) & 0xFF
        out[o + 1] = version & 0xFF
        for i in range(12):
            out[o + 2 + i] = tname[i]
        d = k if devices.shape[0] > 1 else 0
        for i in range(20):
            out[o + 14 + i] = devices[d, i]
        sec, ns = _split_stamp(ts[k])
        _put_stamp(out, o, sec, ns, bases)
        size = np.uint64(b1 - b0)
        for i in range(8):
            out[o + 42 + i] = (size >> np.uint64(8 * (7 - i))) & np.uint64(0xFF)
        crc = np.uint64(0)
        for j in range(b1 - b0):
            byte = body[b0 + j]
            out[o + 58 + j] = byte
            idx = ((crc >> np.uint64(56)) ^ np.uint64(byte)) & np.uint64(0xFF)
            crc = table[idx] ^ (crc << np.uint64(8))
        for i in range(8):
            out[o + 50 + i] = (crc >> np.uint64(8 * (7 - i))) & np.uint64(0xFF)
        o += 58 + (b1 - b0)


@functools.lru_cache(maxsize=64)
def _names_matrix(names: tuple) -> np.ndarray:
    """One 20-byte device name per message, ``(N, 20)`` (read-only, cached: a live stream
    sends the same sequence of devices block after block)."""
    out = (np.frombuffer(b"".join([_name_bytes(n, 20).tobytes() for n in names]),
                         np.uint8).reshape(len(names), 20) if names
           else np.zeros((1, 20), np.uint8))
    out.flags.writeable = False
    return out


@functools.lru_cache(maxsize=1024)
def _name_bytes(name: str, size: int) -> np.ndarray:
    out = np.zeros(size, np.uint8)
    raw = name.encode("ascii")[:size]
    out[:len(raw)] = np.frombuffer(raw, np.uint8)
    # cached, so read-only; and one array type for the kernels, as _names_matrix's (a
    # writable and a read-only name matrix each compiled a _frame_kernel)
    out.flags.writeable = False
    return out


def frame_messages(bodies, offsets, message_type: str, device_names, timestamps, *,
                   header_version: int = 1) -> bytes:
    """Put OpenIGTLink headers in front of N message bodies, byte for byte what pyigtl's
    ``pack`` writes (a compiled loop: header, time stamp, CRC-64 of each body).

    Parameters
    ----------
    bodies : bytes
        The N bodies one after the other (with a version-2 header: extended header, content,
        metadata).
    offsets : array of N + 1 ints
        Body k is ``bodies[offsets[k]:offsets[k + 1]]``.
    message_type : str
        E.g. ``"TRANSFORM"`` or ``"TDATA"`` (at most 12 ASCII characters).
    device_names : str or sequence of N str
        One device name (1-20 ASCII characters) for all messages, or one per message.
    timestamps : array of N floats
        Seconds since the epoch, in [0, 2**32).
    header_version : int
        1 (OpenIGTLink 1 and 2) or 2 (OpenIGTLink 3: extended header and metadata in the body).
    """
    off = np.asarray(offsets, dtype=np.int64)
    ts = np.asarray(timestamps, dtype=np.float64)
    if ts.shape != (off.size - 1,):
        raise InputError(f"expected {off.size - 1} timestamps, got {ts.shape}")
    if isinstance(device_names, str):
        dev = _name_bytes(device_names, 20)[None]
    else:
        dev = _names_matrix(tuple(device_names))
        if dev.shape[0] not in (1, ts.size) and ts.size:
            raise InputError(f"expected {ts.size} device names, got {dev.shape[0]}")
    body = np.frombuffer(bodies, np.uint8) if len(bodies) else np.zeros(1, np.uint8)
    out = np.empty(58 * ts.size + int(off[-1] - off[0]) if ts.size else 0, np.uint8)
    _frame_kernel(body, off - off[0] if off[0] else off, int(header_version),
                  _name_bytes(message_type, 12), dev, ts, _CRC_TABLE, _FRAC_BASES, out)
    return out.tobytes()


_HEADER = struct.Struct(">H12s20sIIQQ")       # version, type, device, stamp, body size, CRC
_EXT_HEADER = struct.Struct(">HHII")          # extended header: size, metadata sizes, id
_META_ENTRY = struct.Struct(">HHI")           # metadata index: key size, encoding, value size
_ASCII = 3                                    # IANA US-ASCII, the encoding pyigtl writes


def _metadata_columns(metadata, n: int) -> tuple:
    """``metadata`` (key -> N values) as ASCII keys and, per key, N ASCII values; numbers are
    written as ``format(x, ".3e")``, a bytes array (dtype ``S``) as it is."""
    keys, cols = [], []
    for key, values in metadata.items():
        array = type(values) is np.ndarray
        vals = values.tolist() if array else list(values)
        if len(vals) != n:
            raise InputError(f"expected {n} values of metadata {key!r}, got {len(vals)}")
        keys.append(_key_bytes(key))
        kind = values.dtype.kind if array else ""
        if kind == "S":
            cols.append(vals)                                   # already ASCII bytes
        elif kind in ("f", "i", "u"):
            cols.append([b"%.3e" % v for v in vals])           # one kind: no test per value
        else:
            cols.append([(v if isinstance(v, str) else format(v, ".3e")).encode("ascii")
                         for v in vals])
    return keys, cols


@functools.lru_cache(maxsize=256)
def _key_bytes(key: str) -> bytes:
    return key.encode("ascii")


@functools.lru_cache(maxsize=256)
def _v2_head(key_sizes: tuple, lens: tuple) -> tuple:
    """Extended header, metadata index and body size of a version-2 TRANSFORM whose metadata
    keys and values have these byte lengths."""
    index = struct.pack(">H", len(key_sizes)) + b"".join(
        _META_ENTRY.pack(k, _ASCII, v) for k, v in zip(key_sizes, lens))
    ext = _EXT_HEADER.pack(12, len(index), sum(key_sizes) + sum(lens), 0)
    return ext, index, 60 + len(index) + sum(key_sizes) + sum(lens)


#: Fewest messages whose version-2 bodies are built with array operations (measured: 1 message
#: 17 us as arrays, 8 us joined; about equal at 6).
_VECTOR_BODIES = 6


def transform_bodies(matrices, metadata=None) -> tuple:
    """TRANSFORM message bodies and their offsets (see :func:`frame_messages`): the 3x4 matrix
    as big-endian float32 column by column; with ``metadata`` (key -> one value per message,
    str or number) in the version-2 layout: extended header, matrix, metadata index, keys and
    values."""
    M = np.asarray(matrices, dtype=np.float64)
    n = len(M)
    content = M[:, :3, :].transpose(0, 2, 1).astype(">f4").tobytes()   # C order: by column
    if metadata is None:
        return content, 48 * np.arange(n + 1)
    keys, cols = _metadata_columns(metadata, n)
    key_sizes = tuple(len(k) for k in keys)

    lens0 = tuple(len(c[0]) for c in cols) if n else ()
    if n >= _VECTOR_BODIES and all(len(v) == w for c, w in zip(cols, lens0) for v in c):
        # the usual case of a block, every value of a key as long (e.g. all "OK"): one array
        # operation per part of the body instead of a loop over the messages (below a few
        # messages, the loop's byte joins cost less than the arrays: one sample per read)
        ext, index, size = _v2_head(key_sizes, lens0)
        body = np.empty((n, size), np.uint8)
        body[:, :12] = np.frombuffer(ext, np.uint8)
        body[:, 12:60] = np.frombuffer(content, np.uint8).reshape(n, 48)
        o = 60 + len(index)
        body[:, 60:o] = np.frombuffer(index, np.uint8)
        for k, c, w in zip(keys, cols, lens0):
            body[:, o:o + len(k)] = np.frombuffer(k, np.uint8)
            o += len(k)
            body[:, o:o + w] = np.frombuffer(b"".join(c), np.uint8).reshape(n, w)
            o += w
        return body.tobytes(), size * np.arange(n + 1)
    parts, offsets = [], [0]
    for i, vals in enumerate(zip(*cols) if cols else [()] * n):   # (no keys: empty metadata)
        h = _v2_head(key_sizes, tuple(map(len, vals)))
        parts += [h[0], content[48 * i:48 * i + 48], h[1]]
        for k, v in zip(keys, vals):
            parts += [k, v]
        offsets.append(offsets[-1] + h[2])
    return b"".join(parts), offsets


def _value_matrix(values, n: int):
    """The N values of one metadata key as an ``(N, w)`` uint8 matrix when they all have the
    same byte length w (the usual case: a bytes array of full-width values, or numbers whose
    ``.3e`` form has one length); None otherwise."""
    if type(values) is np.ndarray and values.dtype.kind == "S":
        # the kernel refuses a NUL byte in a value: a shorter value of the array (NUL-padded)
        return (np.ascontiguousarray(values).view(np.uint8).reshape(n, values.dtype.itemsize)
                if values.shape == (n,) and values.dtype.itemsize else None)
    if type(values) is np.ndarray and values.dtype.kind in "fiu":
        vals = [b"%.3e" % v for v in values.tolist()]
    else:
        vals = [(v if isinstance(v, str) else format(v, ".3e")).encode("ascii")
                for v in values]
    if len(vals) != n or not n:
        return None
    w = len(vals[0])
    joined = b"".join(vals)
    if len(joined) != n * w or any(len(v) != w for v in vals):
        return None
    return np.frombuffer(joined, np.uint8).reshape(n, w)


@functools.lru_cache(maxsize=64)
def _v2_template(keys: tuple, widths: tuple) -> tuple:
    """The body of a version-2 TRANSFORM whose metadata values have these byte widths, with
    zeros where the matrix and the values go, and the position in it of every value byte."""
    ext, index, size = _v2_head(tuple(map(len, keys)), widths)
    body, slots = bytearray(ext + bytes(48) + index), []
    for k, w in zip(keys, widths):
        body += k
        slots += range(len(body), len(body) + w)
        body += bytes(w)
    assert len(body) == size
    return np.frombuffer(bytes(body), np.uint8), np.array(slots, np.int64)


@njit(cache=True)
def _v2_kernel(M, ts, devices, template, slots, values, table, bases, out):
    """Version-2 TRANSFORM messages of one body layout: message k is the 58-byte header
    (device ``devices[k]`` or ``devices[0]``), then ``template`` with the matrix (big-endian
    float32, column by column) at bytes 12-59 and ``values[k]`` at ``slots``; CRC-64 of the
    body in the header. False, with ``out`` unfinished, where a value has a NUL byte (a
    shorter value of a NUL-padded bytes array: not of this layout)."""
    for k in range(values.shape[0]):
        for j in range(values.shape[1]):
            if values[k, j] == 0:
                return False
    f = np.empty(12, np.float32)
    u = f.view(np.uint32)
    size = template.shape[0]
    name = "TRANSFORM"
    for k in range(M.shape[0]):
        o = k * (58 + size)
        out[o] = 0
        out[o + 1] = 2                                   # header version 2
        for i in range(12):
            out[o + 2 + i] = ord(name[i]) if i < 9 else 0
        d = k if devices.shape[0] > 1 else 0
        for i in range(20):
            out[o + 14 + i] = devices[d, i]
        sec, ns = _split_stamp(ts[k])
        _put_stamp(out, o, sec, ns, bases)
        for i in range(8):
            out[o + 42 + i] = (np.uint64(size) >> np.uint64(8 * (7 - i))) & np.uint64(0xFF)
        b = o + 58
        for i in range(size):
            out[b + i] = template[i]
        for c in range(4):
            for r in range(3):
                f[3 * c + r] = M[k, r, c]
        for i in range(12):
            w = u[i]
            for j in range(4):
                out[b + 12 + 4 * i + j] = (w >> np.uint32(8 * (3 - j))) & np.uint32(0xFF)
        for j in range(slots.shape[0]):
            out[b + slots[j]] = values[k, j]
        crc = np.uint64(0)
        for i in range(size):
            idx = ((crc >> np.uint64(56)) ^ np.uint64(out[b + i])) & np.uint64(0xFF)
            crc = table[idx] ^ (crc << np.uint64(8))
        for i in range(8):
            out[o + 50 + i] = (crc >> np.uint64(8 * (7 - i))) & np.uint64(0xFF)
    return True


def pack_transforms_v2(matrices, timestamps, device_names, metadata) -> bytes:
    """:func:`pack_transforms` with ``metadata`` (header version 2) for one device name or one
    per message (``str`` or a sequence of N): in one compiled pass when every key's values
    have one byte length (the live stream's blocks), else through :func:`transform_bodies`
    and :func:`frame_messages`; the same bytes either way."""
    M = np.ascontiguousarray(matrices, dtype=np.float64)
    ts = np.ascontiguousarray(timestamps, dtype=np.float64)
    n = M.shape[0]
    cols = [_value_matrix(v, n) for v in metadata.values()]
    if n and cols and ts.shape == (n,) and not any(c is None for c in cols):
        keys = tuple(_key_bytes(k) for k in metadata)
        template, slots = _v2_template(keys, tuple(c.shape[1] for c in cols))
        devices = _names_matrix((device_names,) if isinstance(device_names, str)
                                else tuple(device_names))
        if devices.shape[0] in (1, n):
            out = np.empty(n * (58 + template.shape[0]), np.uint8)
            if _v2_kernel(M, ts, devices, template, slots, np.concatenate(cols, axis=1),
                          _CRC_TABLE, _FRAC_BASES, out):
                return out.tobytes()
    body, off = transform_bodies(M, metadata)       # ragged values; the errors of bad input
    return frame_messages(body, off, "TRANSFORM", device_names, ts, header_version=2)


def pack_transforms(matrices, timestamps, device_name: str, metadata=None) -> bytes:
    """Pack N TRANSFORM messages at once, byte for byte what pyigtl's
    ``TransformMessage.pack`` gives, in a compiled loop (a block of poses costs about as much
    as one pyigtl message).

    Parameters
    ----------
    matrices : ndarray, shape (N, 4, 4)
        Transforms as sent (the caller scales metres to millimetres).
    timestamps : array of N floats
        Seconds since the epoch, in [0, 2**32).
    device_name : str
        1-20 ASCII characters.
    metadata : dict, optional
        OpenIGTLink version-2 metadata, key -> N values (str, or numbers written as
        ``format(x, ".3e")``): the messages then have header version 2 (as pyigtl's with
        ``header_version = 2`` and the same ``metadata`` dict); without it, version 1.
    """
    if metadata is not None:
        return pack_transforms_v2(matrices, timestamps, device_name, metadata)
    M = np.ascontiguousarray(matrices, dtype=np.float64)
    ts = np.ascontiguousarray(timestamps, dtype=np.float64)
    out = np.empty(M.shape[0] * _MSG, np.uint8)
    _pack_kernel(M, ts, _name_bytes(device_name, 20), _CRC_TABLE, _FRAC_BASES, out)
    return out.tobytes()


@njit(cache=True)
def _crc64(body, table):
    """CRC-64 of OpenIGTLink over ``body`` (uint8 array)."""
    crc = np.uint64(0)
    for j in range(body.shape[0]):
        idx = ((crc >> np.uint64(56)) ^ np.uint64(body[j])) & np.uint64(0xFF)
        crc = table[idx] ^ (crc << np.uint64(8))
    return crc


@njit(cache=True)
def _split_kernel(data, starts):
    """The start of every whole message in ``data`` (58-byte header, then the body whose size
    the header gives) into ``starts``; returns how many, stopping at an incomplete one."""
    o, n = 0, 0
    while o + 58 <= data.shape[0]:
        size = np.uint64(0)
        for i in range(8):
            size = (size << np.uint64(8)) | np.uint64(data[o + 42 + i])
        if np.uint64(o + 58) + size > np.uint64(data.shape[0]):
            break
        starts[n] = o
        n += 1
        o += 58 + np.int64(size)
    starts[n] = o
    return n


@njit(cache=True)
def _downgrade_kernel(data, starts, n, table, out):
    """Copy the ``n`` messages of ``data`` into ``out`` with header version 1: a version-2
    message loses its extended header and metadata (the body is its content alone, the CRC
    computed again); other messages are copied as they are. Returns the bytes written."""
    o = 0
    for k in range(n):
        s, e = starts[k], starts[k + 1]
        version = (np.int64(data[s]) << 8) | np.int64(data[s + 1])
        size = e - s - 58
        c0, c1 = s + 58, e
        if version >= 2 and size >= 12:
            ext = (np.int64(data[s + 58]) << 8) | np.int64(data[s + 59])
            mh = (np.int64(data[s + 60]) << 8) | np.int64(data[s + 61])
            mb = np.int64(0)
            for i in range(4):
                mb = (mb << 8) | np.int64(data[s + 62 + i])
            if ext >= 12 and ext + mh + mb <= size:
                c0, c1 = s + 58 + ext, e - mh - mb
        if c0 == s + 58 and version < 2:
            out[o:o + e - s] = data[s:e]
            o += e - s
            continue
        out[o:o + 42] = data[s:s + 42]
        out[o] = 0
        out[o + 1] = 1
        m = np.uint64(c1 - c0)
        for i in range(8):
            out[o + 42 + i] = (m >> np.uint64(8 * (7 - i))) & np.uint64(0xFF)
        crc = _crc64(data[c0:c1], table)
        for i in range(8):
            out[o + 50 + i] = (crc >> np.uint64(8 * (7 - i))) & np.uint64(0xFF)
        out[o + 58:o + 58 + c1 - c0] = data[c0:c1]
        o += 58 + c1 - c0
    return o


def _split(data: bytes) -> tuple:
    """``(buffer, starts, n)``: the whole messages of ``data`` (see :func:`_split_kernel`)."""
    buf = np.frombuffer(data, np.uint8)
    starts = np.empty(len(data) // 58 + 2, np.int64)
    return buf, starts, int(_split_kernel(buf, starts))


def to_version_1(data: bytes) -> bytes:
    """The OpenIGTLink messages in ``data`` with header version 1, as an OpenIGTLink 1 or 2
    reader expects them: each version-2 message without its extended header and metadata
    (content and time stamp unchanged, body size and CRC-64 written again); version-1
    messages unchanged."""
    buf, starts, n = _split(data)
    if not n:
        return b""
    out = np.empty(len(data), np.uint8)
    used = _downgrade_kernel(buf, starts, n, _CRC_TABLE, out)
    return out[:used].tobytes()


def pack_message(message_type: str, device_name: str, content: bytes, *,
                 header_version: int = 1, timestamp: float | None = None) -> bytes:
    """One OpenIGTLink message (e.g. a STATUS or RTS_TDATA reply): ``content`` behind the
    header; with ``header_version=2`` inside an extended header and an empty metadata index
    (as pyigtl packs a version-2 message without metadata)."""
    body = content
    if header_version >= 2:
        body = _EXT_HEADER.pack(12, 2, 0, 0) + content + b"\0\0"
    t = time.time() if timestamp is None else float(timestamp)
    sec = int(t)
    frac, ns = 0, int((t - sec) * 1e9)
    for b, base in enumerate(_FRAC_BASES.tolist()):      # as pyigtl converts nanoseconds
        if ns >= base:
            frac |= 1 << (31 - b)
            ns -= base
    return _HEADER.pack(2 if header_version >= 2 else 1, message_type.encode("ascii"),
                        _name_bytes(device_name, 20).tobytes(), sec, frac, len(body),
                        _crc64_small(body)) + body


_CRC_LIST = _CRC_TABLE.tolist()


def _crc64_small(body: bytes) -> int:
    """CRC-64 of a short body in plain Python (no compiled kernel to load in the I/O
    thread for a client's few bytes)."""
    crc, table, mask = 0, _CRC_LIST, (1 << 64) - 1
    for b in body:
        crc = table[(crc >> 56) ^ b] ^ ((crc << 8) & mask)
    return crc


def status_content(code: int = 1, text: str = "", *, subcode: int = 0,
                   error_name: str = "") -> bytes:
    """The body of an OpenIGTLink STATUS message: code (1 = OK), sub-code, a 20-byte error
    name and the NUL-terminated status text."""
    return (struct.pack(">Hq", int(code), int(subcode)) + _name_bytes(error_name, 20).tobytes()
            + text.encode("ascii", "replace") + b"\0")


def _warm_up():
    packable(np.eye(4)[None], np.array([1.5]))
    pack_transforms(np.eye(4)[None], np.array([1.5]), "Sensor")
    pack_transforms(np.eye(4)[None], np.array([1.5]), "Sensor", {"Status": ["OK"]})
    # values of different lengths: the general path (bodies, then frame_messages)
    pack_transforms(np.repeat(np.eye(4)[None], 2, axis=0), np.array([1.5, 1.5]), "Sensor",
                    {"Status": ["OK", "INVALID"]})


warm_up_with("openemt.live._igtl_wire:_pack_kernel", _warm_up)
warm_up_with("openemt.live._igtl_wire:_frame_kernel", _warm_up)
warm_up_with("openemt.live._igtl_wire:packable", _warm_up)
warm_up_with("openemt.live._igtl_wire:_v2_kernel", _warm_up)
