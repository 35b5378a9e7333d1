"""Outputs that grow while a live session runs (``track --log``, ``--save-raw``).

A one-shot output is written whole under a temporary name and renamed at the end
(:func:`openemt.io.atomic_path`). A live session may run for hours and may be killed at any
moment, so its outputs are appended in chunks instead, with bounded memory:

- the file is created under a temporary name beside the target (the naming of
  :mod:`openemt._atomic`, so that the next run removes it when the session was killed
  before it held anything; a symbolic-link target is written through) and renamed to the target **when it
  first holds a row** (or at a clean end): a session stopped during start-up never replaces
  an existing file, with an empty one or otherwise;
- rows are buffered for about ``flush_seconds`` (1 s) and then appended and flushed to the
  operating system; a session killed outright (SIGKILL, out of memory) loses at most that
  last second, and the file it leaves is readable;
- HDF5 outputs hold resizable chunked datasets and, per group of equally long datasets, the
  attribute ``rows`` (the rows committed by the last flush; a reader reads no more) and, on the
  root, ``complete`` (False until the session ends cleanly);
- before each append the free space of the file system is compared with the bytes to write;
  a full disk (or an I/O error) ends the session as :class:`DiskFullError` ("disk full writing
  X", exit 2 in the CLI) with the rows flushed so far readable. libhdf5 writes through the
  guarded file object of the one-shot writers (:class:`openemt.io._h5write.GuardedFile`): a
  failed write never reaches the library, so closing the file cannot crash inside it.
"""

from __future__ import annotations

import contextlib
import os
import time
from pathlib import Path

import numpy as np

from .._atomic import (
    _WRITE_ERRORS,
    _fsync_file,
    _fsync_folder,
    new_temporary,
)
from .._errors import InputError
from ._h5write import GuardedFile

__all__ = ["CsvStream", "DiskFullError", "H5Stream"]

#: free space kept beyond the bytes of a flush (HDF5 metadata, chunk rounding)
_HEADROOM = 256 * 1024


class DiskFullError(OSError):
    """A streaming output could not be written (no space left, quota, I/O error); the rows
    flushed before stay readable."""


