"""A hand-written OpenIGTLink decoder for the tests (independent of openemt's and pyigtl's
packers): header, version-2 extended header and metadata, TRANSFORM, STRING and TDATA bodies,
per the OpenIGTLink protocol description."""

from __future__ import annotations

import socket
import struct
import threading

import numpy as np
import pyigtl

HEADER = struct.Struct(">H12s20sIIQQ")


def _matrix(values) -> np.ndarray:
    M = np.eye(4)
    M[:3, :] = np.asarray(values, dtype=np.float64).reshape(4, 3).T   # column by column
    return M


def decode(data: bytes) -> list:
    """Every whole message in ``data``: dicts with ``type``, ``device``, ``timestamp``,
    ``version``, ``metadata`` and ``matrix`` (TRANSFORM), ``text`` (STRING) or ``tools``
    (TDATA: a list of (name, type, matrix))."""
    out, o = [], 0
    while o + 58 <= len(data):
        version, mtype, device, sec, frac, size, _crc = HEADER.unpack_from(data, o)
        if o + 58 + size > len(data):
            break
        body = data[o + 58:o + 58 + size]
        o += 58 + size
        msg = {"type": mtype.rstrip(b"\0").decode(), "device": device.rstrip(b"\0").decode(),
               "timestamp": sec + frac / 2.0 ** 32, "version": version, "metadata": {}}
        content = body
        if version == 2:
            ext, mh, mb, _id = struct.unpack_from(">HHII", body)
            content = body[ext:len(body) - mh - mb]
            meta = body[len(body) - mh - mb:]
            (count,) = struct.unpack_from(">H", meta)
            p = 2 + 8 * count
            for i in range(count):
                ks, _enc, vs = struct.unpack_from(">HHI", meta, 2 + 8 * i)
                key = meta[p:p + ks].decode()
                msg["metadata"][key] = meta[p + ks:p + ks + vs].decode()
                p += ks + vs
        if msg["type"] == "TRANSFORM":
            msg["matrix"] = _matrix(struct.unpack(">12f", content[:48]))
        elif msg["type"] == "STRING":
            _enc, n = struct.unpack_from(">HH", content)
            msg["text"] = content[4:4 + n].decode()
        elif msg["type"] == "TDATA":
            msg["tools"] = tdata_tools(content)
        out.append(msg)
    return out


def tdata_tools(content: bytes) -> list:
    """The elements of a TDATA body: (name, type, matrix) per 70-byte element."""
    assert len(content) % 70 == 0
    tools = []
    for k in range(len(content) // 70):
        e = content[70 * k:70 * k + 70]
        tools.append((e[:20].rstrip(b"\0").decode(), e[20],
                      _matrix(struct.unpack(">12f", e[22:70]))))
    return tools


class GetStatus(pyigtl.messages.MessageBase):
    """A GET_STATUS message (empty content), packed by pyigtl: with header version 2, what a
    client sends to announce that it reads version-2 messages (the server answers STATUS)."""

    def __init__(self, header_version=2):
        super().__init__(device_name="Hello")
        self._message_type = "GET_STATUS"
        self._valid_message = True
        self.header_version = header_version


def get_status(header_version: int = 2) -> bytes:
    return GetStatus(header_version).pack()


class RawReader:
    """A TCP client that keeps every byte a server sends (decoded by :func:`decode`).

    ``announce=True``: it first sends a version-2 GET_STATUS and waits for the STATUS answer;
    ``data`` then holds only what came after the answer (all sent as to a version-2 client)."""

    def __init__(self, port, announce=False):
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=5.0)
        self.data = bytearray()
        if announce:
            self.sock.sendall(get_status(2))
            buf = b""
            while True:
                b = self.sock.recv(1 << 16)
                assert b, "the server closed the connection before answering GET_STATUS"
                buf += b
                msgs, o = [], 0
                while o + 58 <= len(buf):
                    size = HEADER.unpack_from(buf, o)[5]
                    if o + 58 + size > len(buf):
                        break
                    msgs.append((buf[o + 2:o + 14].rstrip(b"\0"), o + 58 + size))
                    o += 58 + size
                ends = [e for t, e in msgs if t == b"STATUS"]
                if ends:
                    self.data += buf[ends[0]:]
                    break
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        self.sock.settimeout(0.05)
        while not self._done.is_set():
            try:
                b = self.sock.recv(1 << 16)
            except TimeoutError:
                continue
            except OSError:
                return
            if not b:
                return
            self.data += b

    def messages(self) -> list:
        return decode(bytes(self.data))

    def close(self):
        self._done.set()
        self._thread.join(timeout=3.0)
        self.sock.close()
