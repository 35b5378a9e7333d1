"""Opening input files so that a reader reads only a regular file of a bounded size.

Every reader of openemt goes through here before it reads a byte:

* :func:`check_regular` refuses anything that is not a regular file (a FIFO, a character or
  block device, a socket, a folder) with one line naming it; opening a FIFO for reading blocks
  until a writer appears, and a device can deliver without end;
* :func:`read_limited` opens with ``O_NONBLOCK`` (so a FIFO swapped in after the check cannot
  block the open), checks the opened file again (``fstat``), refuses a file larger than the
  limit of its format and returns its bytes (:func:`read_text`: decoded as UTF-8);
* :func:`check_text_nesting` bounds the nesting of TOML text before ``tomllib`` parses it
  (the parser recurses once per level of inline arrays and tables; JSON has its own check in
  :mod:`openemt.io._jsontext`).

The limits are module constants, listed in docs/robustness.md ("Bounded work").
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from .._atomic import file_kind
from .._errors import InputError

__all__ = ["MAX_CONFIG_BYTES", "MAX_JSON_BYTES", "MAX_TEXT_BYTES", "MAX_TOML_DEPTH",
           "check_regular", "check_text_nesting", "read_limited", "read_text", "read_toml"]

#: largest tracker description or board file (TOML/JSON) read (a shipped one is ~2 KB)
MAX_CONFIG_BYTES = 1 << 20
#: largest calibration or correction JSON file read (a thin-plate-spline correction of 100,000
#: pairs is ~15 MB)
MAX_JSON_BYTES = 64 << 20
#: largest text data file read whole (ILEMT ``.dat``, couplings CSV, pose CSV, NDI export)
MAX_TEXT_BYTES = 4 << 30
#: deepest nesting of inline arrays/tables accepted in a TOML file (openemt's need 2)
MAX_TOML_DEPTH = 32

def check_regular(path, what: str) -> os.stat_result:
    """The ``os.stat`` of ``path`` if it is a regular file (symlinks followed); otherwise
    ``FileNotFoundError`` (missing) or one-line :class:`InputError` naming what it is."""
    path = Path(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise FileNotFoundError(f"expected {what}, got missing file {str(path)!r}") from None
    except OSError as exc:
        raise InputError(f"expected {what}, got {str(path)!r} that cannot be examined "
                         f"({exc.strerror})") from None
    if not stat.S_ISREG(st.st_mode):
        raise InputError(f"expected {what} (a regular file), got {str(path)!r} which is "
                         f"{file_kind(st.st_mode)}")
    return st


def _size_text(n: int) -> str:
    for unit, scale in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{n} bytes"


def read_limited(path, what: str, max_bytes: int) -> bytes:
    """The bytes of the regular file ``path``, at most ``max_bytes`` of them.

    Opened non-blocking and checked after opening (``fstat``), so a FIFO or device put in its
    place after :func:`check_regular` is refused instead of blocking; a larger file is refused
    with one line naming the file, its size and the limit."""
    path = Path(path)
    check_regular(path, what)
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0)
    try:
        fd = os.open(path, flags)
    except FileNotFoundError:
        raise FileNotFoundError(f"expected {what}, got missing file {str(path)!r}") from None
    except OSError as exc:
        raise InputError(f"expected {what}, got {str(path)!r} that cannot be opened "
                         f"({exc.strerror})") from None
    with os.fdopen(fd, "rb") as fh:
        st = os.fstat(fh.fileno())
        if not stat.S_ISREG(st.st_mode):
            raise InputError(f"expected {what} (a regular file), got {str(path)!r} which is "
                             f"{file_kind(st.st_mode)}")
        if st.st_size > max_bytes:
            raise InputError(f"expected {what} of at most {_size_text(max_bytes)}, got "
                             f"{path.name} of {_size_text(st.st_size)}")
        data = fh.read(max_bytes + 1)
    if len(data) > max_bytes:             # grew while being read
        raise InputError(f"expected {what} of at most {_size_text(max_bytes)}, got "
                         f"{path.name} of more")
    return data


def read_text(path, what: str, max_bytes: int = MAX_TEXT_BYTES) -> str:
    """The text of :func:`read_limited` decoded as UTF-8 (a byte-order mark dropped); a byte
    that is not UTF-8 is one line naming its offset and the file."""
    try:
        return read_limited(path, what, max_bytes).decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputError(f"expected {what} (UTF-8 text), got a byte that is not UTF-8 at "
                         f"offset {exc.start} in {Path(path).name}") from None


def check_text_nesting(text: str, what: str, where: str, limit: int = MAX_TOML_DEPTH) -> None:
    """Refuse TOML text whose inline arrays/tables nest deeper than ``limit`` (one line naming
    the file); brackets inside strings and comments are ignored, ``[[table]]`` headers count
    as one level."""
    if text.count("[") + text.count("{") <= limit:
        return
    depth = deepest = 0
    quote = ""
    i, n = 0, len(text)
    while i < n:
        ch = text[i]
        if quote:
            if ch == "\n" and len(quote) == 1:     # a one-line string ends at the line end
                quote = ""
            elif ch == "\\" and quote[0] == '"':
                i += 1                              # skip the escaped character
            elif text.startswith(quote, i):
                i += len(quote) - 1
                quote = ""
        elif ch == "#":
            j = text.find("\n", i)
            i = n if j < 0 else j
            continue
        elif ch in "\"'":
            quote = ch * 3 if text.startswith(ch * 3, i) else ch
            i += len(quote)
            continue
        elif ch in "[{":
            depth += 1
            if depth > deepest:
                deepest = depth
                if deepest > limit:
                    line = text.count("\n", 0, i) + 1
                    raise InputError(f"{where}: expected {what} nested at most {limit} levels "
                                     f"deep, got deeper nesting at line {line}")
        elif ch in "]}":
            depth = max(depth - 1, 0)
        i += 1


def read_toml(path, what: str, label: str) -> dict:
    """The table of the TOML configuration file ``path`` (a regular file of at most
    :data:`MAX_CONFIG_BYTES`, nesting bounded): ``what`` names the file kind in a refusal of
    the file, ``label`` in a refusal of its nesting; bad text is one line naming the file."""
    import tomllib

    data = read_limited(path, what, MAX_CONFIG_BYTES)
    try:
        text = data.decode("utf-8")
        check_text_nesting(text, label, str(path))
        return tomllib.loads(text)
    except UnicodeDecodeError:
        raise InputError(f"{path}: expected a TOML text file, got binary data") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: expected valid TOML, got {exc}") from None