class _Stream:
    """The temporary name, the rename when rows first arrive, the flush cadence and the
    disk-space check shared by the HDF5 and CSV streams."""

    def __init__(self, path, suffix: str, *, flush_seconds: float = 1.0,
                 max_buffered_bytes: int = 64 << 20):
        self.path = Path(path)
        # the target (a symbolic link written through), a temporary file beside it named as
        # every openemt temporary (cleaned by the next run when this one is killed early)
        self.target, tmp, mode = new_temporary(self.path, suffix)
        os.chmod(tmp, mode)
        self.tmp = Path(tmp)
        self.folder = self.target.parent
        self.flush_seconds = float(flush_seconds)
        self.max_buffered_bytes = int(max_buffered_bytes)
        self.published = False
        self.closed = False
        self.rows = 0                     # rows committed (flushed) so far
        self._buffered_bytes = 0
        # the flush clock starts with the first row, not at creation: start-up before the
        # first sample (loading the solver's kernels) must not make the first flush come at once
        self._last_flush = None
        # a stream whose rows must be committed no later than this one's (the raw recording
        # behind a track log): flushed first whenever this one flushes
        self.flush_first = None

    # -- to be provided by subclasses: _write_buffered() -> rows added, _sync(), _close_file()
    def _publish(self) -> None:
        if not self.published:
            _fsync_file(self.tmp)
            os.replace(self.tmp, self.target)
            _fsync_folder(self.folder)
            self.published = True

    def _check_space(self, nbytes: int) -> None:
        try:
            st = os.statvfs(self.folder)
        except OSError:
            return
        if st.f_bavail * st.f_frsize < 2 * nbytes + _HEADROOM:
            raise DiskFullError(f"disk full writing {str(self.path)!r} ({self._kept()})")

    def _kept(self) -> str:
        return (f"{self.rows} rows written, readable" if self.rows and self.published
                else "nothing written")

    def _disk_error(self, exc) -> DiskFullError:
        err = getattr(self, "_guard", None)
        err = err.error if err is not None and err.error is not None else exc
        # the one-shot writers' wording for the same errors ("disk full", "input/output
        # error", ...), with what the stream kept instead of "nothing was written"
        what = _WRITE_ERRORS.get(getattr(err, "errno", None), ("cannot write",))[0]
        return DiskFullError(f"{what} writing {str(self.path)!r} ({self._kept()})")

    def maybe_flush(self) -> None:
        """Flush when ``flush_seconds`` have passed since the last flush (or the first row) or
        the buffer is large."""
        now = time.monotonic()
        if self._last_flush is None:
            if not self._buffered_bytes:
                return
            self._last_flush = now
        if (self._buffered_bytes >= self.max_buffered_bytes
                or now - self._last_flush >= self.flush_seconds):
            self.flush()

    def flush(self) -> None:
        """Append the buffered rows to the file and hand them to the operating system."""
        first = self.flush_first
        if first is not None and not first.closed:
            first.flush()
        self._last_flush = time.monotonic()
        if not self._buffered_bytes:
            return
        self._check_space(self._buffered_bytes)
        try:
            added = self._write_buffered()
        except DiskFullError:
            raise
        except (OSError, RuntimeError, ValueError) as exc:
            self._fail()
            raise self._disk_error(exc) from None
        self._buffered_bytes = 0
        self.rows += added
        if self.rows:
            self._publish()

    def close(self, *, keep_empty: bool = True) -> None:
        """Flush, mark the file complete and close it. The target is replaced by the file
        when it holds rows, or when ``keep_empty`` (a clean end); otherwise the temporary
        file is removed and an existing target kept."""
        if self.closed:
            return
        try:
            self.flush()
            self._finish()
        except DiskFullError:
            self._fail()
            self.discard()                # nothing published: no temporary file left either
            raise
        except (OSError, RuntimeError, ValueError) as exc:
            self._fail()
            self.discard()
            raise self._disk_error(exc) from None
        self.closed = True
        if self.rows or keep_empty:
            self._publish()
        else:
            self.discard()

    def abort(self) -> None:
        """Stop after an error: what is buffered is flushed when the file still takes it, the
        file is closed without being marked complete; a file that never held a row is
        removed (an existing target is left as it was)."""
        if self.closed:
            return
        with contextlib.suppress(Exception):
            if self._buffered_bytes:
                self.flush()
        self._fail()
        if not self.published:
            self.discard()

    def discard(self) -> None:
        with contextlib.suppress(OSError):
            if not self.published:
                os.unlink(self.tmp)

    def _fail(self) -> None:
        self.closed = True
        with contextlib.suppress(Exception):
            self._close_file()

    def __enter__(self):
        return self

    def __exit__(self, typ, exc, tb):
        if typ is None:
            self.close()
        else:
            self.abort()


