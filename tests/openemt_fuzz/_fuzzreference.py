"""Hostile references for ``openemt collect``: generated OpenIGTLink servers (loopback only) and
reference CSVs.

Three levels, each case generated from a seed:

- ``client``: a hostile server (:func:`serve`) streams a robot's poses with one kind of damage
  (:data:`SERVER_KINDS`) to :class:`openemt.collect.ReferenceClient` in this process; a finding
  is an exception, a client that does not end within the time limit, or a kept pose that is not
  rigid and finite;
- ``csv``: a reference CSV with one kind of damage (:data:`CSV_KINDS`) read by
  :func:`openemt.collect.read_reference_csv`; a finding is an exception other than
  ``InputError``, a hang, or a kept pose that is not rigid and finite (its time, peak memory
  and rows are reported);
- ``collect``: ``openemt collect`` in a child process against a hostile server or CSV; a
  finding is a traceback, a hang, a written pose that is not rigid or finite or not the pose
  the reference held at that dwell (1 mm, 0.5 deg against the simulated truth), or a mismatched
  reference (frozen, another motion, metres sent as millimetres, every message broken) that is
  not refused.
"""

from __future__ import annotations

import random
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

__all__ = ["CSV_KINDS", "MISMATCHED", "SERVER_KINDS", "csv_case", "fuzz_reference", "serve"]

SERVER_KINDS = ("benign", "crc_some", "crc_all", "not_rotation", "status_invalid",
                "valid_false", "glitch", "jump", "huge_size", "truncated", "bad_metadata",
                "index_65535", "random_header", "frozen", "other_motion", "metres_as_mm")
CSV_KINDS = ("benign", "nan", "empty", "wrong_length", "zero_quaternion", "inf_time", "nul",
             "milliseconds", "glitch", "jump", "not_a_number", "frozen", "other_motion",
             "millimetres_as_metres", "big")
#: Kinds whose reference does not match the tracker: collect must refuse them.
MISMATCHED = {"crc_all", "frozen", "other_motion", "metres_as_mm", "millimetres_as_metres"}
_DEVICE = "RobotToBase"


def _crc(body: bytes) -> int:
    import crcmod

    return crcmod.mkCrcFun(0x142F0E1EBA9EA3693, rev=False, initCrc=0, xorOut=0)(body)


def transform_message(M_mm, stamp: float, *, version: int = 1, meta=None, crc_ok=True,
                      device: str = _DEVICE, meta_sizes=None) -> bytes:
    """An OpenIGTLink TRANSFORM (translation in mm), version 1 or 2 (with ``meta``)."""
    content = struct.pack(">12f", *np.asarray(M_mm, float)[:3, :4].T.reshape(-1))
    body = content
    if version >= 2:
        meta = meta or {}
        keys = [(k.encode(), v.encode()) for k, v in meta.items()]
        mh = struct.pack(">H", len(keys)) + b"".join(
            struct.pack(">HHI", len(k), 3, len(v)) for k, v in keys)
        md = b"".join(k + v for k, v in keys)
        if meta_sizes is not None:
            mh = struct.pack(">H", meta_sizes[0]) + mh[2:]
        body = struct.pack(">HHII", 12, len(mh), len(md), 0) + content + mh + md
    sec = int(stamp) & 0xFFFFFFFF if np.isfinite(stamp) and stamp >= 0 else 0
    frac = int((stamp - int(stamp)) * 2 ** 32) & 0xFFFFFFFF if np.isfinite(stamp) and stamp >= 0 \
        else 0
    crc = _crc(body) ^ (0 if crc_ok else 0x5A5A)
    head = struct.pack(">H12s20sIIQQ", version, b"TRANSFORM", device.encode(), sec, frac,
                       len(body), crc)
    return head + body


