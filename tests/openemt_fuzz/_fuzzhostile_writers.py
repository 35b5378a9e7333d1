"""Hostile output paths for every writing command (``openemt bench fuzz``, section
``hostile_writers``).

Each *case* runs one real command line (:data:`WRITERS`) through :func:`openemt.cli.main` in a
worker process (so a crash inside a library kills the worker, not the bench, and counts as
``broken``; a command blocked on a FIFO past the time limit is killed and counts as ``broken``
too) with ``-o`` (or ``--log`` / ``--save-raw``) pointing at something hostile (:data:`KINDS`):

``fifo``, ``chardev`` (a ``mknod`` copy of /dev/null), ``socket``, ``folder``, ``symlink_loop``,
``name_too_long`` (NAME_MAX + 1 bytes), ``bundled_folder`` (inside ``openemt.datasets``)
    must be refused: exit 2, one ``error:`` line, the special file unchanged, nothing new in
    the folder;
``symlink``, ``dangling_symlink``, ``name_max`` (a 255-byte name)
    must be written: exit 0, the link kept and its target a regular non-empty file, no
    temporary file left;
``full_disk``
    the output on a full 2 MB tmpfs: exit 2 with ``disk full writing``, nothing left but the
    filler (skipped where a tmpfs cannot be mounted);
``nearly_full_disk``
    the same with 64 KB left, so that the disk fills in the middle of the write: either exit 0
    and a complete output, or exit 2 with ``disk full writing`` and nothing left;
``killed``
    the command in a separate process, SIGKILLed as soon as its temporary file appears (or at
    the end): no partial output; then another command writing another name in the folder must
    remove the stale temporary file.

A case the platform does not allow (``mknod`` or ``mount`` without privileges) is ``skipped``.
The summary counts ``cases``, ``held``, ``broken`` and ``skipped`` per kind and per writer (and,
for ``killed``, ``temporary_seen``: the kills that landed while the temporary file existed), with
up to 20 examples of broken cases.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import stat
import subprocess
import sys
import tempfile
import time
from pathlib import Path

__all__ = ["KINDS", "WRITERS", "hostile_writers"]

#: writer name -> (argv with ``{out}`` for the output and ``{sim}``/``{truth}``/``{ilemt}`` for
#: the prepared inputs, output file extension)
WRITERS = {
    "simulate": (["simulate", "--preset", "dipole-approx", "--pattern", "md", "--seed", "1",
                  "-o", "{out}", "--quiet"], ".h5"),
    "import_ilemt": (["import", "ilemt", "{ilemt}", "-o", "{out}", "--quiet"], ".h5"),
    "solve": (["solve", "{sim}", "--calibration", "{truth}", "-o", "{out}", "--quiet"], ".h5"),
    "track_save_raw": (["track", "--source", "sim", "--duration", "1", "--fast", "--no-igtl",
                        "--save-raw", "{out}", "--quiet"], ".h5"),
    "track_log": (["track", "--source", "sim", "--duration", "1", "--fast", "--no-igtl",
                   "--log", "{out}", "--quiet"], ".h5"),
    "calibrate": (["calibrate", "{sim}", "--from", "{truth}", "-o", "{out}", "--quiet"],
                  ".json"),
    "report": (["report", "--dataset", "{sim}", "--calibration", "{truth}", "-o", "{out}",
                "--quiet"], ".html"),
}

REFUSED = ("fifo", "chardev", "socket", "folder", "symlink_loop", "name_too_long",
           "bundled_folder")
WRITTEN = ("symlink", "dangling_symlink", "name_max")
KINDS = REFUSED + WRITTEN + ("full_disk", "nearly_full_disk", "killed")

_TMP_PREFIX = ".openemt-"
_SEEN = "temporary seen and removed"


def _serve(conn) -> None:  # worker process: run command lines, answer (exit status, stderr)
    import io

    from openemt.cli import main

    conn.send("ready")
    while True:
        argv = conn.recv()
        if argv is None:
            return
        err = io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            try:
                rc = main(argv)
            except BaseException as exc:  # noqa: BLE001 - reported as the case's outcome
                rc, err = -1, io.StringIO(f"{type(exc).__name__}: {exc}")
        conn.send((rc, err.getvalue()))


class _Worker:
    """One warm process running CLI command lines; restarted after a crash or a hang."""

    def __init__(self, time_limit: float):
        self.time_limit = time_limit
        self._proc = self._conn = None

    def _start(self):
        import multiprocessing as mp

        ctx = mp.get_context("spawn")
        parent, child = ctx.Pipe()
        self._proc = ctx.Process(target=_serve, args=(child,))
        self._proc.start()
        child.close()
        self._conn = parent
        if not parent.poll(300) or parent.recv() != "ready":
            raise RuntimeError("the hostile-writer worker did not start")

    def run(self, argv) -> tuple[int | None, str]:
        """(exit status, stderr); exit status None: the command hung or killed the worker."""
        if self._proc is None or not self._proc.is_alive():
            self._start()
        self._conn.send([str(a) for a in argv])
        try:
            if self._conn.poll(self.time_limit):
                return self._conn.recv()
            msg = f"hung: no answer within {self.time_limit:g} s"
        except EOFError:
            msg = f"crashed: the worker died (exit {self._proc.exitcode})"
        self.close()
        return None, msg

    def close(self):
        if self._proc is not None:
            if self._proc.is_alive():
                if self._conn is not None:
                    with contextlib.suppress(OSError, BrokenPipeError):
                        self._conn.send(None)
                self._proc.join(2)
                if self._proc.is_alive():
                    self._proc.kill()
                    self._proc.join(5)
            self._proc = None
        if self._conn is not None:
            self._conn.close()
            self._conn = None


def _argv(writer: str, out: Path, inputs: dict) -> list[str]:
    return [a.format(out=out, **inputs) for a in WRITERS[writer][0]]


def _one_error_line(rc, err: str) -> str:
    """'' if the command refused cleanly (exit 2, one ``error:`` line), else what it did."""
    if rc != 2:
        return f"exit {rc}: {' '.join(err.split())[-200:]}"
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    if len(lines) != 1 or not lines[0].startswith("error: "):
        return f"exit 2 but {len(lines)} stderr lines: {' '.join(err.split())[-200:]}"
    return ""


def _temporaries(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith(_TMP_PREFIX))


def _mount_tmpfs(path: Path) -> str:
    """'' if a 2 MB tmpfs is mounted at ``path``, else why not."""
    try:
        r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(path)],
                           check=False, capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.SubprocessError) as exc:
        return str(exc)
    return "" if r.returncode == 0 else (r.stderr.strip() or f"mount exit {r.returncode}")


def _fill(folder: Path, leave: int) -> None:
    """Fill the file system of ``folder`` up to ``leave`` bytes (0: until it is full)."""
    st = os.statvfs(folder)
    free = st.f_bavail * st.f_frsize
    with open(folder / "filler", "wb", buffering=0) as fh:
        fh.write(b"\0" * max(0, free - leave))
        while not leave:
            try:
                fh.write(b"\0" * 4096)
            except OSError:
                break


class _Cases:
    def __init__(self, work: Path, worker: _Worker, inputs: dict, time_limit: float):
        self.work, self.worker, self.inputs = work, worker, inputs
        self.time_limit = time_limit
        self._n = 0
        self.tmpfs: Path | None = None
        self.tmpfs_reason = ""

    def folder(self) -> Path:
        self._n += 1
        d = self.work / f"case{self._n:04d}"
        d.mkdir()
        return d

    # each returns (outcome, message) with outcome in held / broken / skipped
    def refused(self, writer: str, kind: str):
        d = self.folder()
        ext = WRITERS[writer][1]
        out = d / f"out{ext}"
        keep = None  # (path, file type) that must survive unchanged
        if kind == "fifo":
            os.mkfifo(out)
        elif kind == "chardev":
            try:
                os.mknod(out, stat.S_IFCHR | 0o666, os.stat("/dev/null").st_rdev)
            except OSError as exc:
                return "skipped", f"mknod not permitted: {exc.strerror or exc}"
        elif kind == "socket":
            s = socket.socket(socket.AF_UNIX)
            try:
                s.bind(str(out))
            except OSError as exc:
                s.close()
                return "skipped", f"cannot bind a Unix socket there: {exc.strerror or exc}"
            s.close()
        elif kind == "folder":
            out.mkdir()
        elif kind == "symlink_loop":
            out.symlink_to(d / f"loop{ext}")
            (d / f"loop{ext}").symlink_to(out)
        elif kind == "name_too_long":
            out = d / ("w" * (os.pathconf(d, "PC_NAME_MAX") + 1 - len(ext)) + ext)
        elif kind == "bundled_folder":
            out = _bundled_folder() / f"openemt-bench-{os.getpid()}{ext}"
        if os.path.lexists(out):
            keep = (out, stat.S_IFMT(os.lstat(out).st_mode))
        before = sorted(p.name for p in d.iterdir())
        rc, err = self.worker.run(_argv(writer, out, self.inputs))
        problem = _one_error_line(rc, err) if rc is not None else err
        if keep is not None and not problem and not (
                os.path.lexists(keep[0]) and stat.S_IFMT(os.lstat(keep[0]).st_mode) == keep[1]):
            problem = f"{kind} at the output path was replaced"
        if not problem and sorted(p.name for p in d.iterdir()) != before:
            problem = f"left {sorted({p.name for p in d.iterdir()} - set(before))}"
        if kind == "bundled_folder" and os.path.lexists(out):
            problem = problem or "wrote into the bundled-dataset folder"
            with contextlib.suppress(OSError):
                os.unlink(out)
        return ("broken", problem) if problem else ("held", "")

    def written(self, writer: str, kind: str):
        d = self.folder()
        ext = WRITERS[writer][1]
        real = d / "real"
        real.mkdir()
        target = real / f"target{ext}"
        if kind == "symlink":
            target.write_bytes(b"old contents")
            out = d / f"link{ext}"
            out.symlink_to(target)
        elif kind == "dangling_symlink":
            out = d / f"link{ext}"
            out.symlink_to(target)
        else:  # name_max
            out = target = d / ("n" * (os.pathconf(d, "PC_NAME_MAX") - len(ext)) + ext)
        rc, err = self.worker.run(_argv(writer, out, self.inputs))
        if rc != 0:
            return "broken", f"exit {rc}: {' '.join(err.split())[-200:]}"
        if kind != "name_max" and not (out.is_symlink() and os.readlink(out) == str(target)):
            return "broken", "the symbolic link was not kept"
        if not target.is_file() or target.stat().st_size == 0 \
                or target.read_bytes()[:12] == b"old contents":
            return "broken", "the target was not written"
        left = _temporaries(d) + _temporaries(real)
        return ("broken", f"temporary files left: {left}") if left else ("held", "")

    def full_disk(self, writer: str, leave: int):
        if self.tmpfs is None:
            return "skipped", f"no tmpfs: {self.tmpfs_reason}"
        for p in self.tmpfs.iterdir():
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p)
            else:
                p.unlink()
        _fill(self.tmpfs, leave)
        out = self.tmpfs / f"out{WRITERS[writer][1]}"
        rc, err = self.worker.run(_argv(writer, out, self.inputs))
        left = sorted(p.name for p in self.tmpfs.iterdir() if p.name != "filler")
        if rc == 0 and leave:  # it fitted: a complete output and nothing else
            if left != [out.name] or out.stat().st_size == 0:
                return "broken", f"exit 0 but the folder holds {left}"
            return "held", "fitted"
        problem = _one_error_line(rc, err) if rc is not None else err
        if not problem and "disk full writing" not in err:
            problem = f"not reported as a full disk: {' '.join(err.split())[-200:]}"
        if not problem and left:
            problem = f"left {left}"
        return ("broken", problem) if problem else ("held", "")

    def killed(self, writer: str):
        d = self.folder()
        out = d / f"out{WRITERS[writer][1]}"
        code = ("import sys\nfrom openemt.cli import main\nsys.exit(main(sys.argv[1:]))\n")
        proc = subprocess.Popen([sys.executable, "-c", code, *_argv(writer, out, self.inputs)],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        seen = False
        t_end = time.monotonic() + self.time_limit
        while proc.poll() is None and time.monotonic() < t_end:
            if _temporaries(d):
                seen = True
                break
            time.sleep(0.002)
        proc.send_signal(signal.SIGKILL)
        rc = proc.wait(30)
        finished = rc == 0
        if out.exists() and not finished:
            return "broken", "a partial output file after SIGKILL"
        # another command writing another name in the same folder cleans up
        other = d / "other.h5"
        rc2, err2 = self.worker.run(_argv("track_save_raw", other, self.inputs))
        if rc2 != 0:
            return "broken", f"the later run failed: exit {rc2}: {' '.join(err2.split())[-200:]}"
        left = _temporaries(d)
        if left:
            return "broken", f"stale temporaries not removed by the later run: {left}"
        return "held", _SEEN if seen else "killed after the write"


def _bundled_folder() -> Path:
    import openemt.datasets as bundled

    return Path(bundled.__file__).resolve().parent


def _prepare(work: Path) -> dict:
    from openemt import datasets
    from openemt.cli import main

    sim, truth = work / "sim.h5", work / "truth.json"
    rc = main(["simulate", "--preset", "dipole-approx", "--pattern", "md", "--seed", "1",
               "-o", str(sim), "--truth-calibration", str(truth), "--quiet"])
    if rc != 0:
        raise RuntimeError(f"could not simulate the input dataset (exit {rc})")
    return {"sim": str(sim), "truth": str(truth),
            "ilemt": str(datasets.path("cal_9_15_premo_cmu"))}


def hostile_writers(rounds: int = 1, *, time_limit: float = 60.0, writers=None, kinds=None,
                    progress=None) -> dict:
    """Run every kind of hostile output for every writer ``rounds`` times; returns the counts
    (see the module docstring). ``writers`` / ``kinds`` restrict the matrix."""
    writers = list(WRITERS if writers is None else writers)
    kinds = list(KINDS if kinds is None else kinds)
    by_kind: dict = {}
    by_writer: dict = {}
    examples: list = []
    worker = _Worker(time_limit)
    with tempfile.TemporaryDirectory(prefix="openemt-hostile-") as tmp:
        work = Path(tmp)
        cases = _Cases(work / "cases", worker, _prepare(work), time_limit)
        cases.work.mkdir()
        if {"full_disk", "nearly_full_disk"} & set(kinds):
            mnt = work / "tmpfs"
            mnt.mkdir()
            cases.tmpfs_reason = _mount_tmpfs(mnt)
            cases.tmpfs = None if cases.tmpfs_reason else mnt
        try:
            for _ in range(rounds):
                for writer in writers:
                    for kind in kinds:
                        if kind in REFUSED:
                            outcome, msg = cases.refused(writer, kind)
                        elif kind in WRITTEN:
                            outcome, msg = cases.written(writer, kind)
                        elif kind in ("full_disk", "nearly_full_disk"):
                            outcome, msg = cases.full_disk(writer, 0 if kind == "full_disk"
                                                           else 64 * 1024)
                        else:
                            outcome, msg = cases.killed(writer)
                        for table, key in ((by_kind, kind), (by_writer, writer)):
                            c = table.setdefault(key, {"held": 0, "broken": 0, "skipped": 0})
                            c[outcome] += 1
                        if msg == _SEEN:
                            by_kind[kind]["temporary_seen"] = \
                                by_kind[kind].get("temporary_seen", 0) + 1
                        if outcome == "broken" and len(examples) < 20:
                            examples.append({"writer": writer, "kind": kind, "message": msg})
                        if progress is not None:
                            progress(1)
        finally:
            worker.close()
            if cases.tmpfs is not None:
                subprocess.run(["umount", "-l", str(cases.tmpfs)], check=False,
                               capture_output=True, timeout=30)
    total = {k: sum(c[k] for c in by_kind.values()) for k in ("held", "broken", "skipped")}
    return {"cases": sum(total.values()), **total, "by_kind": by_kind, "by_writer": by_writer,
            "full_disk_platform": "tmpfs" if cases.tmpfs is not None
            else (cases.tmpfs_reason or None),
            "examples": examples}
