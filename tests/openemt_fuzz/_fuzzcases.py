"""Mutated inputs for every reader and a checker that classifies what the reader did with them.

One place for the fuzz cases, used by the test suite (``tests/test_fuzz_readers.py``, a bounded
hypothesis run) and by ``openemt bench fuzz`` (a long random run). A *target* is a reader with
a valid seed file; a *case* is that file after a list of mutations; the checker runs the reader
on it and sorts the outcome into:

``ok``
    the reader returned, and what it returned passes the target's sanity check;
``rejected``
    :class:`~openemt._errors.InputError` or ``OSError`` with a message (a clean refusal);
``vague``
    some other ``ValueError`` (the CLI would print it as bad input, but it does not come from
    openemt's own checks, so it need not say what was expected);
``garbage``
    the reader returned something that fails the sanity check (non-finite or mis-shaped
    values accepted silently);
``crash``
    any other exception (a bug: the CLI would print a traceback);
``hang``
    the reader took longer than the time limit.
"""

from __future__ import annotations

import json
import math
import random
import re
import shutil
import signal
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from openemt._errors import InputError

__all__ = ["CLI_COMMANDS", "OUTCOMES", "TARGETS", "CaseRunner", "Outcome", "mutate_bytes",
           "run_checks",
           "mutate_json", "prepare_targets", "run_case", "run_cli_case"]

OUTCOMES = ("ok", "rejected", "vague", "garbage", "crash", "hang")

#: tokens spliced into files: numbers at the edges of float64, NaN spellings, separators,
#: NDI's missing-value sentinel, encodings that are not UTF-8
TOKENS = (b"nan", b"NaN", b"inf", b"-inf", b"1e400", b"-1e308", b"1e-320", b"0", b"-0", b"1e150",
          b"999999999999999999999", b"-3.697314E28", b"\x00", b"\xff\xfe", b"\xef\xbb\xbf",
          b"\t", b",", b";", b" ", b"\n", b"\r\n", b"[", b"]", b"{", b"}", b'"', b"'", b"%",
          b"(", b")", b"*", b"+", b".*", b"(a+)+", b"\\", b"true", b"null", b"Port 10:", b"OK",
          b"Missing")

#: values a JSON mutation puts in place of a node
JSON_VALUES = (None, True, 0, -1, 1, 1e308, -1e308, 1e-320, float("nan"), float("inf"), "",
               "x", "1.0", [], {}, [[]], [None], [1, 2], {"a": 1}, 10**30, 1000000000)


def mutate_bytes(data: bytes, ops) -> bytes:
    """Apply byte-level mutations; ``ops`` is a list of ``(kind, a, b)`` with integers ``a``, ``b``
    (taken modulo the current length, so any integers are valid)."""
    d = bytearray(data)
    for kind, a, b in ops:
        n = len(d)
        if kind == "flip" and n:
            d[a % n] ^= 1 << (b % 8)
        elif kind == "truncate":
            del d[(a % (n + 1)):]
        elif kind == "delete" and n:
            i = a % n
            del d[i:i + 1 + b % 64]
        elif kind == "duplicate" and n:
            i = a % n
            d[i:i] = d[i:i + 1 + b % 256]
        elif kind == "insert":
            d[a % (n + 1):a % (n + 1)] = TOKENS[b % len(TOKENS)]
        elif kind == "replace_number" and n:
            _replace_number(d, a, TOKENS[b % len(TOKENS)])
        elif kind == "swap_lines":
            lines = bytes(d).split(b"\n")
            if len(lines) > 1:
                i, j = a % len(lines), b % len(lines)
                lines[i], lines[j] = lines[j], lines[i]
                d = bytearray(b"\n".join(lines))
        elif kind == "drop_line":
            lines = bytes(d).split(b"\n")
            if lines:
                del lines[a % len(lines)]
                d = bytearray(b"\n".join(lines))
        elif kind == "empty":
            d = bytearray()
    return bytes(d)


def _replace_number(d: bytearray, a: int, token: bytes) -> None:
    digits = b"0123456789"
    n = len(d)
    start = a % n
    i = start
    while i < n and d[i] not in digits:
        i += 1
    if i == n:
        return
    j = i
    while j < n and (d[j] in digits or d[j] in b".eE+-"):
        j += 1
    d[i:j] = token


