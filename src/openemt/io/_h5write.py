"""HDF5 output that a full disk cannot crash: the file object libhdf5 writes through
(:class:`GuardedFile`) and the atomic HDF5 writer built on :func:`openemt._atomic.atomic_path`
(docs/robustness.md#writers)."""

from __future__ import annotations

import contextlib
import os

from .._atomic import atomic_path

__all__ = ["GuardedFile", "atomic_h5", "atomic_h5_layout", "contiguous_dataset",
           "raise_if_write_failed", "write_at"]


class GuardedFile:
    """A binary file object for the HDF5 library (h5py's ``fileobj`` driver) that never lets a
    failed write reach it.

    libhdf5 (2.0) crashes with a segmentation fault when it closes a file after a failed write
    (a full disk), so this object absorbs the failure: the first ``OSError`` of a write is kept
    in :attr:`error`, and from then on written bytes are kept in memory (so that what the
    library reads back is what it wrote) instead of going to the disk. The owner calls
    :meth:`check` after closing the HDF5 file (and, when streaming, after each block, so that a
    full disk stops a long write early) and discards the file when it raises.

    In the normal case every write goes straight to the disk (``os.pwrite``): memory does not
    grow with the file. Usable for any HDF5 output, atomic (:func:`atomic_h5`) or appended to
    in place.
    """

    def __init__(self, fd: int, name: str = ""):
        self._fd = fd
        self.name = name
        self._pos = 0
        self._size = os.fstat(fd).st_size
        self.error: OSError | None = None
        self._kept: list[tuple[int, bytes]] = []  # (offset, bytes) written after a failure

    # the subset of the io API that h5py's fileobj driver uses
    def tell(self) -> int:
        return self._pos

    def seek(self, offset: int, whence: int = os.SEEK_SET) -> int:
        base = {os.SEEK_SET: 0, os.SEEK_CUR: self._pos, os.SEEK_END: self._size}[whence]
        self._pos = base + offset
        return self._pos

    def readinto(self, buf) -> int:
        view = memoryview(buf).cast("B")
        n = max(0, min(len(view), self._size - self._pos))
        data = b""
        if n:
            try:
                data = os.pread(self._fd, n, self._pos)
            except OSError as exc:
                self._fail(exc)
        view[:len(data)] = data
        view[len(data):n] = bytes(n - len(data))
        for off, kept in self._kept:  # bytes that could not be written, in write order
            lo, hi = max(off, self._pos), min(off + len(kept), self._pos + n)
            if lo < hi:
                view[lo - self._pos:hi - self._pos] = kept[lo - off:hi - off]
        self._pos += n
        return n

    def read(self, n: int = -1) -> bytes:
        n = self._size - self._pos if n is None or n < 0 else n
        buf = bytearray(n)
        got = self.readinto(buf)
        return bytes(buf[:got])

    def write(self, data) -> int:
        view = memoryview(data).cast("B")
        n = len(view)
        if self.error is None:
            try:
                done = 0
                while done < n:
                    done += os.pwrite(self._fd, view[done:], self._pos + done)
            except OSError as exc:
                self._fail(exc)
        if self.error is not None:
            self._kept.append((self._pos, bytes(view)))
        self._pos += n
        self._size = max(self._size, self._pos)
        return n

    def truncate(self, size: int | None = None) -> int:
        size = self._pos if size is None else int(size)
        if self.error is None:
            try:
                os.ftruncate(self._fd, size)
            except OSError as exc:
                self._fail(exc)
        self._size = size
        return size

    def flush(self) -> None:
        pass

    def _fail(self, exc: OSError) -> None:
        if self.error is None:
            self.error = exc

    def check(self) -> None:
        """Raise the first write error, if any (as an ``OSError`` with its errno)."""
        if self.error is not None:
            code = self.error.errno
            raise OSError(code, os.strerror(code) if code else str(self.error), self.name)


#: id(h5py.File) -> its GuardedFile, while the file is open in :func:`atomic_h5`
_GUARDS: dict[int, GuardedFile] = {}


def raise_if_write_failed(h5file) -> None:
    """For streaming writers: raise now if a write into ``h5file`` (opened by
    :func:`atomic_h5`) has failed, so that a full disk ends a long write at once instead of
    at its end. A file not opened by :func:`atomic_h5` passes."""
    guard = _GUARDS.get(id(h5file))
    if guard is not None:
        guard.check()


