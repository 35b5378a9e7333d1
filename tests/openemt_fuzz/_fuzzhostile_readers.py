"""Hostile inputs for the readers: files that try to make openemt read outside themselves,
allocate far more than they hold, block on a FIFO or a device, or set absurd amounts of work.

Unlike the mutation cases of :mod:`openemt_fuzz._fuzzcases`, each case here is built on
purpose by a *builder* in a fresh folder: HDF5 datasets, raw recordings and pose files with
external links, soft links out of the file, virtual datasets, external storage (``/etc/passwd``,
``/proc/self/environ``, a FIFO), a plugin filter, declared-shape bombs and row counts that
disagree (sealed again afterwards, as a hostile writer would: the seal is a CRC anyone can
recompute); FIFO and device paths given to every reader; tracker, board, calibration and
correction files with deep nesting, absurd rates and counts and oversized lists.

Every case (:func:`cases`) is run twice in a child process with a time limit: through its Python reader
(:func:`run_reader`, via ``this module's ``_child_main````) and through
a command of the CLI. A run *held* when it ended with exit status 2 and exactly one ``error:``
line, left nothing in the output folder, finished within the time limit and peaked below
:data:`MEMORY_LIMIT_BYTES` of resident memory; any other outcome is a finding
(``accepted``, ``vague``, ``crash``, ``hang``, ``memory``, ``garbage``).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["MEMORY_LIMIT_BYTES", "OUTCOMES", "HostileCase", "all_runs", "build_seeds", "cases", "n_runs",
           "run_case", "run_hostile_readers", "run_reader"]

#: outcomes of one run; every one but ``held`` is a finding
OUTCOMES = ("held", "accepted", "vague", "crash", "hang", "memory", "garbage")
#: peak resident memory above which a refusal still counts as a finding (``memory``)
MEMORY_LIMIT_BYTES = 1 << 30
#: address-space cap of the child processes, so that an unbounded allocation fails there
#: instead of exhausting the machine
_ADDRESS_LIMIT = 16 << 30


# ----------------------------------------------------------------------------- readers


def _read_dataset(path):
    from openemt.io import open_dataset_couplings, read_dataset

    ds = read_dataset(path)
    with open_dataset_couplings(path) as reader:
        reader.read(0, min(4, len(reader)))
    return ds


def _readers() -> dict:
    from openemt.correct import read_correction
    from openemt.io import (
        import_csv,
        read_board,
        read_calibration,
        read_ilemt_dat,
        read_ndi_tsv,
        read_poses_csv,
    )
    from openemt.live import read_tracker
    from openemt.signal import read_raw
    from openemt.solve import read_poses

    return {"dataset": _read_dataset, "raw": read_raw, "poses": read_poses,
            "calibration": read_calibration, "tracker": read_tracker, "board": read_board,
            "correction": read_correction, "csv": import_csv, "poses_csv": read_poses_csv,
            "ndi": read_ndi_tsv, "dat": read_ilemt_dat}


def run_reader(reader: str, path) -> int:
    """Run one reader on ``path`` the way the CLI would report it: 0 when it returned, 2 with
    one ``error:`` line on stderr for :class:`~openemt._errors.InputError`, 3 for another
    refusal (an ``OSError`` such as "missing file" for a path that exists), a traceback and 1
    for anything else."""
    from openemt._errors import InputError

    try:
        _readers()[reader](Path(path))
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 3
    return 0


# ----------------------------------------------------------------------------- seeds


def build_seeds(folder) -> Path:
    """Valid seed files in ``folder`` (a small dataset, calibration, tracker, correction, raw
    recording and poses file) that the builders turn hostile."""
    import h5py

    from openemt.correct import fit_correction, write_correction
    from openemt.datasets import path as dataset_path
    from openemt.io import read_ilemt_calibration, write_calibration, write_dataset, write_poses_csv
    from openemt.live import example_tracker
    from openemt.signal import ChannelLayout, RawSignal, write_raw
    from openemt.solve._output import POSES_SCHEMA

    from ._fuzzcases import _small_dataset

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    ds = _small_dataset()
    write_dataset(ds, folder / "seed.h5")
    cal = read_ilemt_calibration(dataset_path("cal_9_15_premo_cmu") / "base_calibration.mat")
    write_calibration(cal, folder / "seed_cal.json")
    tracker = example_tracker("simulated")
    for p in tracker.parent.iterdir():
        if p.suffix in (".toml", ".json"):
            shutil.copy(p, folder / p.name)
    rng = np.random.default_rng(0)
    ref = np.tile(np.eye(4), (12, 1, 1))
    ref[:, :3, 3] = rng.uniform(-0.1, 0.1, (12, 3)) + [0, 0, 0.2]
    meas = ref.copy()
    meas[:, :3, 3] += 1e-3
    write_correction(fit_correction(meas, ref, "dlt", k=3), folder / "seed_corr.json")
    write_poses_csv(folder / "poses.csv", meas)
    layout = ChannelLayout()
    write_raw(RawSignal(samples=rng.normal(size=(4800, layout.n_channels)), layout=layout),
              folder / "seed_raw.h5")
    with h5py.File(folder / "seed_poses.h5", "w") as f:
        f.attrs["schema"] = POSES_SCHEMA
        f.attrs["solver"] = "lm"
        f["poses"] = ref
        f["pose_vectors"] = np.zeros((12, 6))
        f["status"] = np.zeros(12, dtype=np.int8)
        f["residual"] = np.zeros(12)
        f["iterations"] = np.zeros(12, dtype=np.int32)
    return folder


# ----------------------------------------------------------------------------- builders


def _h5_case(seed: str, change, *, sealed: bool = True):
    """A builder: copy seed file ``seed`` and let ``change(f, folder)`` edit it (h5py, "r+")."""
    def build(folder: Path, seeds: Path) -> Path:
        import h5py

        from openemt.io._h5safe import seal

        path = folder / "data.h5"
        shutil.copy(seeds / seed, path)
        with h5py.File(path, "r+") as f:
            change(f, folder)
        if sealed and seed == "seed.h5":
            seal(path)
        return path
    return build


def _fifo(folder: Path) -> Path:
    p = folder / "fifo"
    if not p.exists():
        os.mkfifo(p)
    return p


def _main_name(f) -> str:
    if "couplings_real" in f:
        return "couplings_real"
    return "samples" if "samples" in f else "poses"


def _external_storage(target_of, nbytes=64):
    def change(f, folder):
        name = _main_name(f)
        shape, dtype = f[name].shape, f[name].dtype
        del f[name]
        n = int(np.prod(shape)) * dtype.itemsize
        f.create_dataset(name, shape=shape, dtype=dtype,
                         external=[(str(target_of(folder)), 0, max(n, nbytes))])
    return change


def _softlink(target: str):
    def change(f, folder):
        import h5py
        name = "stage" if "stage" in f else _main_name(f)
        del f[name]
        f[name] = h5py.SoftLink(target)
    return change


def _virtual(f, folder):
    import h5py

    name = _main_name(f)
    shape, dtype = f[name].shape, f[name].dtype
    with h5py.File(folder / "other.h5", "w") as g:
        g.create_dataset("x", data=np.zeros(shape, dtype=dtype))
    del f[name]
    layout = h5py.VirtualLayout(shape=shape, dtype=dtype)
    layout[:] = h5py.VirtualSource(str(folder / "other.h5"), "x", shape=shape)
    f.create_virtual_dataset(name, layout)


def _plugin_filter(f, folder):
    name = _main_name(f)
    data = f[name][()]
    del f[name]
    f.create_dataset(name, data=data, compression="lzf")


def _declared_rows(rows: int):
    def change(f, folder):
        name = _main_name(f)
        shape, dtype = f[name].shape, f[name].dtype
        del f[name]
        if "couplings_imag" in f:
            del f["couplings_imag"]
            f.attrs["couplings_complex"] = False
        f.create_dataset(name, shape=(rows,) + shape[1:], dtype=dtype,
                         chunks=(min(rows, 65536),) + shape[1:])
    return change


def _gzip_zeros(rows: int):
    def change(f, folder):
        name = _main_name(f)
        shape = f[name].shape
        del f[name]
        if "couplings_imag" in f:
            del f["couplings_imag"]
            f.attrs["couplings_complex"] = False
        d = f.create_dataset(name, shape=(rows,) + shape[1:], dtype="f8", compression="gzip",
                             compression_opts=9, chunks=(65536,) + shape[1:])
        block = np.zeros((65536,) + shape[1:])
        for start in range(0, rows, 65536):
            d[start:start + 65536] = block[:rows - start]
    return change


def _short_rows(name: str):
    def change(f, folder):
        data = f[name][()]
        del f[name]
        f[name] = np.concatenate([data, data[:5]])
    return change


def _special(kind: str, filename: str):
    """A builder: ``filename`` is a FIFO, or a symlink to a character device."""
    def build(folder: Path, seeds: Path) -> Path:
        path = folder / filename
        if kind == "fifo":
            os.mkfifo(path)
        else:
            os.symlink("/dev/zero", path)
        return path
    return build


def _text(filename: str, make):
    """A builder writing ``make(seeds)`` (str) to ``filename``."""
    def build(folder: Path, seeds: Path) -> Path:
        path = folder / filename
        path.write_text(make(seeds), encoding="utf-8")
        if filename.endswith(".toml"):               # the tracker's calibration beside it
            for p in seeds.glob("*.json"):
                shutil.copy(p, folder / p.name)
        return path
    return build


def _tracker(old: str, new):
    """Replace ``old`` by ``new()`` in the shipped tracker file (built when the case is)."""
    return lambda seeds: (seeds / "simulated.toml").read_text().replace(old, new())


def _tracker_append(extra):
    return lambda seeds: (seeds / "simulated.toml").read_text() + extra()


def _json_edit(seed: str, edit):
    import json

    def make(seeds):
        doc = json.loads((seeds / seed).read_text())
        return edit(doc)
    return make


def _nested(depth: int) -> str:
    return "[" * depth + "]" * depth


def _cal_coils(doc, n=20000):
    import json
    doc["model"]["L_se"] = [[0.0] * n] * 3
    doc["model"]["M_se"] = [[1.0] * n] * 3
    return json.dumps(doc)


def _cal_long_list(doc, n=20_000_000):
    import json
    text = json.dumps(doc)
    return text[:-1] + ', "extra": {"big": [' + ",".join(["0"] * n) + "]}}"


def _board(extra_coils: int = 0, turns: float = 0, layers: int = 1):
    def make(seeds):
        from importlib import resources
        text = resources.files("openemt.board").joinpath("anser.toml").read_text("utf-8")
        if turns:
            text += "".join(f'\n[[coils]]\nname = "big{i}"\ncenter = [0.0, 0.0, 0.0]\n'
                            f'shape = "circular"\nturns_per_layer = {turns}\nlayers = {layers}\n'
                            f'layer_spacing = 0.001\nouter_size = 0.9\n'
                            f'trace_width = 1e-6\ntrace_spacing = 1e-6\n'
                            for i in range(extra_coils))
        else:
            text += "".join(f'\n[[coils]]\nname = "c{i}"\ncenter = [0.0, 0.0, 0.0]\n'
                            f'turns_per_layer = 1\nouter_size = 0.01\n'
                            for i in range(extra_coils))
        return text
    return make


@dataclass(frozen=True)
class HostileCase:
    """One hostile input: its reader (a key of the reader table), the builder that makes it in
    a folder from the seed files, and the CLI command run on it (``{file}``, ``{seed}`` and
    ``{out}`` are filled in; None: the reader only)."""

    name: str
    reader: str
    build: object
    cli: tuple | None


_INFO = ("info", "{file}", "--json")
_SOLVE = ("solve", "{file}", "-c", "{seed}/seed_cal.json", "-o", "{out}/poses.h5", "--json")
_SOLVE_CAL = ("solve", "{seed}/seed.h5", "-c", "{file}", "-o", "{out}/poses.h5", "--json")
_TRACK = ("track", "--tracker", "{file}", "--duration", "0.05", "--json")
_REPLAY = ("track", "--source", "replay", "{file}", "--duration", "0.05", "--json")
_BOARD = ("simulate", "--preset", "anser", "--board", "{file}", "--n-poses", "4", "-o",
          "{out}/sim.h5", "--json")
_CORR = ("correct", "apply", "{file}", "{seed}/poses.csv", "-o", "{out}/c.csv", "--json")


def cases() -> list:
    """Every hostile case (built lazily: the files are made when a case runs)."""
    etc, environ = (lambda folder: "/etc/passwd"), (lambda folder: "/proc/self/environ")
    out = []
    for seed, reader, clis in (("seed.h5", "dataset", (_INFO, _SOLVE)),
                               ("seed_raw.h5", "raw", (_REPLAY,)),
                               ("seed_poses.h5", "poses", ())):
        tag = reader
        kinds = [
            ("external_link_etc", _ext_link_to(etc)),
            ("external_link_fifo", _ext_link_to(_fifo)),
            ("external_storage_etc", _external_storage(etc)),
            ("external_storage_environ", _external_storage(environ)),
            ("external_storage_fifo", _external_storage(_fifo)),
            ("virtual_dataset", _virtual),
            ("soft_link_dangling", _softlink("/no/such/object")),
            ("soft_link_climbing", _softlink("../../x")),
            ("plugin_filter", _plugin_filter),
            ("declared_rows_1e8", _declared_rows(10**8)),
        ]
        if reader == "dataset":
            kinds += [("gzip_zeros_3e6_rows", _gzip_zeros(3_000_000)),
                      ("stage_rows_differ", _short_rows("stage")),
                      ("pattern_rows_differ", _short_rows("pattern"))]
        if reader == "poses":
            kinds += [("status_rows_differ", _short_rows("status"))]
        for kind, change in kinds:
            for cli in clis or (None,):
                out.append(HostileCase(f"{tag}:{kind}", reader, _h5_case(seed, change), cli))
        if reader == "dataset":
            out.append(HostileCase(f"{tag}:external_link_etc_unsealed", reader,
                                   _h5_case(seed, _ext_link_to(etc), sealed=False), _INFO))
    for reader, filename, cli in (("dataset", "data.h5", _INFO),
                                  ("dataset", "data.h5", _SOLVE),
                                  ("raw", "raw.h5", _REPLAY), ("poses", "poses.h5", None),
                                  ("calibration", "cal.json", _INFO),
                                  ("calibration", "cal.json", _SOLVE_CAL),
                                  ("calibration", "cal.mat", _INFO),
                                  ("tracker", "tracker.toml", _TRACK),
                                  ("board", "board.toml", _BOARD),
                                  ("correction", "corr.json", _CORR),
                                  ("csv", "data.csv", None), ("poses_csv", "poses.csv", None),
                                  ("ndi", "export.tsv", None),
                                  ("dat", "soYoutZup_seYoutZup_md.dat", None)):
        for kind in ("fifo", "device"):
            out.append(HostileCase(f"{reader}:{kind}:{filename}", reader,
                                   _special(kind, filename), cli))
    trackers = {
        "deep_nesting": _tracker_append(lambda: "\n[simulation2]\nx = " + _nested(5000)
                                        + "\n"),
        "sample_rate_1e15": _tracker("sample_rate = 96000.0", lambda: "sample_rate = 1e15"),
        "channels_1e18": _tracker("channels = 6 ", lambda: "channels = 1000000000000000000 "),
        "output_rate_tiny": _tracker("output_rate = 1500.0", lambda: "output_rate = 0.0015"),
        "sensors_20000": _tracker_append(lambda: "".join(
            f'\n[[sensors]]\nname = "s{i}"\nchannels = [{6 + i}]\n' for i in range(20000))),
        "list_20M": _tracker("frequencies = [7500.0, 10500.0, 13500.0]",
                             lambda: "frequencies = [" + ",".join(["1.0"] * 20_000_000) + "]"),
        "carriers_300": _tracker("frequencies = [7500.0, 10500.0, 13500.0]",
                                 lambda: "frequencies = [" + ",".join(
                                     f"{100.0 * (k + 1)}" for k in range(300)) + "]"),
        "seed_negative": _tracker("seed = 0", lambda: "seed = -1"),
    }
    for kind, make in trackers.items():
        out.append(HostileCase(f"tracker:{kind}", "tracker", _text("tracker.toml", make),
                               _TRACK))
    cals = {
        "deep_nesting": _json_edit("seed_cal.json", lambda d: _nested(100_000)),
        "sensor_coils_20000": _json_edit("seed_cal.json", _cal_coils),
        "list_20M": _json_edit("seed_cal.json", _cal_long_list),
    }
    for kind, make in cals.items():
        out.append(HostileCase(f"calibration:{kind}", "calibration", _text("cal.json", make),
                               _INFO))
    out.append(HostileCase("correction:deep_nesting", "correction",
                           _text("corr.json", _json_edit("seed_corr.json",
                                                         lambda d: _nested(100_000))), _CORR))
    boards = {
        "deep_nesting": lambda seeds: "x = " + _nested(5000) + "\n",
        "coils_20000": _board(20000),
        "segments_56_coils_10000_turns": _board(56, turns=10000, layers=2),
    }
    for kind, make in boards.items():
        out.append(HostileCase(f"board:{kind}", "board", _text("board.toml", make), _BOARD))
    return out


def _ext_link_to(target_of):
    def change(f, folder):
        import h5py
        name = _main_name(f)
        del f[name]
        f[name] = h5py.ExternalLink(str(target_of(folder)), "/x")
    return change


# ----------------------------------------------------------------------------- running


@dataclass(frozen=True)
class RunOutcome:
    """One run of a case: its class (one of :data:`OUTCOMES`), a message, the time and the
    child's peak resident memory."""

    kind: str
    message: str
    seconds: float
    peak_bytes: int