def serve(kind: str, motion, *, seed: int, speed: float = 4.0, rate: float = 250.0,
          n_messages: int | None = None, other=None, deadline: float = 60.0):
    """A hostile server on 127.0.0.1 (a free port): on connection, streams ``motion``'s
    reference poses (simulated time from the connection, ``speed`` per wall second) damaged as
    ``kind`` says; returns ``(port, thread, stop_event)``."""
    rng = random.Random(seed)
    lsock = socket.socket()
    lsock.bind(("127.0.0.1", 0))
    lsock.listen(1)
    lsock.settimeout(0.2)
    port = lsock.getsockname()[1]
    stop = threading.Event()

    def run():
        end = time.monotonic() + deadline
        conn = None
        try:
            while conn is None and not stop.is_set() and time.monotonic() < end:
                try:
                    conn, _ = lsock.accept()
                except TimeoutError:
                    continue
            if conn is None:
                return
            conn.settimeout(1.0)
            t0 = time.time()
            k = 0
            clock = 1.7e9 + rng.uniform(0, 1e4)
            jump_at = rng.randint(50, 350) if n_messages else rng.randint(200, 2000)
            while not stop.is_set() and time.monotonic() < end:
                wait = t0 + k / (rate * speed) - time.time()
                if wait > 0:
                    time.sleep(min(wait, 0.01))
                    continue
                tau = (time.time() - t0) * speed
                src = other if kind == "other_motion" else motion
                B = src.reference_poses([0.0 if kind == "frozen" else tau])[0].copy()
                B[:3, 3] *= 1.0 if kind == "metres_as_mm" else 1e3
                stamp = clock + tau
                version, meta, crc_ok, sizes = 1, None, True, None
                r = rng.random()
                if kind == "crc_some" and r < 0.3 or kind == "crc_all":
                    crc_ok = False
                elif kind == "not_rotation" and r < 0.2:
                    B[:3, :3] *= rng.choice([2.0, 0.5, 1.01]) if r < 0.1 else 1.0
                    if r >= 0.1:
                        B[0, 1] += 0.3                       # sheared
                elif kind == "status_invalid":
                    version = 2
                    meta = {"TransformStatus": "INVALID" if r < 0.2 else "OK"}
                elif kind == "valid_false":
                    version = 2
                    meta = {"TransformValid": "false" if r < 0.2 else "true"}
                elif kind == "glitch" and r < 0.01:
                    stamp += rng.choice([1e3, 1e4, 1e6, -1e6, -clock, 2.0 ** 32 - 1 - clock])
                elif kind == "jump" and k >= jump_at:
                    stamp += 1000.0
                elif kind == "bad_metadata" and r < 0.2:
                    version, meta = 2, {"TransformStatus": "OK"}
                    sizes = (rng.randint(2, 9),)
                elif kind == "index_65535" and r < 0.1:
                    version, meta, sizes = 2, {"TransformStatus": "OK"}, (65535,)
                msg = transform_message(B, stamp, version=version, meta=meta, crc_ok=crc_ok,
                                        meta_sizes=sizes)
                if kind == "huge_size" and k == jump_at:
                    msg = msg[:42] + struct.pack(">Q", rng.choice([2 ** 64 - 1, 2 ** 62])) \
                        + msg[50:]
                elif kind == "random_header" and k == jump_at:
                    msg = bytes(rng.getrandbits(8) for _ in range(58)) + msg
                elif kind == "truncated" and k == jump_at:
                    conn.sendall(msg[:70])
                    return
                conn.sendall(msg)
                k += 1
                if n_messages is not None and k >= n_messages:
                    return
        except OSError:
            return
        finally:
            if conn is not None:
                conn.close()
            lsock.close()

    th = threading.Thread(target=run, daemon=True, name="hostile-reference")
    th.start()
    return port, th, stop


def _rigid_finite(P) -> bool:
    from openemt.collect import rigid_rows

    P = np.asarray(P, float).reshape(-1, 4, 4)
    return bool(rigid_rows(P).all())


