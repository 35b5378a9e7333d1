"""ILEMT ``.dat`` logger files: reader, stage-error compensation, sign flips, folder import.

The file format, the fixture naming, the sign-flip rule and the stage compensation follow
docs/ilemt-data.md#dat-format to docs/ilemt-data.md#stage-compensation (MacLachlan et al. 2025, MacLachlan et al. 2025).
"""

from __future__ import annotations

import hashlib
import re
import warnings
from pathlib import Path

import numpy as np

from .. import __version__
from .._errors import InputError
from ..geometry import fixture_axes
from ._dataset import Dataset
from ._namepattern import compile_name_pattern
from ._safefile import MAX_CONFIG_BYTES, MAX_TEXT_BYTES, check_regular, read_limited

__all__ = [
    "ILEMT_NAME_RE",
    "compensate_stage",
    "file_sha256",
    "import_ilemt_folder",
    "parse_ilemt_name",
    "parse_sign_options",
    "read_ilemt_dat",
    "resolve_signs",
]

#: File-name rule of the ILEMT tools: source code, sensor code, pattern (greedy, unanchored).
ILEMT_NAME_RE = re.compile(r"so(.*)_se(.*)_(.*)\.dat")

#: Null-row drift threshold on max |C_first - C_last| (complex, elementwise).
DRIFT_LIMIT = 1e-4

_N_FIELDS = 24

# -- number syntax -------------------------------------------------------------------------
_UNUM = r"(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?"
_NUM = r"[+-]?" + _UNUM
_REAL = f"({_NUM})"
_CPLX = f"({_NUM})(?:([+-]{_UNUM})i)?"     # "%g" files omit a zero imaginary part
_SEP = r"(?:[ \t]*,[ \t]*|[ \t]+)"
_LINE_RE = re.compile(r"[ \t]*" + _SEP.join([_REAL] * 6 + [_CPLX] * 18) + r"[ \t,]*")
_REAL_TOKEN_RE = re.compile(_NUM)
_CPLX_TOKEN_RE = re.compile(_CPLX)

# -- stage compensation tables (docs/ilemt-data.md#stage-compensation): from-axis position mm -> error mm -------
_TABLE_ZX = ((50, 0.100), (40, 0.088), (30, 0.085), (20, 0.085), (10, 0.070), (0, 0.050),
             (-10, 0.025), (-20, -0.010), (-30, -0.050), (-40, -0.108), (-46, -0.140))
_TABLE_ZZ = ((49, -0.130), (29, -0.115), (4, -0.090), (-21, -0.050), (-46, 0.000))
_TABLE_XX = ((50, 0.000), (25, 0.040), (0, 0.040), (-25, 0.050), (-50, 0.155))
_TABLE_YY = ((50, 0.000), (25, -0.130), (0, -0.200), (-5, -0.230), (-10, -0.235),
             (-15, -0.255), (-20, -0.257), (-25, -0.310), (-50, -0.350))


def _interp_extrap(x: np.ndarray, table) -> np.ndarray:
    """Piecewise-linear lookup with linear extrapolation by the end segments."""
    t = np.asarray(sorted(table), dtype=np.float64)
    xp, fp = t[:, 0], t[:, 1]
    y = np.interp(x, xp, fp)
    lo = x < xp[0]
    hi = x > xp[-1]
    if np.any(lo):
        s = (fp[1] - fp[0]) / (xp[1] - xp[0])
        y[lo] = fp[0] + s * (x[lo] - xp[0])
    if np.any(hi):
        s = (fp[-1] - fp[-2]) / (xp[-1] - xp[-2])
        y[hi] = fp[-1] + s * (x[hi] - xp[-1])
    return y


def _table_delta(x: np.ndarray, table) -> np.ndarray:
    return _interp_extrap(x, table) - _interp_extrap(np.zeros(1), table)[0]


