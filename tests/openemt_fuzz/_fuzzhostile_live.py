"""Hostile live cases of ``openemt bench fuzz`` (section ``hostile_live``): signals at random
times during a logged ``track --source sim`` session, and sound sources that never start or
stop delivering.

Each case runs ``openemt track`` in a child process in its own temporary folder that already
holds a log from "an earlier session" and checks what the session promises
(docs/robustness.md#live-sessions):

``sigterm`` / ``sigint``
    SIGTERM or SIGINT after a random delay, from the start of the child (start-up) or from
    the moment its log first appeared (running): exit 143 / 130 (or the
    interpreter's own -15 / -2 when the signal comes before openemt's ``main`` runs); the log
    and raw files are readable; a log that holds rows after a clean stop is marked complete
    and holds as many rows as the JSON summary says; a stop before the first row leaves the
    earlier log untouched (never an empty one in its place).
``sigkill``
    SIGKILL the same way: both files readable (marked incomplete when the session
    had started writing), never an empty log in place of the earlier one.
``stall_never`` / ``stall_later``
    a stand-in sound card that never delivers, or stops after some blocks: exit 2 with one
    ``error:`` line naming the stall, within the time limit; the log keeps the rows tracked.

Outcomes per kind: ``held`` or a finding (``bad_exit``, ``unreadable``, ``emptied``,
``incomplete``, ``rows_mismatch``, ``hang``); ``findings`` counts the findings.
"""

from __future__ import annotations

import json
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

__all__ = ["KINDS", "fuzz_live"]

KINDS = ("sigterm", "sigint", "sigkill", "stall_never", "stall_later")

_EARLIER = b"an earlier session's log"

# Ctrl-C's default handler even where the parent ignores SIGINT (a background job)
_TRACK = ("import signal, sys\nsignal.signal(signal.SIGINT, signal.default_int_handler)\n"
          "from openemt.cli import main\nsys.exit(main(sys.argv[1:]))\n")

# a stand-in sounddevice module: never delivers (BLOCKS = 0) or delivers BLOCKS blocks of the
# simulated tracker and then falls silent
_SOUND = '''import sys, threading, time, types
import numpy as np
from openemt.live import SimulatedBackend
BLOCKS = int(sys.argv.pop(1))
class InputStream:
    def __init__(self, samplerate, channels, dtype, blocksize, device, callback):
        self.callback, self.channels = callback, channels
        self.stop_event = threading.Event()
        self.thread = threading.Thread(target=self.run, daemon=True)
        sim = SimulatedBackend(chunk=960)     # simulated up front: delivered without delay
        self.blocks = [sim.read() for _ in range(BLOCKS)]
    def run(self):
        for x in self.blocks:
            if self.stop_event.is_set():
                return
            block = np.zeros((len(x), self.channels), np.float32)
            block[:, :x.shape[1]] = x
            self.callback(block, len(x), None, None)
            time.sleep(0.005)
    def start(self):
        self.thread.start()
    def stop(self):
        self.stop_event.set()
    def close(self):
        pass
sys.modules["sounddevice"] = types.SimpleNamespace(InputStream=InputStream)
from openemt.cli import main
sys.exit(main(sys.argv[1:]))
'''

_READ = '''import json, sys
from openemt.live import read_track_log
from openemt.signal import read_raw
out = {}
for key, path in (("log", sys.argv[1]), ("raw", sys.argv[2])):
    try:
        if key == "log":
            d = read_track_log(path)
            out[key] = {"rows": d.rows, "complete": d.complete}
        else:
            r = read_raw(path)
            out[key] = {"rows": r.n_samples, "complete": r.complete}
    except Exception as exc:
        out[key] = {"error": " ".join(str(exc).split())[:200]}
print(json.dumps(out))
'''


def _read(folder: Path, time_limit: float) -> dict:
    """Read the log and raw files in a child process (a crash there is a finding too)."""
    r = subprocess.run([sys.executable, "-c", _READ, "log.h5", "raw.h5"], cwd=folder,
                       capture_output=True, text=True, timeout=time_limit, check=False)
    if r.returncode != 0:
        return {"log": {"error": f"reader exit {r.returncode}"},
                "raw": {"error": f"reader exit {r.returncode}"}}
    return json.loads(r.stdout)