def _hwm(pid: int) -> int:
    """Peak resident memory (bytes) of a running process, from /proc (0 where unreadable)."""
    try:
        with open(f"/proc/{pid}/status", "rb") as fh:
            for line in fh:
                if line.startswith(b"VmHWM:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return 0


def _run_child(argv, *, time_limit: float, cwd) -> tuple:
    """(exit status or None on timeout, stderr text, seconds, peak RSS bytes). The peak is the
    child's own high-water mark (``VmHWM``: reported by the child as it exits, and polled)."""
    t0 = time.perf_counter()
    peak_file = os.path.join(cwd, ".peak")
    with open(os.path.join(cwd, ".stderr"), "w+b") as err:
        proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                stderr=err, cwd=cwd)
        code, peak = None, 0
        while True:
            peak = max(peak, _hwm(proc.pid))
            try:
                code = proc.wait(0.02)
                break
            except subprocess.TimeoutExpired:
                pass
            if time.perf_counter() - t0 > time_limit:
                proc.kill()
                proc.wait()
                break
        err.seek(0)
        text = err.read().decode("utf-8", errors="replace")
    try:
        with open(peak_file) as fh:
            peak = max(peak, int(fh.read().strip() or 0))
    except (OSError, ValueError):
        pass
    return code, text, time.perf_counter() - t0, peak