def compensate_stage(stage_mm_deg) -> np.ndarray:
    """Add the measured ILEMT stage errors to logged stage vectors (docs/ilemt-data.md#stage-compensation).

    Parameters
    ----------
    stage_mm_deg : array_like, shape (N, 6) or (6,)
        Logged stage vectors ``[x, y, z, a, b, c]`` in **mm and degrees**, as in the files.

    Returns
    -------
    ndarray, shape like the input
        Compensated stage vectors, still in mm and degrees. The null pose stays exactly zero;
        the rotation columns are unchanged.

    Notes
    -----
    Four lookup tables (Z->X, Z->Z, X->X, Y->Y) are interpolated linearly, extrapolated
    linearly by their end segments, and referenced to their value at 0. The XY error is
    rotated by the stage Rz (column 6) before it is added, as the original tools do.
    """
    s = np.asarray(stage_mm_deg, dtype=np.float64)
    if s.ndim not in (1, 2) or s.shape[-1] != 6:
        raise InputError(f"expected `stage_mm_deg` to have shape (N, 6) or (6,), got {s.shape}")
    if not np.all(np.isfinite(s)):
        raise InputError("expected finite `stage_mm_deg`, got NaN or inf")
    one = s.ndim == 1
    s2 = np.atleast_2d(s)
    x, y, z, c = s2[:, 0], s2[:, 1], s2[:, 2], np.deg2rad(s2[:, 5])
    ex = _table_delta(z, _TABLE_ZX) + _table_delta(x, _TABLE_XX)
    ey = _table_delta(y, _TABLE_YY)
    ez = _table_delta(z, _TABLE_ZZ)
    cos, sin = np.cos(c), np.sin(c)
    out = s2.copy()
    out[:, 0] = x + cos * ex - sin * ey
    out[:, 1] = y + sin * ex + cos * ey
    out[:, 2] = z + ez
    return out[0] if one else out


def _stage_si(stage_mm_deg: np.ndarray) -> np.ndarray:
    out = np.empty_like(stage_mm_deg)
    out[:, :3] = stage_mm_deg[:, :3] * 1e-3
    out[:, 3:] = np.deg2rad(stage_mm_deg[:, 3:])
    return out


# -- file names and hashes -------------------------------------------------------------------
def parse_ilemt_name(name: str) -> tuple[str, str, str] | None:
    """``so<SRC>_se<SEN>_<pattern>.dat`` -> ``(SRC, SEN, pattern)``, or None if it does not match."""
    m = ILEMT_NAME_RE.search(Path(name).name)
    return None if m is None else (m.group(1), m.group(2), m.group(3))


