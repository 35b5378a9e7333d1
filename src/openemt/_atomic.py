"""Safe file output: write to a temporary file beside the target, then rename; never over an
input, never onto something that is not a regular file.

The guarantees (docs/robustness.md#writers lists the test of each):

* **Only regular files are replaced.** An output that exists and is not a regular file (a
  character or block device, a FIFO, a socket, a folder) is refused with one
  :class:`~openemt._errors.InputError`, and so is a symbolic-link loop and any path inside the
  installed bundled-dataset folder (``openemt.datasets``).
* **Symbolic links are written through.** An output that is a symbolic link keeps the link: the
  file it points to is replaced (as ``>`` in a shell does); the temporary file is created beside
  the link's target, so the final rename stays within one file system.
* **Short temporary names.** A temporary file is named ``.openemt-<host>-<pid>-<random><suffix>``
  (about 35 characters, whatever the target's name), so an output name may use the file
  system's whole limit (NAME_MAX, 255 bytes on Linux).
* **Durable.** The data is fsync'ed before the rename and the folder after it (where the file
  system supports it), so after a crash the target is the old file or the complete new one.
* **A full disk is one error.** ``ENOSPC``, ``EDQUOT``, ``EFBIG``, ``EIO`` and ``EROFS`` become
  one ``OSError`` such as ``disk full writing 'X'`` (the CLI prints it as one ``error:`` line,
  exit 2) and the temporary file is removed. HDF5 files are written through :func:`atomic_h5`,
  whose file object never lets the HDF5 library see a failed write (libhdf5 2.0 crashes with a
  segmentation fault when it closes a file after one).
* **Stale temporaries are cleaned.** A run killed outright (SIGKILL, power loss) cannot remove
  its temporary file; the next openemt run that writes into the same folder removes every
  openemt temporary file whose process is gone (``<host>`` is a tag of the machine and process
  namespace, so temporaries of runs on other machines sharing the folder are left alone).
  Termination by SIGTERM or Ctrl-C cleans up like any other failure (the CLI turns SIGTERM into
  an exception).
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import socket
import stat
import tempfile
import zlib
from pathlib import Path

from ._errors import InputError

__all__ = ["atomic_path", "check_output_path", "check_outputs", "file_kind", "new_temporary",
           "remove_stale_temporaries", "resolve_output"]

# the process umask, read once at import (setting it to read it is not thread-safe later)
_UMASK = os.umask(0o022)
os.umask(_UMASK)

_TMP_TAG = "openemt"
#: the installed bundled-dataset folder (openemt.datasets), never written into
_DATASETS_DIR = Path(__file__).resolve().parent / "datasets"


def _host_tag() -> str:
    """8 hex digits naming this machine and process namespace (pids are only comparable within
    one); temporaries of other machines sharing a network folder are never removed."""
    try:
        ns = os.stat("/proc/self/ns/pid").st_ino
    except OSError:
        ns = 0
    return f"{zlib.crc32(f'{socket.gethostname()}|{ns}'.encode()):08x}"


_HOST = _host_tag()
# .openemt-<host>-<pid>-<random>[.suffix]; and the longer name of earlier versions,
# .<target name>.openemt-<pid>.<random>.<suffix> (no host tag: taken as this machine's)
_TMP_RE = re.compile(rf"\.{_TMP_TAG}-([0-9a-f]{{8}})-(\d+)-[A-Za-z0-9_]+(?:\.[A-Za-z0-9]+)?\Z")
_OLD_TMP_RE = re.compile(rf"\..+\.{_TMP_TAG}-(\d+)\.[A-Za-z0-9_]+\.[A-Za-z0-9]+\Z")

# errno -> the start of the one-line message "<what> writing 'X' (<detail>; nothing was written)"
_WRITE_ERRORS = {
    errno.ENOSPC: ("disk full", "no space left on device"),
    errno.EDQUOT: ("disk quota exceeded", "no space left in your quota"),
    errno.EFBIG: ("file too large", "larger than the file system allows"),
    errno.EIO: ("input/output error", "a failing disk or network file system"),
    errno.EROFS: ("read-only file system", "the folder cannot be written"),
}


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    except OverflowError:  # not a pid this system can have
        return False
    return True


def _stale_owner(name: str) -> int | None:
    """The pid of the openemt run that made the temporary file ``name`` on this machine, or
    None if ``name`` is not such a file."""
    m = _TMP_RE.match(name)
    if m:
        return int(m.group(2)) if m.group(1) == _HOST else None
    m = _OLD_TMP_RE.match(name)
    return int(m.group(1)) if m else None


def remove_stale_temporaries(path) -> list[Path]:
    """Remove the temporary files of earlier, killed openemt runs in the folder of ``path``
    (whatever output they were writing); returns them.

    Only files named like openemt's temporaries, made on this machine by a process that no
    longer exists, are removed.
    """
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    removed = []
    with contextlib.suppress(OSError):
        for entry in os.scandir(folder):
            if not entry.name.startswith("."):
                continue
            pid = _stale_owner(entry.name)
            if pid is None or _pid_alive(pid):
                continue
            with contextlib.suppress(OSError):
                if entry.is_file(follow_symlinks=False):
                    os.unlink(entry.path)
                    removed.append(Path(entry.path))
    return removed


def file_kind(mode: int) -> str:
    """What a file of ``os.stat`` mode ``mode`` that is not a regular file is, in words."""
    for test, name in ((stat.S_ISDIR, "a folder"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def resolve_output(output, *, folder: bool = False, check_datasets: bool = True) -> Path:
    """The path an output is really written to, after refusing what must not be replaced.

    A symbolic link resolves to its target (written through, the link is kept). Refused with an
    :class:`~openemt._errors.InputError`: a symbolic-link loop, an existing path that is not a
    regular file (a folder if ``folder``), and a path inside the bundled-dataset folder.
    """
    given = Path(output)
    want = "a folder" if folder else "a regular file or a new file name"
    try:
        st = os.stat(given)
    except FileNotFoundError:
        st = None  # missing, or a link to a missing file (created through the link)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise InputError(f"expected {want} for output, got {str(given)!r}, a symbolic link "
                             "loop") from None
        if exc.errno == errno.ENAMETOOLONG:
            raise InputError(f"expected an output name within the file system's limit, got "
                             f"{str(given)!r} ({len(given.name.encode())} bytes)") from None
        if exc.errno == errno.ENOTDIR:
            raise InputError(f"expected {want} for output, got {str(given)!r}, whose folder "
                             "part is a file") from None
        raise
    if st is not None:
        ok = stat.S_ISDIR(st.st_mode) if folder else stat.S_ISREG(st.st_mode)
        if not ok:
            raise InputError(f"expected {want} for output, got {str(given)!r}, which is "
                             f"{file_kind(st.st_mode)} (not replaced)")
    real = Path(os.path.realpath(given))
    if check_datasets:
        _refuse_datasets(given, real)
    return real


def _refuse_datasets(given: Path, real: Path) -> None:
    with contextlib.suppress(OSError):
        datasets = _DATASETS_DIR.resolve()
        if real == datasets or datasets in real.parents:
            raise InputError(f"expected an output outside the installed bundled-dataset folder "
                             f"{str(datasets)!r}, got {str(given)!r}")


def _same_file(a: Path, b: Path) -> bool:
    try:
        sa, sb = a.stat(), b.stat()
    except OSError:
        return False
    return (sa.st_dev, sa.st_ino) == (sb.st_dev, sb.st_ino)


def check_output_path(output, inputs, *, folder: bool = False) -> None:
    """Refuse an output path that cannot be written safely: one of the inputs, inside an input
    folder, or one that :func:`resolve_output` refuses (a device, FIFO, socket or folder in
    place of a file, a symbolic-link loop, the bundled-dataset folder).

    The comparison with the inputs resolves symbolic links and ``..`` and compares device and
    inode, so a hard link to an input is refused too.

    Parameters
    ----------
    output : path-like
        The file (or, with ``folder``, the folder) about to be written.
    inputs : iterable of path-like
        Files and folders being read.
    folder : bool
        The output is a folder (``demo --output-dir``), not a file.

    Raises
    ------
    InputError
        Naming the output and what is wrong with it.
    """
    out = Path(output)
    out_resolved = resolve_output(out, folder=folder, check_datasets=False)
    if not folder and not out_resolved.parent.is_dir():
        raise _missing_folder(out, out_resolved.parent)
    for given in inputs:
        inp = Path(given)
        if not inp.exists():
            continue
        inp_resolved = inp.resolve()
        if _same_file(out, inp) or out_resolved == inp_resolved:
            raise InputError(f"expected an output path different from the input {str(inp)!r}, "
                             f"got the same file {str(out)!r} (it would be overwritten)")
        if inp.is_dir() and inp_resolved in out_resolved.parents:
            raise InputError(f"expected an output path outside the input folder {str(inp)!r}, "
                             f"got {str(out)!r} inside it")
    _refuse_datasets(out, out_resolved)


def check_outputs(named: dict, inputs=(), *, folders=()) -> None:
    """Check every output of one command before any work: each as :func:`check_output_path`
    does, its folder writable, and no two options naming the same file (through links too).

    Parameters
    ----------
    named : dict
        Option name (``"--log"``) -> output path; None values are skipped.
    inputs : iterable of path-like
        Files and folders being read.
    folders : iterable of str
        Options whose output is a folder (``--output-dir``), not a file.
    """
    seen: dict = {}
    for opt, given in named.items():
        if given is None:
            continue
        folder = opt in folders
        check_output_path(given, inputs, folder=folder)
        target = resolve_output(given, folder=folder, check_datasets=False)
        parent = target if folder and target.is_dir() else target.parent
        if parent.is_dir() and not os.access(parent, os.W_OK | os.X_OK):
            raise InputError(f"expected a writable folder for {opt} {str(given)!r}, got "
                             f"read-only folder {str(parent)!r}")
        for other, seen_target in seen.items():
            if seen_target == target or (target.exists() and seen_target.exists()
                                         and os.path.samefile(target, seen_target)):
                raise InputError(f"expected different files for {other} and {opt}, got "
                                 f"{str(given)!r} for both")
        seen[opt] = target


def _missing_folder(output: Path, folder: Path) -> FileNotFoundError:
    return FileNotFoundError(f"expected an existing folder for output {str(output)!r}, got "
                             f"missing folder {str(folder)!r}")


def _described(exc: OSError, tmp: str, path: Path) -> OSError:
    """The error as one line naming the user's output path instead of the temporary file."""
    code = getattr(exc, "errno", None)
    if code in _WRITE_ERRORS:
        what, detail = _WRITE_ERRORS[code]
        out = OSError(f"{what} writing {str(path)!r} ({detail}; nothing was written)")
        out.errno = code
        return out
    if tmp not in str(exc) and getattr(exc, "filename", None) != tmp:
        return exc
    reason = (exc.strerror or str(exc)).replace(tmp, str(path))
    return OSError(f"cannot write {str(path)!r}: {reason}")


