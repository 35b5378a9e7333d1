"""OpenIGTLink TRACKING DATA (``TDATA``) messages: every tool of one sample in one message.

pyigtl (0.3) has no TDATA message class, so the body is encoded here per the OpenIGTLink
protocol description of TDATA (openigtlink.org, "TDATA (Tracking Data)"): one 70-byte
element per tool,

=========  =========  ===================================================================
bytes      type       field
=========  =========  ===================================================================
0-19       char[20]   tool name (the OpenIGTLink device name of the sensor), NUL-padded
20         uint8      type: 1 tracker, 2 6D, 3 3D, 4 5D
21         uint8      reserved (0)
22-69      float32    the upper 3x4 of the transform, column by column (R11 R21 R31 R12 R22
                      R32 R13 R23 R33 TX TY TZ), big-endian, translation in millimetres
=========  =========  ===================================================================

behind the usual 58-byte header (version 1, type ``TDATA``; :func:`openemt.live._igtl_wire.
frame_messages`). A 1500 samples/s stream of K tools is then 1500 messages per second instead
of 1500 K TRANSFORMs, which is what viewers that spend a fixed time per message need.
"""

from __future__ import annotations

import numpy as np

from .._errors import InputError
from ._igtl_wire import frame_messages

__all__ = ["TDATA_6D", "TDATA_ELEMENT", "pack_tdata"]

#: The element type of a 6-DOF tool.
TDATA_6D = 2
#: The layout of one TDATA element (70 bytes, no padding).
TDATA_ELEMENT = np.dtype([("name", "S20"), ("type", "u1"), ("reserved", "u1"),
                          ("matrix", ">f4", (12,))])


def pack_tdata(matrices, valid, names, timestamps, device_name: str = "openemt",
               kind: int = TDATA_6D) -> tuple[bytes, int]:
    """Pack one TDATA message per sample holding every valid tool of that sample.

    Parameters
    ----------
    matrices : ndarray, shape (N, K, 4, 4)
        Per sample and tool, the transform as sent (the caller scales metres to millimetres).
    valid : ndarray, shape (N, K), bool
        The tools to include; a sample without any valid tool gets no message.
    names : sequence of K str
        Tool names (1-20 ASCII characters each).
    timestamps : array of N floats
        Seconds since the epoch, in [0, 2**32).
    device_name : str
        Device name of the messages.
    kind : int
        Element type (default 2, 6D).

    Returns
    -------
    (bytes, int)
        The messages one after the other, and how many there are.
    """
    M = np.asarray(matrices, dtype=np.float64)
    ok = np.asarray(valid, dtype=bool)
    if M.ndim != 4 or M.shape[2:] != (4, 4) or ok.shape != M.shape[:2]:
        raise InputError(f"expected matrices (N, K, 4, 4) and valid (N, K), got {M.shape} "
                         f"and {ok.shape}")
    n, k = ok.shape
    if len(names) != k:
        raise InputError(f"expected {k} tool names, got {len(names)}")
    elems = np.zeros((n, k), TDATA_ELEMENT)
    elems["name"] = np.array([s.encode("ascii")[:20] for s in names], dtype="S20")
    elems["type"] = kind
    elems["matrix"] = M[:, :, :3, :].transpose(0, 1, 3, 2).reshape(n, k, 12)
    per = ok.sum(axis=1)
    keep = per > 0
    if not keep.any():
        return b"", 0
    body = elems[ok].tobytes()                   # row-major: the tools of a sample in order
    offsets = np.concatenate([[0], np.cumsum(per[keep]) * TDATA_ELEMENT.itemsize])
    ts = np.asarray(timestamps, dtype=np.float64)[keep]
    return frame_messages(body, offsets, "TDATA", device_name, ts), int(keep.sum())