def file_sha256(path) -> str:
    """SHA-256 hex digest of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


# -- sign options ------------------------------------------------------------------------------
def _strip_matlab_comments(text: str) -> str:
    """Remove ``%{ ... %}`` block comments and ``%`` line comments (quotes respected)."""
    out_lines = []
    depth = 0
    for line in text.splitlines():
        stripped = line.strip()
        if stripped == "%{":
            depth += 1
            continue
        if stripped == "%}" and depth:
            depth -= 1
            continue
        if depth:
            continue
        kept = []
        in_str = False
        for i, ch in enumerate(line):
            if ch == "'":
                # a quote opens a string unless it follows an identifier/closing bracket (transpose)
                prev = line[i - 1] if i else " "
                if in_str or not (prev.isalnum() or prev in "_)]}.'"):
                    in_str = not in_str
            elif ch == "%" and not in_str:
                break
            kept.append(ch)
        out_lines.append("".join(kept))
    return "\n".join(out_lines)


_ENTRY_RE = re.compile(r"'((?:[^']|'')*)'\s*,?\s*\[([^\]]*)\]")


def _one_line(text: str, limit: int = 40) -> str:
    """A cell's text for an error message: its whitespace (line breaks included: a bracket may
    span lines) collapsed to single spaces, at most ``limit`` characters."""
    return " ".join(text.split())[:limit]


def _parse_sign_cell(body: str, what: str, path) -> list[tuple[str, tuple[float, ...]]]:
    entries = []
    pos = 0
    for m in [*_ENTRY_RE.finditer(body), None]:     # None: the text after the last entry
        gap = body[pos:m.start() if m else None]
        if gap.replace("...", "").strip(" \t\r\n,;"):
            raise InputError(f"{path}: expected `options.{what} = {{ 'regex' [s s s] ... }}`, "
                             f"got unparsable text {gap.strip()[:40]!r}")
        if m is None:
            return entries
        pos = m.end()
        regex = m.group(1).replace("''", "'")
        try:
            compile_name_pattern(regex)
        except InputError as exc:
            raise InputError(f"{path}: `options.{what}`: {exc}") from None
        try:
            signs = tuple(float(v) for v in m.group(2).replace(",", " ").split())
        except ValueError:
            raise InputError(f"{path}: expected numeric signs in `options.{what}`, "
                             f"got [{_one_line(m.group(2))}]") from None
        if not signs or any(s not in (-1.0, 1.0) for s in signs):
            raise InputError(f"{path}: expected signs of +1/-1 in `options.{what}`, "
                             f"got [{_one_line(m.group(2))}]")
        entries.append((regex, signs))


def parse_sign_options(path) -> tuple[list[tuple[str, tuple[float, ...]]],
                                      list[tuple[str, tuple[float, ...]]]]:
    """Read ``options.source_signs`` / ``options.sensor_signs`` from an ILEMT options file.

    Only the cell construct ``options.source_signs = { 'regex' [s s s] ... };`` is understood
    (``%`` and ``%{ ... %}`` comments and ``...`` continuations are allowed). A missing
    assignment gives an empty list.

    Returns
    -------
    source_signs, sensor_signs : list of (regex, signs)
        In file order; the first pattern found by ``re.search`` in a file name applies.
    """
    path = Path(path)
    try:
        text = read_limited(path, "an ILEMT options file", MAX_CONFIG_BYTES).decode(
            "utf-8", errors="replace")
    except OSError as exc:
        raise OSError(f"expected a readable ILEMT options file, got {path}: {exc.strerror}") from None
    text = _strip_matlab_comments(text)
    result = []
    for what in ("source_signs", "sensor_signs"):
        found = list(re.finditer(r"options\s*\.\s*" + what + r"\s*=\s*", text))
        if not found:
            result.append([])
            continue
        rest = text[found[-1].end():]          # the last assignment wins, as in MATLAB
        if not rest.startswith("{"):
            raise InputError(f"{path}: expected `options.{what} = {{ 'regex' [s s s] ... }}`, "
                             f"got `options.{what} = {rest[:30].strip()!r}...`")
        end = rest.find("}")
        if end < 0:
            raise InputError(f"{path}: expected a closing '}}' for `options.{what}`, got end of file")
        result.append(_parse_sign_cell(rest[1:end], what, path))
    return result[0], result[1]


def _check_sign_list(signs, name: str, n: int) -> list[tuple[str, np.ndarray]]:
    if signs is None:
        return []
    out = []
    for item in signs:
        try:
            regex, s = item
        except (TypeError, ValueError):
            raise TypeError(f"expected `{name}` entries (regex, (s1, ..., s{n})), got {item!r}") from None
        if not isinstance(regex, str):
            raise TypeError(f"expected a regex string in `{name}`, got {type(regex).__name__}")
        try:
            compile_name_pattern(regex)
        except InputError as exc:
            raise InputError(f"`{name}`: {exc}") from None
        s = np.asarray(s, dtype=np.float64)
        if s.shape != (n,) or not np.all(np.abs(s) == 1.0):
            raise InputError(f"expected {n} signs of +1/-1 for {regex!r} in `{name}`, got {s.tolist()}")
        out.append((regex, s))
    return out


def resolve_signs(name: str, signs) -> np.ndarray:
    """Sign vector for a file name: the first ``(pattern, signs)`` whose pattern is found in the
    name (``re.search`` semantics, matched by the linear-time :mod:`._namepattern`), else all
    ones (length 3)."""
    for regex, s in signs:
        if compile_name_pattern(regex).search(name):
            return np.asarray(s, dtype=np.float64)
    return np.ones(3)


def _folder_signs(folder: Path):
    opt = folder / "local_cal_options.m"
    if opt.exists():                    # a FIFO or device there is refused, not skipped
        return parse_sign_options(opt)
    return [], []


# -- the .dat reader ---------------------------------------------------------------------------
def _line_error(path: Path, lineno: int, line: str) -> InputError:
    fields = [f for f in re.split(r"[ \t]*,[ \t]*|[ \t]+", line.strip()) if f != ""]
    if len(fields) != _N_FIELDS:
        return InputError(f"{path.name}: line {lineno}: expected {_N_FIELDS} fields, got {len(fields)}")
    for k, tok in enumerate(fields):
        ok = (_REAL_TOKEN_RE.fullmatch(tok) if k < 6 else _CPLX_TOKEN_RE.fullmatch(tok))
        if ok is None:
            kind = "a real number" if k < 6 else "a complex number a+bi or a"
            return InputError(f"{path.name}: line {lineno}: field {k + 1}: expected {kind}, "
                              f"got {tok[:40]!r}")
    return InputError(f"{path.name}: line {lineno}: expected {_N_FIELDS} numeric fields, "
                      f"got unparsable line")


def _parse_dat(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """-> stage (N, 6) mm/deg as logged, hr (N, 3, 3) complex, lr (N, 3, 3) complex."""
    try:
        text = read_limited(path, "an ILEMT .dat file", MAX_TEXT_BYTES).decode("ascii")
    except UnicodeDecodeError as exc:
        raise InputError(f"{path.name}: expected an ASCII ILEMT .dat file, got a non-ASCII byte "
                         f"at offset {exc.start}") from None
    groups = []
    match = _LINE_RE.fullmatch
    for lineno, line in enumerate(text.splitlines(), 1):
        m = match(line)
        if m is None:
            if not line.strip():
                continue
            raise _line_error(path, lineno, line)
        groups.append(m.groups("0"))
    if not groups:
        raise InputError(f"{path.name}: expected ILEMT data rows of {_N_FIELDS} fields, got an empty file")
    v = np.array(groups, dtype=np.float64)             # (N, 42)
    finite = np.isfinite(v)
    if not finite.all():
        r, k = np.argwhere(~finite)[0]
        raise InputError(f"{path.name}: data row {r + 1}: field {k + 1}: expected a finite "
                         f"number, got {groups[r][k]!r}")
    stage = v[:, :6]
    z = v[:, 6::2] + 1j * v[:, 7::2]                    # (N, 18) complex
    # value k of a 9-block: source k % 3 into sensor k // 3 -> C[source, sensor] = block.reshape(3,3).T
    hr = z[:, :9].reshape(-1, 3, 3).transpose(0, 2, 1)
    lr = z[:, 9:].reshape(-1, 3, 3).transpose(0, 2, 1)
    return np.ascontiguousarray(stage), np.ascontiguousarray(hr), np.ascontiguousarray(lr)


def _check_drift(name: str, stage: np.ndarray, hr: np.ndarray) -> None:
    if len(stage) >= 2 and np.array_equal(stage[0], stage[-1]):
        drift = float(np.max(np.abs(hr[0] - hr[-1])))
        if drift > DRIFT_LIMIT:
            warnings.warn(f"{name}: null-pose drift max |C_first - C_last| = {drift:.3g} "
                          f"exceeds {DRIFT_LIMIT:g}", stacklevel=3)


def _read_one(path: Path, source_signs, sensor_signs, compensate: bool, codes=None) -> dict:
    name = path.name
    if codes is None:
        parsed = parse_ilemt_name(name)
        if parsed is None:
            warnings.warn(f"{name}: file name does not match so<SRC>_se<SEN>_<pattern>.dat; "
                          "assuming home fixtures (no fixture rotation)", stacklevel=3)
            parsed = ("YoutZup", "YoutZup", "")
        codes = parsed
    so_code, se_code, pattern = codes
    for role, code in (("source", so_code), ("sensor", se_code)):
        try:
            fixture_axes(code)
        except ValueError as exc:
            raise InputError(f"{name}: unknown {role} fixture code {code!r}: {exc}") from None
    stage_logged, hr, lr = _parse_dat(path)
    _check_drift(name, stage_logged, hr)
    s_so = resolve_signs(name, source_signs)
    s_se = resolve_signs(name, sensor_signs)
    flip = np.outer(s_so, s_se)
    hr = hr * flip
    lr = lr * flip
    stage = compensate_stage(stage_logged) if compensate else stage_logged
    n = len(stage)
    return {"name": name, "couplings": hr, "lr": lr, "stage": _stage_si(stage),
            "stage_logged": _stage_si(stage_logged), "source_fixture": so_code,
            "sensor_fixture": se_code, "pattern": pattern, "n": n,
            "source_signs": np.broadcast_to(s_so, (n, 3)),
            "sensor_signs": np.broadcast_to(s_se, (n, 3))}


def _sign_json(signs) -> list:
    return [[r, [int(x) for x in s]] for r, s in signs]


def _assemble(parts: list[dict], meta: dict) -> Dataset:
    return Dataset(
        couplings=np.concatenate([p["couplings"] for p in parts]),
        stage=np.concatenate([p["stage"] for p in parts]),
        source_fixture=np.concatenate([np.full(p["n"], p["source_fixture"]) for p in parts]),
        sensor_fixture=np.concatenate([np.full(p["n"], p["sensor_fixture"]) for p in parts]),
        pattern=np.concatenate([np.full(p["n"], p["pattern"]) for p in parts]),
        file_index=np.concatenate([np.full(p["n"], i, dtype=np.int64) for i, p in enumerate(parts)]),
        files=tuple(p["name"] for p in parts),
        stage_logged=np.concatenate([p["stage_logged"] for p in parts]),
        source_signs=np.concatenate([p["source_signs"] for p in parts]),
        sensor_signs=np.concatenate([p["sensor_signs"] for p in parts]),
        extra={"couplings_lr": np.concatenate([p["lr"] for p in parts])},
        meta=meta,
    )


def _names_from_options(folder: Path) -> dict:
    opt = folder / "local_cal_options.m"
    out = {}
    if opt.exists():
        text = _strip_matlab_comments(read_limited(opt, "an ILEMT options file",
                                                   MAX_CONFIG_BYTES).decode("utf-8", "replace"))
        for what in ("source", "sensor"):
            m = list(re.finditer(r"options\s*\.\s*" + what + r"\s*=\s*'((?:[^']|'')*)'", text))
            if m:
                out[what] = {"name": m[-1].group(1).replace("''", "'")}
    return out


def _meta(folder: Path, files: list[Path], so_signs, se_signs, sign_origin: str,
          compensate: bool, importer: str) -> dict:
    meta = _names_from_options(folder)
    meta["format"] = "ilemt-dat"
    meta["units"] = {"couplings": "1 (hardware scale)", "stage": "m, m, m, rad, rad, rad",
                     "stage_logged": "m, m, m, rad, rad, rad"}
    meta["provenance"] = {
        "openemt_version": __version__,
        "importer": importer,
        "folder": str(folder),
        "inputs": {p.name: file_sha256(p) for p in files},
        "source_signs": _sign_json(so_signs),
        "sensor_signs": _sign_json(se_signs),
        "signs_from": sign_origin,
        "compensate_stage": bool(compensate),
        "couplings": "hr block (cols 7-15); lr block in extra['couplings_lr']; signs applied to both",
    }
    return meta


def _signs_for(folder: Path, source_signs, sensor_signs):
    origin = "arguments"
    if source_signs is None or sensor_signs is None:
        f_so, f_se = _folder_signs(folder)
        has_file = (folder / "local_cal_options.m").is_file()
        if source_signs is None:
            source_signs = f_so
        if sensor_signs is None:
            sensor_signs = f_se
        origin = "local_cal_options.m" if has_file else "none"
    return (_check_sign_list(source_signs, "source_signs", 3),
            _check_sign_list(sensor_signs, "sensor_signs", 3), origin)


def read_ilemt_dat(path, *, source_signs=None, sensor_signs=None, compensate_stage=True,
                   source_fixture=None, sensor_fixture=None, pattern=None) -> Dataset:
    """Read one ILEMT ``.dat`` logger file (TAB ``±a±bi`` or comma ``%g`` style).

    Parameters
    ----------
    path : path-like
        ``so<SRC>_se<SEN>_<pattern>.dat``; fixture codes and pattern come from the name.
    source_signs, sensor_signs : list of (regex, (s1, s2, s3)), optional
        Sign-flip rules (docs/ilemt-data.md#sign-flips). ``None`` reads them from the file's folder
        ``local_cal_options.m`` when present (else no flips); ``[]`` means no flips.
    compensate_stage : bool
        Apply the stage-error compensation of docs/ilemt-data.md#stage-compensation (default on).
    source_fixture, sensor_fixture, pattern : str, optional
        Override the values parsed from the file name (needed when the name does not follow
        the convention; otherwise home fixtures ``YoutZup`` and an empty pattern are assumed).

    Returns
    -------
    Dataset
        ``couplings`` (N, 3, 3) complex hr couplings ``C[source, sensor]`` with signs applied,
        ``stage`` compensated (m, rad), ``stage_logged`` (m, rad), ``extra["couplings_lr"]``.
    """
    path = Path(path)
    check_regular(path, "an ILEMT .dat file")
    so, se, origin = _signs_for(path.parent, source_signs, sensor_signs)
    codes = None
    if source_fixture is not None or sensor_fixture is not None or pattern is not None:
        parsed = parse_ilemt_name(path.name) or ("YoutZup", "YoutZup", "")
        codes = (source_fixture or parsed[0], sensor_fixture or parsed[1],
                 parsed[2] if pattern is None else pattern)
    part = _read_one(path, so, se, bool(compensate_stage), codes)
    meta = _meta(path.parent, [path], so, se, origin, compensate_stage,
                 "openemt.io.read_ilemt_dat")
    return _assemble([part], meta)


def import_ilemt_folder(folder, *, source_signs=None, sensor_signs=None, compensate_stage=True,
                        patterns=None) -> Dataset:
    """Import every ``so*_se*_*.dat`` file of an ILEMT data folder into one Dataset.

    Files are read in name order and concatenated; ``files`` holds the file names and
    ``file_index`` the file of each row.

    Parameters
    ----------
    folder : path-like
        An ILEMT data folder (e.g. ``cal_9_15_premo_cmu``).
    source_signs, sensor_signs : list of (regex, (s1, s2, s3)), optional
        Sign-flip rules; ``None`` reads the folder's ``local_cal_options.m`` if present, else no
        flips. ``[]`` means no flips. Never guessed from the folder name.
    compensate_stage : bool
        Apply the stage-error compensation (docs/ilemt-data.md#stage-compensation).
    patterns : str or collection of str, optional
        Keep only files whose pattern (``md``, ``ld``, ``sweep``, ...) is listed.

    Returns
    -------
    Dataset
        With ``meta["source"]["name"]`` / ``meta["sensor"]["name"]`` from the options file and
        ``meta["provenance"]`` (openemt version, SHA-256 of every input, sign lists, compensation).

    Examples
    --------
    >>> import openemt
    >>> data = openemt.import_ilemt_folder(openemt.datasets.path("cal_9_15_premo_cmu"))
    >>> len(data), len(data.files), data.couplings.shape[1:]
    (8033, 21, (3, 3))
    >>> int(data.mask(pattern="md").sum())
    852
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"expected an ILEMT data folder, got missing folder {str(folder)!r}")
    if isinstance(patterns, str):
        patterns = [patterns]
    wanted = None if patterns is None else set(patterns)
    files = []
    for p in sorted(folder.glob("*.dat"), key=lambda p: p.name):
        parsed = parse_ilemt_name(p.name)
        if parsed is None or not p.exists():      # a FIFO or device is refused by the reader
            continue
        if wanted is not None and parsed[2] not in wanted:
            continue
        files.append(p)
    if not files:
        what = "" if wanted is None else f" with pattern in {sorted(wanted)}"
        raise InputError(f"expected so<SRC>_se<SEN>_<pattern>.dat files{what} in {str(folder)!r}, "
                         "got none")
    so, se, origin = _signs_for(folder, source_signs, sensor_signs)
    parts = [_read_one(p, so, se, bool(compensate_stage)) for p in files]
    meta = _meta(folder, files, so, se, origin, compensate_stage, "openemt.io.import_ilemt_folder")
    return _assemble(parts, meta)