BYTE_OPS = ("flip", "truncate", "delete", "duplicate", "insert", "replace_number", "swap_lines",
            "drop_line", "empty")


def _nodes(doc, path=()):
    yield path
    if len(path) > 40:  # do not walk into the deep nests a previous mutation built
        return
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _nodes(v, path + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from _nodes(v, path + (i,))


def mutate_json(doc, ops):
    """Replace, delete or deeply nest nodes of a parsed JSON document; ``ops`` as in
    :func:`mutate_bytes` with kinds ``set``, ``delete``, ``nest``."""
    import copy

    doc = copy.deepcopy(doc)
    for kind, a, b in ops:
        paths = list(_nodes(doc))
        path = paths[a % len(paths)]
        if kind == "set":
            value = copy.deepcopy(JSON_VALUES[b % len(JSON_VALUES)])
        elif kind == "nest":  # spliced in as text by case_bytes (too deep for json.dumps)
            value = f"{_NEST}{1 + b % 5000}"
        elif kind == "delete" and path:
            parent = _get(doc, path[:-1])
            del parent[path[-1]]
            continue
        else:
            continue
        if not path:
            doc = value
        else:
            _get(doc, path[:-1])[path[-1]] = value
    return doc


JSON_OPS = ("set", "delete", "nest")
_NEST = "@@nest@@"


def _get(doc, path):
    for k in path:
        doc = doc[k]
    return doc


# ---------------------------------------------------------------- targets: seed file + reader


@dataclass(frozen=True)
class Target:
    """A reader and the valid file it is fuzzed from."""

    name: str
    filename: str          # name the mutated file must carry (ILEMT names carry meaning)
    seed: bytes            # valid content
    json: bool             # also mutated structurally as JSON
    read: object           # callable(path) -> value
    check: object          # callable(value) -> str | None (None: sane; str: what is wrong)


def _finite(a) -> bool:
    a = np.asarray(a)
    return a.dtype.kind in "fc" and bool(np.all(np.isfinite(a)))


def _check_dataset(ds) -> str | None:
    C = ds.couplings
    n = C.shape[0]
    if C.ndim != 3 or C.shape[1] < 1 or C.shape[2] < 1:
        return f"couplings of shape {C.shape}"
    if ds.stage.shape != (n, 6):
        return f"stage of shape {ds.stage.shape} for {n} rows"
    if not _finite(ds.stage):
        return "non-finite stage values accepted"
    return None


def _check_calibration(cal) -> str | None:
    m = cal.model
    for name in ("L_so", "M_so", "L_se", "M_se"):
        a = getattr(m, name, None)
        if a is not None and not _finite(a):
            return f"non-finite {name} accepted"
    if not math.isfinite(float(getattr(m, "gain", 1.0))):
        return "non-finite gain accepted"
    if cal.linear_correction is None:
        return None
    L = np.asarray(cal.linear_correction, dtype=float)
    if not np.all(np.isfinite(L)) or abs(np.linalg.det(L)) < 1e-12:
        return "singular or non-finite linear correction accepted"
    return None


def _check_poses(table) -> str | None:
    """Poses are finite, except rows the table reports (``bad_lines``/``nonfinite_lines``:
    kept as NaN rows so that pairing by order still holds); rotations are orthonormal."""
    P = np.asarray(table.poses)
    if P.ndim != 3 or P.shape[1:] != (4, 4):
        return f"poses of shape {P.shape}"
    finite = np.all(np.isfinite(P), axis=(1, 2))
    reference = getattr(table, "reference", None)
    if reference is not None:
        finite &= np.all(np.isfinite(reference), axis=(1, 2))
    flagged = len(getattr(table, "bad_lines", ())) + len(getattr(table, "nonfinite_lines", ()))
    if int(np.sum(~finite)) != flagged:
        return f"{int(np.sum(~finite))} non-finite pose rows but {flagged} reported"
    R = P[finite, :3, :3]
    if not np.allclose(R @ np.swapaxes(R, 1, 2), np.eye(3), atol=1e-6):
        return "non-orthonormal rotation accepted"
    return None


def _check_correction(corr) -> str | None:
    probe = np.tile(np.eye(4), (3, 1, 1))
    probe[:, :3, 3] = [[0.1, 0.0, 0.2], [0.0, 0.15, 0.25], [-0.1, 0.05, 0.3]]
    out = corr.apply(probe)
    if not _finite(out):
        return "correction that yields non-finite poses accepted"
    return None


def _small_dataset():
    from openemt.datasets import path as dataset_path
    from openemt.io import read_ilemt_dat

    folder = dataset_path("cal_9_15_premo_cmu")
    ds = read_ilemt_dat(folder / "soYoutZup_seYoutZup_mdtrans.dat")
    return ds.select(np.arange(min(12, len(ds.couplings))))


def prepare_targets(workdir) -> dict[str, Target]:
    """Build the valid seed files (small, from the bundled ILEMT recording) in ``workdir``."""
    from openemt.correct import fit_correction, read_correction, write_correction
    from openemt.datasets import path as dataset_path
    from openemt.io import (
        export_csv,
        import_csv,
        import_ilemt_folder,
        read_calibration,
        read_dataset,
        read_ilemt_calibration,
        read_ilemt_dat,
        read_ndi_tsv,
        read_poses_csv,
        write_calibration,
        write_dataset,
        write_poses_csv,
    )

    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    folder = dataset_path("cal_9_15_premo_cmu")
    dat_name = "soYoutZup_seYoutZup_mdtrans.dat"
    dat_lines = (folder / dat_name).read_bytes().split(b"\n")
    dat_seed = b"\n".join(dat_lines[:16]) + b"\n"
    options_seed = (folder / "local_cal_options.m").read_bytes()

    def read_options(path):
        sub = path.parent / "folder"
        if sub.exists():
            shutil.rmtree(sub)
        sub.mkdir()
        (sub / dat_name).write_bytes(dat_seed)
        shutil.copy(path, sub / "local_cal_options.m")
        return import_ilemt_folder(sub)

    cal = read_ilemt_calibration(folder / "base_calibration.mat")
    write_calibration(cal, workdir / "seed_cal.json")
    ds = _small_dataset()
    write_dataset(ds, workdir / "seed.h5")
    export_csv(ds, workdir / "seed.csv")

    rng = np.random.default_rng(0)
    n = 40
    ref = np.tile(np.eye(4), (n, 1, 1))
    ref[:, :3, 3] = rng.uniform(-0.1, 0.1, (n, 3)) + [0, 0, 0.2]
    meas = ref.copy()
    meas[:, :3, 3] += 1e-3 * np.sin(10 * ref[:, :3, 3])
    write_poses_csv(workdir / "seed_poses.csv", meas, reference=ref)
    corr = fit_correction(meas, ref, "dlt", k=3)
    write_correction(corr, workdir / "seed_corr.json")

    def read_ndi(path):
        rec = read_ndi_tsv(path)
        for t in rec.tools:
            problem = _check_poses(t)
            if problem:
                raise _Garbage(f"tool {t.port}: {problem}")
        return rec

    def read_h5(path):
        from openemt.io import open_dataset_couplings

        out = read_dataset(path)
        with open_dataset_couplings(path) as reader:
            reader.read(0, min(4, len(reader)))
        return out

    targets = [
        Target("ilemt_dat", dat_name, dat_seed, False, read_ilemt_dat, _check_dataset),
        Target("ilemt_options", "local_cal_options.m", options_seed, False, read_options,
               _check_dataset),
        Target("ilemt_mat", "base_calibration.mat", (folder / "base_calibration.mat").read_bytes(),
               False, read_ilemt_calibration, _check_calibration),
        Target("calibration_json", "cal.json", (workdir / "seed_cal.json").read_bytes(), True,
               read_calibration, _check_calibration),
        Target("dataset_h5", "data.h5", (workdir / "seed.h5").read_bytes(), False, read_h5,
               _check_dataset),
        Target("dataset_csv", "data.csv", (workdir / "seed.csv").read_bytes(), False, import_csv,
               _check_dataset),
        Target("poses_csv", "poses.csv", (workdir / "seed_poses.csv").read_bytes(), False,
               read_poses_csv, _check_poses),
        Target("correction_json", "corr.json", (workdir / "seed_corr.json").read_bytes(), True,
               read_correction, _check_correction),
        Target("ndi_tsv", "export.tsv", _ndi_seed(), False, read_ndi, lambda rec: None),
    ]
    return {t.name: t for t in targets}


TARGETS = ("ilemt_dat", "ilemt_options", "ilemt_mat", "calibration_json", "dataset_h5",
           "dataset_csv", "poses_csv", "correction_json", "ndi_tsv")

_NDI_FIELDS = "Frame\tFace\tState\tQ0\tQx\tQy\tQz\tTx\tTy\tTz\tError\tMarkers"
_NDI_TOOLS = ("Port 10: NDI-MF2 610066   T6d0-S00108  s/n:37B31800 Channel:0",
              "Port 1: CAMP OT-Sensor-2013-05-08  s/n:38A1FC00")


def _ndi_seed() -> bytes:
    """An NDI Toolbox export in the layout real files have: the full port label in the header
    and in every row, a ``Missing`` and a ``Too Few Markers`` row filled with the sentinel."""
    sentinel = "\t".join(["-3.697314E28"] * 8)
    lines = ["Tools\t" + "\t".join(f"{lab}\t{_NDI_FIELDS}" for lab in _NDI_TOOLS)]
    for k in range(6):
        cells = ["2"]
        for j, lab in enumerate(_NDI_TOOLS):
            state = {(2, 0): "Missing", (4, 1): "Too Few Markers"}.get((k, j), "OK")
            if state == "OK":
                pose = (f"0.991445\t0.130526\t0.0\t0.0\t{10.5 * k:.4f}\t{-20.25 + k:.4f}\t"
                        f"{-300.125 + 2 * k:.4f}\t0.1234")
            else:
                pose = sentinel
            cells.append(f"{lab}\t{1000 + k}\t0\t{state}\t{pose}\t{3 * j}")
        lines.append("\t".join(cells))
    return ("\r\n".join(lines) + "\r\n").encode()


class _Garbage(Exception):
    pass


#: the CLI run on each target's file: ``{file}`` is the mutated file, ``{seed}`` the seed
#: folder, ``{out}`` an output path in a fresh folder
CLI_COMMANDS = {
    "ilemt_dat": ["import", "ilemt", "{dir}", "-o", "{out}.h5", "--json"],
    "ilemt_options": None,  # the folder import reads it through import ilemt (ilemt_dat)
    "ilemt_mat": ["info", "{file}", "--json"],
    "calibration_json": ["solve", "{seed}/seed.h5", "-c", "{file}", "-o", "{out}.h5", "--json"],
    "dataset_h5": ["solve", "{file}", "-c", "{seed}/seed_cal.json", "-o", "{out}.h5", "--json"],
    "dataset_csv": None,  # read by calibrate/report, too slow per case; the reader is fuzzed
    "poses_csv": ["correct", "fit", "{file}", "--method", "dlt", "--folds", "3", "-o",
                  "{out}.json", "--json"],
    "correction_json": ["correct", "apply", "{file}", "{seed}/seed_poses.csv", "-o",
                        "{out}.csv", "--json"],
    "ndi_tsv": ["import", "ndi", "{file}", "--tool", "10", "-o", "{out}.h5", "--json"],
}


def fresh_case_folders(workdir) -> tuple[Path, Path]:
    """``(input folder, output folder)``, empty, under ``workdir`` (whatever an earlier case
    left there removed): a command case must leave nothing in the output folder."""
    workdir = Path(workdir)
    if workdir.exists():
        shutil.rmtree(workdir)
    case_dir, out_dir = workdir / "in", workdir / "out"
    case_dir.mkdir(parents=True)
    out_dir.mkdir()
    return case_dir, out_dir


def run_cli_case(target: Target, content: bytes, workdir, seed_dir) -> Outcome:
    """Run the target's CLI command on the mutated file, in this process, and classify it:
    exit 0 with its output written, or exit 2 with one ``error:`` line and no output or
    temporary file left behind (``rejected``); anything else is a ``crash`` (a traceback, exit
    1, several error lines) or ``garbage`` (a partial or stray file)."""
    import contextlib
    import io

    from openemt.cli import main

    argv_t = CLI_COMMANDS.get(target.name)
    if argv_t is None:
        return Outcome("ok", "no command", 0.0)
    case_dir, out_dir = fresh_case_folders(workdir)
    path = case_dir / target.filename
    path.write_bytes(content)
    out = out_dir / "result"
    argv = [a.format(file=path, dir=case_dir, seed=seed_dir, out=out) for a in argv_t]
    err, std = io.StringIO(), io.StringIO()
    t0 = time.perf_counter()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(std):
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse
            code = exc.code if isinstance(exc.code, int) else 2
        except Exception as exc:  # noqa: BLE001 - main must not let anything through
            code = f"{type(exc).__name__}: {exc}"
    seconds = time.perf_counter() - t0
    left = sorted(p.name for p in out_dir.iterdir())
    lines = [ln for ln in err.getvalue().splitlines() if ln.strip()]
    if code == 0:
        if not left and any("{out}" in a for a in argv_t):
            return Outcome("garbage", "exit 0 but no output file", seconds)
        return Outcome("ok", "", seconds)
    if code == 2:
        errors = [ln for ln in lines if ln.startswith("error:")]
        if left:
            return Outcome("garbage", f"exit 2 left {left} behind", seconds)
        if len(errors) != 1 or "Traceback" in err.getvalue():
            return Outcome("crash", f"exit 2 with {len(errors)} error lines: {lines[-3:]}",
                           seconds)
        return Outcome("rejected", errors[0], seconds)
    return Outcome("crash", f"exit {code}: {' | '.join(lines[-3:])}", seconds)


class _Hang(Exception):
    pass


def _alarm(signum, frame):
    raise _Hang()


@dataclass(frozen=True)
class Outcome:
    """What one case did: its class (one of :data:`OUTCOMES`), the message and the time."""

    kind: str
    message: str
    seconds: float


def case_bytes(target: Target, ops, json_ops=()) -> bytes:
    """The mutated file content of one case."""
    data = target.seed
    if target.json and json_ops:
        text = json.dumps(mutate_json(json.loads(data), json_ops))
        text = re.sub(f'"{_NEST}([0-9]+)"', lambda m: "[" * int(m[1]) + "1" + "]" * int(m[1]),
                      text)
        data = text.encode()
    return mutate_bytes(data, ops)


def run_case(target: Target, content: bytes, workdir, *, time_limit: float = 10.0) -> Outcome:
    """Write ``content`` under the target's file name in ``workdir`` and classify the reader."""
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    path = workdir / target.filename
    path.write_bytes(content)
    use_alarm = hasattr(signal, "setitimer")
    previous = None
    if use_alarm:
        try:
            previous = signal.signal(signal.SIGALRM, _alarm)
            signal.setitimer(signal.ITIMER_REAL, time_limit)
        except ValueError:  # not the main thread
            use_alarm = False
    t0 = time.perf_counter()
    try:
        value = target.read(path)
        problem = target.check(value)
        kind, msg = ("garbage", problem) if problem else ("ok", "")
    except _Garbage as exc:
        kind, msg = "garbage", str(exc)
    except _Hang:
        kind, msg = "hang", f"no answer within {time_limit} s"
    except InputError as exc:
        kind, msg = ("rejected", str(exc)) if str(exc).strip() else ("vague", "empty message")
    except OSError as exc:
        kind, msg = "rejected", str(exc)
    except ValueError as exc:
        kind, msg = "vague", f"{type(exc).__name__}: {exc}"
    except Exception as exc:  # noqa: BLE001 - the point: anything else is a finding
        kind, msg = "crash", f"{type(exc).__name__}: {exc}"
    finally:
        if use_alarm:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, previous)
    seconds = time.perf_counter() - t0
    if kind not in ("hang",) and seconds > time_limit:
        kind, msg = "hang", f"took {seconds:.1f} s (limit {time_limit} s)"
    return Outcome(kind, msg[:300], seconds)