@contextlib.contextmanager
def _guarded_h5(tmp, path, **h5_options):
    """A new ``h5py.File`` at ``tmp`` written through a :class:`GuardedFile` (errors named after
    ``path``): closed at the end of the block, then its first write error raised."""
    import h5py

    fd = os.open(tmp, os.O_RDWR)
    try:
        guard = GuardedFile(fd, str(path))
        f = h5py.File(guard, "w", **h5_options)
        _GUARDS[id(f)] = guard
        try:
            yield f
        finally:
            _GUARDS.pop(id(f), None)
            f.close()  # cannot fail on I/O: the guard keeps the error
        guard.check()
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_h5(path, *, seal: bool = False, **h5_options):
    """Yield a new ``h5py.File`` that becomes ``path`` on success (see :func:`atomic_path`).

    The HDF5 library writes through a :class:`GuardedFile`, so a full disk or an I/O error is
    one ``OSError`` (``disk full writing 'X'``) with the temporary file removed, never a crash
    inside the library. ``seal``: write openemt's CRC seal after closing (needs
    ``userblock_size=SEAL_SIZE``, see :mod:`openemt.io._h5safe`). ``h5_options`` go to
    ``h5py.File`` (``libver``, ``userblock_size``, ...).
    """
    with atomic_path(path, suffix=".h5") as tmp:
        with _guarded_h5(tmp, path, **h5_options) as f:
            yield f
        if seal:
            from ._h5safe import seal as write_seal
            write_seal(tmp)


def contiguous_dataset(group, name: str, shape: tuple, dtype, units: str | None = None):
    """Create a contiguous dataset whose storage is allocated now and never filled by the
    library: the bytes of its rows lie at one known offset of the file, so other processes
    can write them (:func:`write_at`). Returns ``(dataset, offset)`` (offset None when the
    dataset is empty)."""
    import h5py
    import numpy as np

    dtype = np.dtype(dtype).newbyteorder("<") if np.dtype(dtype).itemsize > 1 \
        else np.dtype(dtype)
    dcpl = h5py.h5p.create(h5py.h5p.DATASET_CREATE)
    dcpl.set_alloc_time(h5py.h5d.ALLOC_TIME_EARLY)
    dcpl.set_fill_time(h5py.h5d.FILL_TIME_NEVER)
    space = h5py.h5s.create_simple(tuple(int(d) for d in shape))
    dsid = h5py.h5d.create(group.id, name.encode(), h5py.h5t.py_create(dtype), space,
                           dcpl=dcpl)
    ds = h5py.Dataset(dsid)
    if units is not None:
        ds.attrs["units"] = units
    return ds, (dsid.get_offset() if int(np.prod(shape)) else None)


@contextlib.contextmanager
def atomic_h5_layout(path, build, **h5_options):
    """An HDF5 file laid out now and filled later, by this or other processes, at known
    offsets: yields ``(tmp, layout)``, where ``layout = build(f)`` is what ``build`` returned
    after creating the file's objects in the new ``h5py.File`` ``f`` (typically with
    :func:`contiguous_dataset`), and ``tmp`` the closed temporary file the writers fill with
    :func:`write_at`. The file becomes ``path`` when the block ends without an exception
    (:func:`openemt._atomic.atomic_path`: no partial file otherwise). The layout itself is
    written through a :class:`GuardedFile` as in :func:`atomic_h5`."""
    with atomic_path(path, suffix=".h5") as tmp:
        with _guarded_h5(tmp, path, **h5_options) as f:
            layout = build(f)
        yield tmp, layout


def write_at(path, offset: int, data) -> None:
    """Write the bytes of the array ``data`` (C order) at ``offset`` of the existing file
    ``path`` (an :func:`atomic_h5_layout` temporary). A failed write is one ``OSError``
    with its errno (a full disk: ``ENOSPC``), so the owner of the file can discard it."""
    import numpy as np

    view = memoryview(np.ascontiguousarray(data)).cast("B")
    fd = os.open(path, os.O_WRONLY)
    try:
        done = 0
        while done < len(view):
            done += os.pwrite(fd, view[done:], offset + done)
    finally:
        os.close(fd)