def _fsync_file(path: str) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_folder(folder: Path) -> None:
    """Make a rename durable; not every file system (or platform) can sync a folder."""
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _temp_suffix(suffix: str | None) -> str:
    return suffix if suffix and re.fullmatch(r"\.[A-Za-z0-9]{1,8}", suffix) else ".tmp"


def new_temporary(path, suffix: str | None = None) -> tuple[Path, str, int]:
    """``(target, tmp, mode)`` for writing ``path``: the file to replace (a symbolic link
    resolved, see the module docstring), a new empty temporary file beside it (stale
    temporaries of killed runs removed first) and the permissions the result should get (a
    replaced file keeps its own). Used by :func:`atomic_path` and the live streams
    (:mod:`openemt.io._stream`); the caller renames or removes ``tmp``."""
    given = Path(path)
    target = resolve_output(given)
    folder = target.parent
    if not folder.is_dir():
        raise _missing_folder(given, folder)
    remove_stale_temporaries(target)
    try:
        mode = stat.S_IMODE(os.stat(target).st_mode)  # a replaced file keeps its permissions
    except OSError:
        mode = 0o666 & ~_UMASK  # the permissions a plain open() would give
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{_TMP_TAG}-{_HOST}-{os.getpid()}-",
                                   suffix=_temp_suffix(suffix), dir=folder)
    except OSError as exc:
        raise _described(exc, "", given) from None
    os.close(fd)
    return target, tmp, mode


@contextlib.contextmanager
def atomic_path(path, suffix: str | None = None):
    """Yield a temporary path in the target's folder; rename it to ``path`` on success.

    On any exception (including Ctrl-C, and SIGTERM under the CLI) the temporary file is removed
    and ``path`` is left untouched, so a failed command never leaves a partial output file. See
    the module docstring for symbolic links, refused targets, durability and full disks.
    Temporary files left in the folder by killed earlier openemt runs are removed first.
    """
    given = Path(path)
    target, tmp, mode = new_temporary(given, suffix)
    folder = target.parent
    try:
        yield Path(tmp)
        os.chmod(tmp, mode)
        _fsync_file(tmp)
        os.replace(tmp, target)
    except OSError as exc:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        described = _described(exc, tmp, given)
        if described is exc:
            raise
        raise described from None
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    _fsync_folder(folder)