def random_ops(rng: random.Random, kinds, n_max: int = 4):
    """Random mutation list for the long run (the tests draw theirs with hypothesis)."""
    return [(rng.choice(kinds), rng.randrange(1 << 30), rng.randrange(1 << 30))
            for _ in range(rng.randint(1, n_max))]


class CaseRunner:
    """Runs cases in a child process, so that a reader stuck inside compiled code (where no
    signal reaches it) counts as a ``hang`` and is killed, and a crash of the interpreter itself
    (a segfault in a library) counts as a ``crash``; the child is restarted after either.

    Use as a context manager; :meth:`run` takes a target name and the file content.
    """

    def __init__(self, workdir, *, time_limit: float = 10.0):
        self.workdir = Path(workdir)
        self.time_limit = time_limit
        self._proc = None
        self._conn = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _start(self):
        import multiprocessing as mp

        ctx = mp.get_context("spawn")
        parent, child = ctx.Pipe()
        # not a daemon: the readers start probe processes of their own (io/_h5safe.py)
        self._proc = ctx.Process(target=_serve, args=(child, str(self.workdir), self.time_limit))
        self._proc.start()
        child.close()
        self._conn = parent
        if not parent.poll(300) or parent.recv() != "ready":
            raise RuntimeError("the fuzz worker did not start")

    def run(self, target: str, content: bytes, *, cli: bool = False) -> Outcome:
        """Classify one case: the reader on ``content``, or with ``cli`` the target's command
        line (:data:`CLI_COMMANDS`) through :func:`openemt.cli.main`."""
        if self._proc is None or not self._proc.is_alive():
            self._start()
        t0 = time.perf_counter()
        self._conn.send((target, content, cli))
        try:
            ready = self._conn.poll(self.time_limit + 5.0)
            if ready:
                return self._conn.recv()
            kind, msg = "hang", f"killed after {self.time_limit + 5.0:.0f} s inside compiled code"
        except EOFError:
            kind, msg = "crash", f"the reader killed the interpreter (exit {self._proc.exitcode})"
        self.close()
        return Outcome(kind, msg, time.perf_counter() - t0)

    def close(self):
        if self._proc is not None:
            if self._proc.is_alive():
                self._proc.kill()
            self._proc.join(5)
            self._proc = None
        if self._conn is not None:
            self._conn.close()
            self._conn = None