def _classify(code, stderr: str, seconds: float, peak: int, left) -> RunOutcome:
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("error:")]
    last = " | ".join(lines[-2:])[:300]
    if code is None:
        return RunOutcome("hang", f"no answer within {seconds:.0f} s", seconds, peak)
    if peak > MEMORY_LIMIT_BYTES:
        return RunOutcome("memory", f"peak {peak / 2**20:.0f} MiB: {last}", seconds, peak)
    if left:
        return RunOutcome("garbage", f"exit {code} left {left}", seconds, peak)
    if code == 0:
        return RunOutcome("accepted", "exit 0", seconds, peak)
    if code == 3:
        return RunOutcome("vague", last, seconds, peak)
    if code == 2 and len(errors) == 1 and "Traceback" not in stderr:
        return RunOutcome("held", errors[0][:300], seconds, peak)
    return RunOutcome("crash", f"exit {code}: {last}", seconds, peak)


def run_case(case: HostileCase, workdir, seeds, *, cli: bool, time_limit: float = 30.0
             ) -> RunOutcome:
    """Build ``case`` in a fresh folder under ``workdir`` and run its reader (``cli=False``)
    or its command in a child process; classify the outcome."""
    from ._fuzzcases import fresh_case_folders

    folder, out = fresh_case_folders(workdir)
    path = case.build(folder, Path(seeds))
    argv = [sys.executable, "-c", _CHILD]
    if cli:
        argv += ["cli", *(a.format(file=path, seed=seeds, out=out) for a in case.cli)]
    else:
        argv += ["reader", case.reader, str(path)]
    code, err, seconds, peak = _run_child(argv, time_limit=time_limit, cwd=str(workdir))
    left = sorted(p.name for p in out.iterdir())
    return _classify(code, err, seconds, peak, left)