def _client_case(kind, seed, time_limit) -> dict:
    from openemt.collect import ReferenceClient, simulated_motion

    m = simulated_motion("robot", 4, spare=4, seed=seed % 7)
    port, th, stop = serve(kind, m, seed=seed, speed=20.0, n_messages=400,
                           other=simulated_motion("robot", 4, spare=4, seed=seed % 7 + 100),
                           deadline=time_limit)
    t0 = time.perf_counter()
    out = {"kind": kind, "finding": None}
    client = None
    try:
        client = ReferenceClient("127.0.0.1", port, _DEVICE, connect_timeout=2.0)
        got_t, got_B = [], []
        while not client.closed and time.perf_counter() - t0 < time_limit:
            t, B = client.take()
            got_t.append(t)
            got_B.append(B)
            time.sleep(0.01)
        t, B = client.take()
        got_t.append(t)
        got_B.append(B)
        if not client.closed:
            out["finding"] = "hang"
        B = np.concatenate(got_B)
        if len(B) and not _rigid_finite(B):
            out["finding"] = "non-rigid pose kept"
        out.update(kept=len(B), drops=client.drops.to_dict(), error=client.error)
    except Exception as exc:                 # noqa: BLE001 - that is the finding
        out["finding"] = f"exception: {type(exc).__name__}: {exc}"
    finally:
        stop.set()
        if client is not None:
            client.close()
        th.join(2.0)
    out["seconds"] = time.perf_counter() - t0
    return out


