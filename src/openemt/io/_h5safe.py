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

Whether sealed or not (anyone can recompute a CRC), every file is then opened through
:func:`open_h5`, which reads only what the file holds: before any data is read,
:func:`check_structure` walks every link without following it and refuses external links, soft
links that name no object of the file, virtual datasets, datasets stored in external files and
filters other than HDF5's built-in deflate, shuffle and Fletcher-32 (a plugin filter runs code
from outside openemt), and it adds up the bytes every dataset and attribute declares: a file may
declare at most :data:`MAX_H5_EXPANSION` times its own size (at least :data:`H5_FLOOR_BYTES`,
never more than :data:`MAX_H5_DECLARED_BYTES`), so that a small file declaring 10**8 rows is
refused before anything is allocated.
"""

from __future__ import annotations

import os
import zlib
from pathlib import Path

from .._errors import InputError
from ._safefile import check_regular

__all__ = ["ALLOWED_H5_FILTERS", "H5_FLOOR_BYTES", "MAX_H5_DECLARED_BYTES", "MAX_H5_EXPANSION",
           "MAX_H5_LINKS", "PROBE_TIMEOUT_S", "SEAL_SIZE", "check_readable", "check_rows",
           "check_structure", "committed_rows", "open_h5", "seal", "seal_matches"]

#: size of the HDF5 user block that carries openemt's seal (a power of two >= 512)
SEAL_SIZE = 512
#: seconds a child process may take to open and walk an unsealed file before it is refused
PROBE_TIMEOUT_S = 20.0

#: HDF5 filters a reader accepts (built into libhdf5; openemt writes Fletcher-32, other tools
#: deflate and shuffle): filter id -> name
ALLOWED_H5_FILTERS = {1: "deflate", 2: "shuffle", 3: "fletcher32"}
#: bytes of arrays and attributes an HDF5 file may declare per byte of its size (deflate
#: expands at most ~1032x; measured data compresses a few times at most)
MAX_H5_EXPANSION = 64
#: bytes any HDF5 file may declare whatever its size
H5_FLOOR_BYTES = 64 << 20
#: bytes no HDF5 file may declare, whatever its size (1 TiB)
MAX_H5_DECLARED_BYTES = 1 << 40
#: links (names of objects) walked in one file, and attributes of all its objects
MAX_H5_LINKS = 100_000

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

    with h5py.File(path, "r") as f:      # nothing of a hostile structure is read below
        check_structure(f, Path(path).name)

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
    if out.kind == "raised" and isinstance(out.value, InputError):
        raise InputError(str(out.value))          # a refused structure: its own message
    if out.kind == "timeout":
        return f"reading its structure did not finish within {timeout:g} s"
    if out.kind == "died":
        return f"reading its structure stopped the reader (exit {out.value})"
    return " ".join(f"{type(out.value).__name__}: {out.value}".split())[:120] or "failed"


# --------------------------------------------------------------------------- structure


def _show(name: bytes) -> str:
    return repr(name.decode("utf-8", errors="replace"))


def _bytes_text(n: int) -> str:
    for unit, scale in (("TiB", 1 << 40), ("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{n} bytes"


def _normal(path: bytes, base: bytes) -> bytes | None:
    """The absolute form of an HDF5 path (relative to group ``base``); None if it climbs."""
    parts = [] if path.startswith(b"/") else [p for p in base.split(b"/") if p]
    for p in path.split(b"/"):
        if p in (b"", b"."):
            continue
        if p == b"..":
            return None
        parts.append(p)
    return b"/" + b"/".join(parts)


def _declared(space, dtype) -> int:
    return int(space.get_simple_extent_npoints()) * int(dtype.get_size())


def check_structure(f, where: str) -> None:
    """Refuse, with one :class:`InputError` naming the object, an open HDF5 file that would
    make a reader read anything but its own bytes or allocate more than its size allows.

    Walks every link once without following any (``H5Lvisit``) and reads no data: external
    links, soft links whose target is no object of the file (or climbs out of it), user-defined
    links, virtual datasets, external storage, filters outside :data:`ALLOWED_H5_FILTERS`, more
    than :data:`MAX_H5_LINKS` links, and declared arrays and attributes beyond the budget (see
    the module docstring) are refused. ``where`` names the file in the messages.
    """
    from h5py import h5a, h5d, h5l, h5o

    links: list = []

    def visit(name, info):
        links.append((name, info.type))
        return 1 if len(links) > MAX_H5_LINKS else None

    f.id.links.visit(visit, info=True)
    if len(links) > MAX_H5_LINKS:
        raise InputError(f"expected an HDF5 file with at most {MAX_H5_LINKS} objects, got "
                         f"{where} with more")
    hard = {b"/"} | {b"/" + n for n, t in links if t == h5l.TYPE_HARD}
    soft = {}
    for name, kind in links:
        if kind == h5l.TYPE_EXTERNAL:
            filename, obj = f.id.links.get_val(name)
            raise InputError(f"expected objects stored inside {where}, got {_show(name)} as an "
                             f"external link to {_show(filename)} (object {_show(obj)})")
        if kind == h5l.TYPE_SOFT:
            soft[b"/" + name] = f.id.links.get_val(name)
        elif kind != h5l.TYPE_HARD:
            raise InputError(f"expected objects stored inside {where}, got {_show(name)} as a "
                             f"user-defined link (type {kind})")
    for name, target in soft.items():
        at = name
        for _ in range(len(soft) + 1):
            at = _normal(soft[at], at.rsplit(b"/", 1)[0]) if at in soft else at
            if at is None or at not in soft:
                break
        if at not in hard:
            raise InputError(f"expected links to objects inside {where}, got {_show(name[1:])} "
                             f"as a soft link to {_show(target)}, which names no object of "
                             f"the file")
    budget = min(max(H5_FLOOR_BYTES, MAX_H5_EXPANSION * _file_size(f)), MAX_H5_DECLARED_BYTES)
    total, largest, n_attrs = 0, (0, b""), 0
    for name in sorted(hard):
        rel = b"." if name == b"/" else name[1:]
        obj = h5o.open(f.id, rel)
        count = h5a.get_num_attrs(obj)
        n_attrs += count
        if n_attrs > MAX_H5_LINKS:
            raise InputError(f"expected an HDF5 file with at most {MAX_H5_LINKS} attributes, "
                             f"got {where} with more")
        sizes = []
        for i in range(count):
            a = h5a.open(obj, index=i)
            sizes.append((_declared(a.get_space(), a.get_type()), rel))
        if isinstance(obj, h5d.DatasetID):
            _check_storage(obj, rel, where)
            sizes.append((_declared(obj.get_space(), obj.get_type()), rel))
        for size, who in sizes:
            total += size
            largest = max(largest, (size, who))
        if total > budget:
            raise InputError(
                f"expected {where} to declare at most {_bytes_text(budget)} of arrays (its size "
                f"x {MAX_H5_EXPANSION}, at least {_bytes_text(H5_FLOOR_BYTES)}), got "
                f"{_bytes_text(total)} or more (the largest: {_show(largest[1])} with "
                f"{_bytes_text(largest[0])})")


def _file_size(f) -> int:
    try:
        return os.path.getsize(f.filename)
    except (OSError, TypeError):
        return int(f.id.get_filesize())


def _check_storage(dset, name: bytes, where: str) -> None:
    from h5py import h5d

    plist = dset.get_create_plist()
    if plist.get_layout() == h5d.VIRTUAL:
        raise InputError(f"expected datasets stored inside {where}, got {_show(name)} as a "
                         "virtual dataset (mapped from other files)")
    if plist.get_external_count():
        ext = plist.get_external(0)[0]
        raise InputError(f"expected datasets stored inside {where}, got {_show(name)} stored "
                         f"in external file {_show(ext)}")
    for i in range(plist.get_nfilters()):
        code, _flags, _values, fname = plist.get_filter(i)
        if code not in ALLOWED_H5_FILTERS:
            raise InputError(
                f"expected datasets stored with HDF5's built-in filters "
                f"({', '.join(ALLOWED_H5_FILTERS.values())}), got {_show(name)} in {where} "
                f"with filter {code} ({_show(fname)})")


def check_rows(f, where: str, n: int, shapes, *, reference: str) -> None:
    """Refuse (one line) a file in which an array of ``shapes`` that exists does not have the
    ``n`` rows of ``reference``: checked on the declared shapes, before anything is read.

    ``shapes`` maps each name to the shape of one row (``(4, 4)`` for poses; then the whole
    shape is checked) or to None (only the row count is); a sequence of names means None."""
    if not isinstance(shapes, dict):
        shapes = dict.fromkeys(shapes)
    for name, tail in shapes.items():
        d = f.get(name)
        if d is None:
            continue
        shape = getattr(d, "shape", None)
        want = f"shape {(n, *tail)}" if tail is not None else f"{n} rows"
        if shape is None:
            raise InputError(f"{where}: expected `{name}` to have {want} like `{reference}`, "
                             "got a group")
        if not shape or shape[0] != n or (tail is not None and tuple(shape[1:]) != tuple(tail)):
            raise InputError(f"{where}: expected `{name}` to have {want} like `{reference}`, "
                             f"got shape {shape}")


def committed_rows(group, keys) -> int:
    """Rows of ``group`` to read: its ``rows`` attribute (a file streamed by a live session,
    which commits its rows as it goes) capped by the lengths of the datasets ``keys``; 0 at
    least."""
    lengths = [group[k].shape[0] for k in keys if group[k].ndim >= 1]
    rows = group.attrs.get("rows")
    if rows is not None:
        lengths.append(int(rows))
    return max(min(lengths, default=0), 0)


def open_h5(path, what: str):
    """Open an HDF5 file for reading after every check of this module: a regular file
    (never a FIFO or device), a matching seal or a successful probe, and a structure that
    keeps the reader inside the file and within its budget (:func:`check_structure`).

    Returns the open ``h5py.File`` (the caller closes it). Raises ``FileNotFoundError`` for a
    missing file and one-line :class:`InputError` (``expected WHAT, got ...``) otherwise."""
    import h5py

    path = Path(path)
    check_regular(path, what)
    reason = check_readable(path)
    if reason:
        raise InputError(f"expected {what}, got {path.name}, which is damaged or not a "
                         f"readable HDF5 file ({reason})")
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise InputError(f"expected {what}, got {path.name}, which is not a readable HDF5 "
                         f"file ({' '.join(str(exc).split())[:80]})") from None
    try:
        check_structure(f, path.name)
    except BaseException:
        f.close()
        raise
    return f