def all_runs() -> list:
    """Every run: ``(case, cli)`` for each case's reader (once per case name) and command."""
    runs, seen = [], set()
    for case in cases():
        if case.name not in seen:
            seen.add(case.name)
            runs.append((case, False))
        if case.cli is not None:
            runs.append((case, True))
    return runs


def n_runs(limit: int | None = None) -> int:
    """How many runs :func:`run_hostile_readers` makes (for a progress bar)."""
    n = len(all_runs())
    return n if limit is None else min(n, limit)


def run_hostile_readers(*, limit: int | None = None, time_limit: float = 30.0,
                        progress=None) -> dict:
    """Run every case of :func:`cases` through its reader and (where it has one) its command
    (with ``limit``, that many runs spread evenly over the list); the counts per outcome and
    per reader, the peak memory of any run, and the findings with their messages."""
    import tempfile

    runs = all_runs()
    if limit is not None and limit < len(runs):
        picks = np.unique(np.linspace(0, len(runs) - 1, max(limit, 0)).round().astype(int))
        runs = [runs[i] for i in picks]
    counts = dict.fromkeys(OUTCOMES, 0)
    by_reader: dict = {}
    findings, peak = [], 0
    with tempfile.TemporaryDirectory(prefix="openemt-hostile-") as tmp:
        seeds = build_seeds(Path(tmp) / "seed") if runs else None
        for case, cli in runs:
            o = run_case(case, Path(tmp) / "case", seeds, cli=cli, time_limit=time_limit)
            counts[o.kind] += 1
            fam = by_reader.setdefault(case.name.split(":")[0], dict.fromkeys(OUTCOMES, 0))
            fam[o.kind] += 1
            peak = max(peak, o.peak_bytes)
            if o.kind != "held":
                findings.append({"case": case.name, "via": f"openemt {case.cli[0]}" if cli
                                 else f"reader {case.reader}", "outcome": o.kind,
                                 "message": o.message})
            if progress is not None:
                progress(1)
    n = sum(counts.values())
    return {"runs": n, "held": counts["held"], "findings": n - counts["held"],
            "outcomes": counts, "by_reader": by_reader,
            "peak_memory_mib": round(peak / 2**20, 1), "examples": findings[:20]}


def _child_main(argv) -> int:  # pragma: no cover - the child process of run_case
    """``cli ARGS...`` runs the command line, ``reader NAME PATH`` one reader; the address
    space is capped first, so that an unbounded allocation fails here."""
    import resource

    resource.setrlimit(resource.RLIMIT_AS, (_ADDRESS_LIMIT, _ADDRESS_LIMIT))
    try:
        if argv[0] == "cli":
            from openemt.cli import main

            return main(argv[1:])
        return run_reader(argv[1], argv[2])
    finally:
        with open(".peak", "w") as fh:
            fh.write(str(_hwm(os.getpid())))


#: the child's entry point: this harness lives beside the tests, not in the installed package
_CHILD = (f"import sys; sys.path.insert(0, {str(Path(__file__).resolve().parents[1])!r}); "
          "from openemt_fuzz._fuzzhostile_readers import _child_main; "
          "sys.exit(_child_main(sys.argv[1:]))")

if __name__ == "__main__":  # pragma: no cover
    sys.exit(_child_main(sys.argv[1:]))