class H5Stream(_Stream):
    """An HDF5 file of resizable datasets appended in chunks (see the module docstring).

    Parameters
    ----------
    path : path-like
        Target file.
    attrs : dict
        Root attributes (``complete`` and ``rows`` are added).
    chunk_rows : int or dict
        Rows per HDF5 chunk (per group name when a dict; default 1500).
    flush_seconds : float
        Seconds between flushes.

    Datasets are created at the first :meth:`append` to their group, with the trailing shape
    and dtype of the arrays given; every dataset of a group must grow by the same rows.
    """

    def __init__(self, path, attrs: dict | None = None, *, chunk_rows=1500,
                 flush_seconds: float = 1.0, max_buffered_bytes: int = 64 << 20):
        import h5py

        super().__init__(path, ".h5", flush_seconds=flush_seconds,
                         max_buffered_bytes=max_buffered_bytes)
        self.chunk_rows = chunk_rows
        # libhdf5 writes through the guard of the one-shot writers (openemt.io._h5write): a
        # failed write is kept there, never seen by the library, and raised by check()
        self._fd = os.open(self.tmp, os.O_RDWR)
        self._guard = GuardedFile(self._fd, str(self.path))
        try:
            self._f = h5py.File(self._guard, "w")
            for k, v in (attrs or {}).items():
                self._f.attrs[k] = v
            self._f.attrs["complete"] = False
            self._f.flush()
            self._guard.check()
        except OSError as exc:
            self._fail()
            self.discard()
            raise self._disk_error(exc) from None
        except BaseException:
            self._fail()
            self.discard()
            raise
        self._groups: dict = {}       # group name -> {dataset name: list of arrays}
        self._group_rows: dict = {}

    def group_attrs(self, group: str, attrs: dict) -> None:
        """Set attributes of a group (created if needed)."""
        g = self._f.require_group(group) if group not in ("", "/") else self._f
        for k, v in attrs.items():
            g.attrs[k] = v

    def append(self, group: str, arrays: dict) -> None:
        """Buffer rows of every dataset of ``group`` ("/" for the root)."""
        buf = self._groups.get(group)
        if buf is None:
            buf = self._groups[group] = {k: [] for k in arrays}
            self._group_rows[group] = 0
        n = None
        for k, v in arrays.items():
            v = np.asarray(v)
            if n is None:
                n = v.shape[0]
            elif v.shape[0] != n:
                raise InputError(f"expected {n} rows for every dataset of {group!r}, got "
                                 f"{v.shape[0]} for {k!r}")
            buf[k].append(v)
            self._buffered_bytes += v.nbytes

    def _chunk(self, group) -> int:
        c = self.chunk_rows
        return int(c.get(group, 1500) if isinstance(c, dict) else c)

    def _write_buffered(self) -> int:
        f = self._f
        added = {}
        for group, buf in self._groups.items():
            g = f.require_group(group) if group not in ("", "/") else f
            n_new = None
            for k, parts in buf.items():
                if not parts:
                    continue
                data = np.concatenate(parts) if len(parts) > 1 else parts[0]
                if k not in g:
                    g.create_dataset(k, shape=(0,) + data.shape[1:],
                                     maxshape=(None,) + data.shape[1:], dtype=data.dtype,
                                     chunks=(self._chunk(group),) + data.shape[1:])
                ds = g[k]
                n0 = self._group_rows[group]
                ds.resize(n0 + data.shape[0], axis=0)
                ds[n0:] = data
                n_new = data.shape[0]
                parts.clear()
            if n_new:
                added[group] = n_new
        f.flush()                                    # the data, then the committed counts
        self._guard.check()                          # a failed write: the counts stay
        for group, n_new in added.items():
            self._group_rows[group] += n_new
            g = f[group] if group not in ("", "/") else f
            g.attrs["rows"] = self._group_rows[group]
        f.flush()
        self._guard.check()
        return max(added.values(), default=0)

    def group_rows(self, group: str) -> int:
        """Rows of ``group`` committed so far."""
        return self._group_rows.get(group, 0)

    def _finish(self) -> None:
        for group in self._groups:
            g = self._f[group] if group not in ("", "/") else self._f
            g.attrs["rows"] = self._group_rows[group]
        self._f.attrs["complete"] = True
        self._f.close()
        self._guard.check()
        with contextlib.suppress(OSError):
            os.fsync(self._fd)
        os.close(self._fd)
        self._fd = None

    def _close_file(self) -> None:
        with contextlib.suppress(Exception):
            self._f.close()
        if self._fd is not None:
            with contextlib.suppress(OSError):
                os.close(self._fd)
            self._fd = None


class CsvStream(_Stream):
    """A text file appended line by line (a header first). A CSV file cannot say whether its
    session ended cleanly; a line torn by a kill is dropped by the readers."""

    def __init__(self, path, header: str, *, flush_seconds: float = 1.0,
                 max_buffered_bytes: int = 64 << 20):
        super().__init__(path, ".csv", flush_seconds=flush_seconds,
                         max_buffered_bytes=max_buffered_bytes)
        self._fh = open(self.tmp, "w", encoding="utf-8")  # noqa: SIM115 - closed in close()
        self._parts: list = [header.rstrip("\n") + "\n"]
        self._n_rows = 0
        self._buffered_bytes = len(self._parts[0])

    def append(self, text: str, rows: int) -> None:
        """Buffer ``rows`` lines of text (each ending with a newline)."""
        self._parts.append(text)
        self._n_rows += int(rows)
        self._buffered_bytes += len(text)

    def _write_buffered(self) -> int:
        self._fh.write("".join(self._parts))
        self._fh.flush()
        self._parts = []
        n, self._n_rows = self._n_rows, 0
        return n

    def _finish(self) -> None:
        self._fh.flush()
        with contextlib.suppress(OSError):
            os.fsync(self._fh.fileno())
        self._fh.close()

    def _close_file(self) -> None:
        with contextlib.suppress(Exception):
            self._fh.close()
