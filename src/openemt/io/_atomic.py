"""Safe file output: write to a temporary file beside the target, then rename; never over an
input.

A temporary file is named ``.<target name>.openemt-<pid>.<random>.tmp``. A run that is killed
outright (SIGKILL, power loss) cannot remove it; the next run writing the same target
recognises such a file by its name and removes it when the process that made it is gone.
Termination by SIGTERM or Ctrl-C cleans up like any other failure (the CLI turns SIGTERM into
an exception).
"""

from __future__ import annotations

import contextlib
import os
import re
import tempfile
from pathlib import Path

from .._errors import InputError

__all__ = ["atomic_path", "check_output_path", "remove_stale_temporaries"]

# the process umask, read once at import (setting it to read it is not thread-safe later)
_UMASK = os.umask(0o022)
os.umask(_UMASK)

_TMP_TAG = "openemt"


def _tmp_pattern(name: str) -> re.Pattern:
    return re.compile(re.escape(f".{name}.{_TMP_TAG}-") + r"(\d+)\.[A-Za-z0-9_]+\.[A-Za-z0-9]+\Z")


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True


def remove_stale_temporaries(path) -> list[Path]:
    """Remove temporary files of earlier, killed runs that wrote ``path``; returns them."""
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    pattern = _tmp_pattern(path.name)
    removed = []
    with contextlib.suppress(OSError):
        for entry in os.scandir(folder):
            m = pattern.match(entry.name)
            if m and not _pid_alive(int(m.group(1))):
                with contextlib.suppress(OSError):
                    os.unlink(entry.path)
                    removed.append(Path(entry.path))
    return removed


def _same_file(a: Path, b: Path) -> bool:
    try:
        sa, sb = a.stat(), b.stat()
    except OSError:
        return False
    return (sa.st_dev, sa.st_ino) == (sb.st_dev, sb.st_ino)


def check_output_path(output, inputs) -> None:
    """Refuse an output path that is one of the inputs or lies inside an input folder.

    The comparison resolves symbolic links and ``..`` and compares device and inode, so a hard
    link to an input is refused too.

    Parameters
    ----------
    output : path-like
        The file (or folder) about to be written.
    inputs : iterable of path-like
        Files and folders being read.

    Raises
    ------
    InputError
        Naming the output and the input it would destroy.
    """
    out = Path(output)
    out_resolved = out.resolve()
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


def _renamed(exc: OSError, tmp: str, path: Path) -> OSError:
    """The error, naming the user's output path instead of the temporary file."""
    if tmp not in str(exc) and getattr(exc, "filename", None) != tmp:
        return exc
    reason = (exc.strerror or str(exc)).replace(tmp, str(path))
    return OSError(f"cannot write {str(path)!r}: {reason}")


@contextlib.contextmanager
def atomic_path(path, suffix: str | None = None):
    """Yield a temporary path in the target's folder; rename it to ``path`` on success.

    On any exception (including Ctrl-C, and SIGTERM under the CLI) the temporary file is removed
    and ``path`` is left untouched, so a failed command never leaves a partial output file.
    Temporary files left by killed earlier runs for the same target are removed first.
    """
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise FileNotFoundError(f"expected an existing folder for output {str(path)!r}, "
                                f"got missing folder {str(folder)!r}")
    if path.is_dir():
        raise IsADirectoryError(f"expected a file path for output, got the folder {str(path)!r}")
    remove_stale_temporaries(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{_TMP_TAG}-{os.getpid()}.",
                                   suffix=suffix or ".tmp", dir=folder)
    except OSError as exc:
        raise OSError(f"cannot write {str(path)!r}: {exc.strerror or exc}") from None
    os.close(fd)
    try:
        yield Path(tmp)
        # mkstemp creates the file 0600; give the result the permissions a plain open() would
        os.chmod(tmp, 0o666 & ~_UMASK)
        os.replace(tmp, path)
    except OSError as exc:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        renamed = _renamed(exc, tmp, path)
        if renamed is exc:
            raise
        raise renamed from None
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