def _signal_case(kind: str, rng: random.Random, folder: Path, time_limit: float,
                 max_delay: float) -> dict:
    sig = {"sigterm": signal.SIGTERM, "sigint": signal.SIGINT, "sigkill": signal.SIGKILL}[kind]
    log = folder / "log.h5"
    log.write_bytes(_EARLIER)
    # half the cases during start-up (a delay from the start of the child), half while the
    # session runs (a delay after the log first appeared)
    phase = rng.choice(("start-up", "running"))
    delay = rng.uniform(0.0, max_delay)
    cmd = [sys.executable, "-c", _TRACK, "track", "--source", "sim", "--no-igtl", "--json",
           "--log", "log.h5", "--save-raw", "raw.h5"]
    proc = subprocess.Popen(cmd, cwd=folder, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    if phase == "running":
        end = time.monotonic() + time_limit
        while log.read_bytes()[:len(_EARLIER)] == _EARLIER and proc.poll() is None:
            if time.monotonic() > end:
                proc.kill()
                proc.communicate()
                return {"outcome": "hang", "phase": phase, "message": "no log appeared"}
            time.sleep(0.02)
    time.sleep(delay)
    written = log.read_bytes()[:len(_EARLIER)] != _EARLIER
    proc.send_signal(sig)
    try:
        out, err = proc.communicate(timeout=time_limit)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        return {"outcome": "hang", "phase": phase, "delay": delay}
    code = proc.returncode
    case = {"phase": phase, "delay": round(delay, 2), "exit": code}
    allowed = {"sigterm": (143, -15), "sigint": (130, -2), "sigkill": (-9,)}[kind]
    if code not in allowed:
        return dict(case, outcome="bad_exit", message=err.strip()[-200:])
    log_now = (folder / "log.h5").read_bytes() if (folder / "log.h5").exists() else None
    if log_now is None:
        return dict(case, outcome="emptied", message="the earlier log was removed")
    if log_now == _EARLIER:                      # stopped before its first row: kept
        if written:
            return dict(case, outcome="rows_mismatch", message="a written log went back")
        if (folder / "raw.h5").exists():
            got = _read(folder, time_limit)
            if "error" in got["raw"]:
                return dict(case, outcome="unreadable", message=got["raw"]["error"])
        return dict(case, outcome="held", rows=0)
    got = _read(folder, time_limit)
    for key in ("log", "raw"):
        if key == "raw" and not (folder / "raw.h5").exists():
            return dict(case, outcome="unreadable", message="the raw file is missing")
        if "error" in got[key]:
            return dict(case, outcome="unreadable", message=f"{key}: {got[key]['error']}")
    rows = got["log"]["rows"]
    case["rows"] = rows
    if rows == 0:
        return dict(case, outcome="emptied", message="an empty log replaced the earlier one")
    # the raw samples behind every logged pose (after a SIGKILL each file may have lost its
    # own last second: two seconds of slack between them)
    slack = 2 * 96000 if kind == "sigkill" else 0
    if got["raw"]["rows"] < 64 * rows - slack:
        return dict(case, outcome="rows_mismatch",
                    message=f"raw {got['raw']['rows']} samples for {rows} poses")
    if kind != "sigkill":
        if not (got["log"]["complete"] and got["raw"]["complete"]):
            return dict(case, outcome="incomplete", message="a clean stop left it incomplete")
        try:
            summary = json.loads(out)
        except ValueError:
            return dict(case, outcome="bad_exit", message="no JSON summary")
        if summary.get("log_rows") != rows:
            return dict(case, outcome="rows_mismatch",
                        message=f"summary {summary.get('log_rows')} rows, file {rows}")
    return dict(case, outcome="held")


def _stall_case(kind: str, folder: Path, time_limit: float) -> dict:
    from openemt.live import example_tracker

    (folder / "log.h5").write_bytes(_EARLIER)
    blocks = 0 if kind == "stall_never" else 20
    cmd = [sys.executable, "-c", _SOUND, str(blocks), "track", "--tracker",
           str(example_tracker("simulated")), "--source", "sound", "--no-igtl", "--quiet",
           "--stall-warn", "0.5", "--stall-timeout", "2", "--log", "log.h5",
           "--json"]
    try:
        r = subprocess.run(cmd, cwd=folder, capture_output=True, text=True,
                           timeout=time_limit, check=False)
    except subprocess.TimeoutExpired:
        return {"outcome": "hang"}
    lines = r.stderr.strip().splitlines()
    want = "never started" if blocks == 0 else "stopped delivering"
    case = {"exit": r.returncode}
    if r.returncode != 2 or len(lines) != 1 or want not in lines[0]:
        return dict(case, outcome="bad_exit", message=r.stderr.strip()[-200:])
    if blocks == 0:
        same = (folder / "log.h5").read_bytes() == _EARLIER
        return dict(case, outcome="held" if same else "emptied")
    got = _read(folder, time_limit)["log"]
    if "error" in got:
        return dict(case, outcome="unreadable", message=got["error"])
    case["rows"] = got["rows"]
    if got["rows"] != 20 * 15 - 1:                # every sample of the 20 blocks kept
        return dict(case, outcome="rows_mismatch", message=f"{got['rows']} rows")
    return dict(case, outcome="held")


def fuzz_live(n_cases: int, seed: int = 0, *, time_limit: float = 60.0, kinds=KINDS,
              max_delay: float = 4.0, progress=None) -> dict:
    """Run ``n_cases`` hostile live cases (kinds in turn; signals after a delay drawn
    uniformly from 0 to ``max_delay`` seconds after the child starts or, for half of them,
    after its log first appeared).

    Returns ``{"cases", "by_kind": {kind: {outcome: count}}, "findings", "examples",
    "rows_kept"}`` (``rows_kept``: log rows found after each signal case, in order).
    """
    rng = random.Random(seed)
    by_kind: dict = {}
    examples: list = []
    rows_kept: list = []
    with tempfile.TemporaryDirectory(prefix="openemt-fuzz-live-") as tmp:
        for k in range(int(n_cases)):
            kind = kinds[k % len(kinds)]
            folder = Path(tmp) / f"case{k}"
            folder.mkdir()
            if kind.startswith("stall"):
                case = _stall_case(kind, folder, time_limit)
            else:
                case = _signal_case(kind, rng, folder, time_limit, max_delay)
                rows_kept.append(case.get("rows"))
            counts = by_kind.setdefault(kind, {})
            counts[case["outcome"]] = counts.get(case["outcome"], 0) + 1
            if case["outcome"] != "held" and len(examples) < 20:
                examples.append(dict(case, kind=kind))
            if progress is not None:
                progress(1)
    findings = sum(n for c in by_kind.values() for o, n in c.items() if o != "held")
    return {"cases": int(n_cases), "by_kind": by_kind, "findings": findings,
            "examples": examples, "rows_kept": rows_kept}
