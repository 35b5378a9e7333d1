"""Opening HDF5 files that may be damaged or hostile without letting libhdf5 hang the process.

The HDF5 C library trusts the addresses inside a file: a damaged file can send it into a loop
that no signal interrupts. openemt therefore *seals* the files it writes: the HDF5 user block
(the first :data:`SEAL_SIZE` bytes, which the library ignores) holds the length and CRC-32 of
the rest of the file. On reading,

* a sealed file whose seal matches is opened directly (the common case; the CRC costs about a
  second per GB);
* any other file (written by another program, edited after writing, or damaged) is first
  *probed* in a child process that opens it and walks every object; a probe that fails, crashes
  or takes longer than :data:`PROBE_TIMEOUT_S` means the file is refused with one clear error
  instead of hanging the caller.
"""

from __future__ import annotations

import os
import zlib
from pathlib import Path

__all__ = ["PROBE_TIMEOUT_S", "SEAL_SIZE", "check_readable", "seal", "seal_matches"]

#: size of the HDF5 user block that carries openemt's seal (a power of two >= 512)
SEAL_SIZE = 512
#: seconds a child process may take to open and walk an unsealed file before it is refused
PROBE_TIMEOUT_S = 20.0

_MAGIC = b"openemt-seal v1\n"
_BLOCK = 1 << 24


def _crc(path: Path, start: int) -> tuple[int, int]:
    crc, n = 0, 0
    with open(path, "rb") as fh:
        fh.seek(start)
        while chunk := fh.read(_BLOCK):
            crc = zlib.crc32(chunk, crc)
            n += len(chunk)
    return crc, n


def seal(path) -> None:
    """Write the seal into the user block of a closed HDF5 file created with
    ``userblock_size=SEAL_SIZE``."""
    path = Path(path)
    crc, n = _crc(path, SEAL_SIZE)
    tag = _MAGIC + f"length={n} crc32={crc:08x}\n".encode()
    with open(path, "r+b") as fh:
        fh.write(tag.ljust(SEAL_SIZE, b"\0"))


def seal_matches(path) -> bool:
    """True if the file carries an openemt seal that matches its content."""
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            head = fh.read(SEAL_SIZE)
    except OSError:
        return False
    if not head.startswith(_MAGIC):
        return False
    try:
        fields = dict(kv.split("=", 1) for kv in
                      head[len(_MAGIC):].split(b"\n", 1)[0].decode("ascii").split())
        length, crc = int(fields["length"]), int(fields["crc32"], 16)
    except (ValueError, KeyError, UnicodeDecodeError):
        return False
    if os.path.getsize(path) != SEAL_SIZE + length:
        return False
    return _crc(path, SEAL_SIZE) == (crc, length)


def _walk(path: str) -> None:  # runs in the child process
    import h5py
    import numpy as np

    def visit(name, obj):
        for key in obj.attrs:
            obj.attrs[key]
        if isinstance(obj, h5py.Dataset) and obj.shape and obj.size:
            obj[(slice(0, 1),) + (slice(None),) * (obj.ndim - 1)]
            obj[(slice(obj.shape[0] - 1, None),) + (slice(None),) * (obj.ndim - 1)]
        elif isinstance(obj, h5py.Dataset):
            np.asarray(obj[()])

    with h5py.File(path, "r") as f:
        for key in f.attrs:
            f.attrs[key]
        f.visititems(visit)


def check_readable(path, *, timeout: float = PROBE_TIMEOUT_S) -> str:
    """``""`` if the HDF5 file can be opened safely, else the reason it cannot.

    Sealed files are checked by their CRC; others by a probe in a child process (see the
    module docstring)."""
    path = Path(path)
    try:
        st = path.stat()
        key = (str(path.resolve()), st.st_size, st.st_mtime_ns, st.st_ino)
    except OSError as exc:
        return " ".join(str(exc).split())
    if key in _checked:
        return ""
    reason = "" if seal_matches(path) else _probe(path, timeout)
    if not reason:
        if len(_checked) > 256:
            _checked.clear()
        _checked.add(key)
    return reason


#: files found readable in this process (path, size, mtime, inode): not checked again
_checked: set = set()


def _probe(path: Path, timeout: float) -> str:
    from ._isolated import run_isolated

    out = run_isolated(_walk, (str(path),), timeout=timeout)
    if out.kind == "ok":
        return ""
    if out.kind == "timeout":
        return f"reading its structure did not finish within {timeout:g} s"
    if out.kind == "died":
        return f"reading its structure stopped the reader (exit {out.value})"
    return " ".join(f"{type(out.value).__name__}: {out.value}".split())[:120] or "failed"