def _serve(conn, workdir, time_limit):  # pragma: no cover - runs in the child process
    workdir = Path(workdir)
    targets = prepare_targets(workdir / "seed")
    conn.send("ready")
    while True:
        try:
            name, content, cli = conn.recv()
        except EOFError:
            return
        if cli:
            outcome = run_cli_case(targets[name], content, workdir / "cli", workdir / "seed")
        else:
            outcome = run_case(targets[name], content, workdir / "case", time_limit=time_limit)
        conn.send(outcome)


def run_checks(n: int, seed: int, make, check, describe, *, time_limit: float,
               progress=None) -> dict:
    """Run ``n`` in-process cases: ``make(rng)`` builds one, ``check(case)`` returns
    ``(kind, message)`` (``"held"`` where the result is sound, else the finding's kind). A
    one-line ``expected ...`` InputError is a refusal that holds, any other a ``vague``
    finding, any other exception a ``crash``, a held case slower than ``time_limit`` a
    ``hang``. Returns the counts, the slowest case and up to 20 examples (``describe(case)``:
    the example's fields)."""
    rng = random.Random(seed)
    counts = {"refused": 0, "evaluated": 0, "findings": 0}
    examples: list = []
    slowest = 0.0
    for _ in range(int(n)):
        case = make(rng)
        t0 = time.perf_counter()
        try:
            kind, message = check(case)
            if kind == "held":
                counts["evaluated"] += 1
        except InputError as exc:
            text = str(exc)
            kind, message = ("vague", text) if "expected" not in text or "\n" in text \
                else ("held", "")
            if kind == "held":
                counts["refused"] += 1
        except Exception as exc:  # noqa: BLE001 - every other exception is a finding
            kind, message = "crash", f"{type(exc).__name__}: {exc}"
        dt = time.perf_counter() - t0
        slowest = max(slowest, dt)
        if dt > time_limit and kind == "held":
            kind, message = "hang", f"{dt:.1f} s"
        if kind != "held":
            counts["findings"] += 1
            counts[kind] = counts.get(kind, 0) + 1
            if len(examples) < 20:
                examples.append({"outcome": kind, **describe(case), "message": message[:200]})
        if progress is not None:
            progress(1)
    return {"cases": int(n), **counts, "slowest_s": round(slowest, 3), "examples": examples}