def csv_case(kind: str, folder: Path, seed: int, *, motion=None, seconds: float = 40.0) -> Path:
    """A reference CSV of ``motion``'s reference poses (100 rows per second on a clock of its
    own) with one kind of damage."""
    from openemt.collect import simulated_motion
    from openemt.geometry import vector_from_pose

    rng = np.random.default_rng(seed)
    m = motion or simulated_motion("robot", 4, spare=20, seed=seed % 7)
    if kind == "other_motion":
        m = simulated_motion("robot", 4, spare=20, seed=seed % 7 + 100)
    n = int(seconds * 100) if kind != "big" else 1_250_000
    t = np.arange(n) / 100.0
    B = m.reference_poses(np.zeros(n) if kind == "frozen" else t)
    v = vector_from_pose(B)
    if kind == "millimetres_as_metres":
        v[:, :3] *= 1e3
    q = __import__("scipy.spatial.transform", fromlist=["Rotation"]).Rotation.from_rotvec(
        v[:, 3:]).as_quat(scalar_first=True)
    clock = 1.7e9 + rng.uniform(0, 1e4)
    tt = clock + t
    if kind == "milliseconds":
        tt = tt * 1e3
    table = np.column_stack([tt, v[:, :3], q])
    lines = ["time,x_m,y_m,z_m,qw,qx,qy,qz"]
    lines += [",".join(repr(float(x)) for x in row) for row in table] if kind != "big" else []
    path = folder / f"ref-{kind}-{seed}.csv"
    if kind == "big":
        with open(path, "w") as fh:
            fh.write(lines[0] + "\n")
            np.savetxt(fh, table, delimiter=",", fmt="%.17g")
        return path
    bad = rng.choice(np.arange(1, len(lines)), size=max(1, len(lines) // 50), replace=False)
    for i in bad:
        f = lines[i].split(",")
        if kind == "nan":
            f[rng.integers(1, 8)] = "nan"
        elif kind == "empty":
            f[rng.integers(0, 8)] = ""
        elif kind == "wrong_length":
            f = f[:rng.integers(1, 8)] if rng.random() < 0.5 else f + ["1", "2"]
        elif kind == "zero_quaternion":
            f[4:8] = ["0", "0", "0", "0"]
        elif kind == "inf_time":
            f[0] = rng.choice(["inf", "-inf"])
        elif kind == "nul":
            f[rng.integers(0, 8)] += "\x00"
        elif kind == "not_a_number":
            f[rng.integers(0, 8)] = "abc"
        elif kind == "glitch" and rng.random() < 0.3:
            f[0] = repr(float(f[0]) + float(rng.choice([1e9, 1e5, -1e7])))
        lines[i] = ",".join(f)
    if kind == "jump":
        j = len(lines) // 2
        lines[j:] = [",".join([repr(float(ln.split(",")[0]) + 1000.0)] + ln.split(",")[1:])
                     for ln in lines[j:]]
    path.write_text("\n".join(lines) + "\n")
    return path


_CHILD = ("import sys\nfrom openemt.collect import read_reference_csv\n"
          "from openemt.collect import rigid_rows\nfrom openemt._errors import InputError\n"
          "try:\n    t, P = read_reference_csv(sys.argv[1])\n"
          "    ok = bool(rigid_rows(P).all()) and bool(__import__('numpy').isfinite(t).all())\n"
          "    hwm = [ln.split()[1] for ln in open('/proc/self/status') if "
          "ln.startswith('VmHWM')]\n"
          "    print(len(t), int(ok), hwm[0])\n"
          "except InputError as e:\n    print('refused', e)\n")


def _csv_case(kind, seed, folder, time_limit) -> dict:
    path = csv_case(kind, folder, seed)
    t0 = time.perf_counter()
    out = {"kind": kind, "finding": None, "bytes": path.stat().st_size}
    try:
        r = subprocess.run([sys.executable, "-c", _CHILD, str(path)], capture_output=True,
                           text=True, timeout=time_limit)
        words = r.stdout.split()
        if r.returncode != 0 or "Traceback" in r.stderr:
            out["finding"] = f"crash: {r.stderr.strip()[-200:]}"
        elif words and words[0] == "refused":
            out["outcome"] = "refused"
        elif len(words) == 3:
            out.update(outcome="read", rows=int(words[0]), peak_bytes=int(words[2]) * 1024)
            if words[1] != "1":
                out["finding"] = "non-rigid pose kept"
    except subprocess.TimeoutExpired:
        out["finding"] = "hang"
    path.unlink()
    out["seconds"] = time.perf_counter() - t0
    return out


def _check_written(path, tol_mm=1.0, tol_deg=0.5) -> str | None:
    """None when every written pose is rigid, finite and the pose the reference held at that
    dwell (against the simulated truth); else what is wrong."""
    from openemt.geometry import invert
    from openemt.io import read_dataset

    ds = read_dataset(path)
    B = ds.extra["reference_poses"]
    if not _rigid_finite(B) or not np.isfinite(ds.couplings).all():
        return "non-rigid or non-finite pose written"
    truth = ds.meta.get("truth") or {}
    if ds.poses is None or "X" not in truth:
        return None
    X, Y = np.asarray(truth["X"]), np.asarray(truth["Y"])
    held = invert(Y) @ ds.poses @ X                  # the reference's tool at each dwell
    d = np.linalg.norm(held[:, :3, 3] - B[:, :3, 3], axis=1) * 1e3
    R = np.einsum("nji,njk->nik", held[:, :3, :3], B[:, :3, :3])
    ang = np.degrees(np.arccos(np.clip((np.trace(R, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    if d.max() > tol_mm or ang.max() > tol_deg:
        return f"mispaired: reference pose {d.max():.1f} mm / {ang.max():.2f} deg off"
    return None


_COLLECT = "import sys\nfrom openemt.cli import main\nsys.exit(main(sys.argv[1:]))\n"


def _collect_case(kind, seed, source, folder, time_limit) -> dict:
    from openemt.collect import simulated_motion, spare_poses

    out_path = folder / f"col-{source}-{kind}-{seed}.h5"
    m = simulated_motion("robot", 4, spare=spare_poses(4), seed=seed)
    argv = [sys.executable, "-c", _COLLECT, "collect", "--source", "sim", "--n-poses", "4",
            "--seed", str(seed), "--sim-speed", "4", "--duration", "60", "-o", str(out_path),
            "--quiet"]
    stop = th = None
    if source == "server":
        port, th, stop = serve(kind, m, seed=seed, speed=4.0,
                               other=simulated_motion("robot", 4, spare=20, seed=seed + 100),
                               deadline=time_limit)
        argv += ["--reference", f"igtl://127.0.0.1:{port}/{_DEVICE}",
                 "--reference-timeout", "1"]
    else:
        argv += ["--reference-csv", str(csv_case(kind, folder, seed, motion=m))]
    t0 = time.perf_counter()
    res = {"kind": kind, "source": source, "finding": None}
    try:
        r = subprocess.run(argv, capture_output=True, text=True, timeout=time_limit)
        errors = [ln for ln in r.stderr.splitlines() if ln.startswith("error:")]
        if "Traceback" in r.stderr or r.returncode not in (0, 2):
            res["finding"] = f"crash (exit {r.returncode}): {r.stderr.strip()[-300:]}"
        elif r.returncode == 2:
            res["outcome"] = "refused"
            if len(errors) != 1:
                res["finding"] = "refusal without exactly one error line"
            elif out_path.exists():
                res["finding"] = "refused but wrote the output"
        else:
            res["outcome"] = "written"
            if kind in MISMATCHED:
                res["finding"] = "mismatched reference written"
            else:
                res["finding"] = _check_written(out_path)
    except subprocess.TimeoutExpired:
        res["finding"] = "hang"
    finally:
        if stop is not None:
            stop.set()
            th.join(2.0)
    res["seconds"] = time.perf_counter() - t0
    return res


def fuzz_reference(n_client: int, n_csv: int, n_collect: int, seed: int = 0, *,
                   time_limit: float = 90.0, progress=None) -> dict:
    """Run the three levels (``n_*`` cases each, kinds in turn, seeds from ``seed``); the
    counts per kind and outcome, the largest time and memory per case, and the findings."""
    rng = random.Random(seed)
    cases = []
    with tempfile.TemporaryDirectory(prefix="openemt-fuzz-reference-") as tmp:
        folder = Path(tmp)
        for i in range(n_client):
            cases.append(("client", _client_case(SERVER_KINDS[i % len(SERVER_KINDS)],
                                                 rng.randrange(10 ** 6), min(time_limit, 30))))
            progress and progress(1)
        for i in range(n_csv):
            kind = CSV_KINDS[i % len(CSV_KINDS)]
            if kind == "big" and i >= len(CSV_KINDS):
                kind = "benign"                     # one 200 MB file is enough
            cases.append(("csv", _csv_case(kind, rng.randrange(10 ** 6), folder, time_limit)))
            progress and progress(1)
        kinds = [("server", k) for k in SERVER_KINDS] + [("csv", k) for k in CSV_KINDS
                                                        if k != "big"]
        for i in range(n_collect):
            source, kind = kinds[i % len(kinds)]
            cases.append(("collect", _collect_case(kind, rng.randrange(6), source, folder,
                                                   time_limit)))
            progress and progress(1)
    out = {"cases": len(cases), "findings": 0, "examples": [], "levels": {}}
    for level, c in cases:
        lv = out["levels"].setdefault(level, {"cases": 0, "findings": 0, "max_seconds": 0.0,
                                              "by_kind": {}})
        lv["cases"] += 1
        lv["max_seconds"] = round(max(lv["max_seconds"], c["seconds"]), 2)
        if "peak_bytes" in c:
            lv["max_peak_mib"] = round(max(lv.get("max_peak_mib", 0), c["peak_bytes"] / 2**20), 1)
            if c["kind"] == "big":
                lv["big_file_mib"] = round(c["bytes"] / 2**20, 1)
                lv["big_file_seconds"] = round(c["seconds"], 1)
                lv["big_file_peak_mib"] = round(c["peak_bytes"] / 2**20, 1)
        k = lv["by_kind"].setdefault(c["kind"] + ("" if "source" not in c
                                                  else f"@{c['source']}"), {})
        key = "finding" if c["finding"] else c.get("outcome", "ok")
        k[key] = k.get(key, 0) + 1
        if c["finding"]:
            lv["findings"] += 1
            out["findings"] += 1
            if len(out["examples"]) < 20:
                out["examples"].append({"level": level, **{x: c.get(x) for x in
                                                           ("kind", "source", "finding")}})
    return out
