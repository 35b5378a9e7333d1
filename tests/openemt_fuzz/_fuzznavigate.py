"""Fuzz section: generated navigation inputs given to ``pivot``, ``spin``, ``register``,
``assess`` and ``points``.

Every case draws a recording (a pivot, a spin, a fiducial set, a grid, a log with dwells) with
known truth, a file kind (pose CSV, track-log CSV, track-log HDF5, pose dataset, markups) and
random damage: rotation blocks scaled, sheared or reflected, NaN / inf / 1e300 values, failed
statuses, torn rows, too few rows, duplicated or collinear points, labels that disagree, times
that go back, and in HDF5 logs a broken structure (a ``rows`` or ``version`` attribute that is
not one, poses of the wrong shape or complex, a status of the wrong shape, times too short). The command runs in this process (``openemt.cli.main``); the outcome is

* ``ok``: exit 0 with a finite answer whose row counts add up (``n`` plus every ``dropped``
  reason equals the rows written), and no answer from rotation blocks that are not rotations;
* ``refused``: exit 2 with exactly one ``error:`` line;
* a finding: ``garbage`` (exit 0 with a non-finite or inconsistent answer, or an answer from
  damaged rotations), ``vague`` (exit 2 with more or other than one error line), ``crash``
  (another exit status or an exception), ``slow`` (longer than the time limit).

The JSON gives the counts per command and outcome, the largest time and the largest growth of
the process's peak memory of one case.
"""

from __future__ import annotations

import contextlib
import io
import json
import random
import resource
import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["fuzz_navigate"]

_FINDINGS = ("garbage", "vague", "crash", "slow")


def _rotations(rng, n, spread):
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(rng.normal(0, spread, (n, 3)))


def _poses(rng, kind, n):
    """Poses (n, 4, 4) and times of a generated recording."""
    from openemt.geometry import pose_from_rt

    tip, pivot = np.array([0.002, -0.001, 0.15]), np.array([0.1, 0.0, 0.2])
    if kind == "pivot":
        R = _rotations(rng, n, 0.35)
        p = pivot - R.apply(tip) + rng.normal(0, 2e-4, (n, 3))
    elif kind == "spin":
        from scipy.spatial.transform import Rotation

        R = Rotation.from_rotvec(np.outer(rng.uniform(-1.4, 1.4, n), tip / np.linalg.norm(tip)))
        p = pivot - R.apply(tip) + rng.normal(0, 2e-4, (n, 3))
    else:                                            # dwells: still, moving, still, ...
        k = max(1, n // 40)
        stops = rng.uniform(-0.05, 0.05, (k, 3)) + pivot
        key = np.repeat(stops, 2, axis=0)
        tk = np.cumsum(np.tile([1.0, 0.6], k))
        t = np.linspace(0, tk[-1] + 0.6, n)
        p = np.stack([np.interp(t, np.r_[0.0, tk], np.r_[key[:1, a], key[:, a]])
                      for a in range(3)], axis=1) + rng.normal(0, 5e-5, (n, 3))
        R = _rotations(rng, 1, 0.3)[[0] * n]
        return pose_from_rt(R.as_matrix(), p), t
    return pose_from_rt(R.as_matrix(), p), np.arange(n) / 40.0


def _damage(rng, P, status, times, matrices: bool):
    """Random damage in place; returns its names (``rotation`` marks damaged rotations, made
    only where the file stores matrices: a CSV stores rotation vectors)."""
    names = []
    n = len(P)
    for _ in range(rng.integers(0, 3)):
        what = rng.choice(["scale", "shear", "reflect"] * matrices
                          + ["nan", "inf", "huge", "status", "times", "few", "same"])
        rows = rng.choice(n, size=max(1, int(rng.integers(1, max(2, n // 4)))), replace=False)
        if what in ("scale", "shear", "reflect"):
            M = {"scale": np.eye(3) * rng.choice([2.0, 0.5, 1.001]),
                 "shear": np.array([[1, rng.uniform(0.01, 1), 0], [0, 1, 0], [0, 0, 1.0]]),
                 "reflect": np.diag([1.0, 1.0, -1.0])}[what]
            P[rows, :3, :3] = P[rows, :3, :3] @ M
        elif what == "nan":
            P[rows, rng.integers(0, 3), 3] = np.nan
        elif what == "inf":
            P[rows, 0, 3] = np.inf
        elif what == "huge":
            P[rows, :3, 3] *= 10.0 ** rng.integers(3, 300)
        elif what == "status":
            status[rows] = rng.integers(1, 6)
        elif what == "times":
            times[rows] = times[rows] - rng.uniform(0, 5)
        elif what == "few":
            P[int(rng.integers(1, 12)):] = np.nan
        else:
            P[:] = P[0]
        names.append(str(what))
    # damaged rotations that survive the other damage (NaN rows, copies of row 0)
    ok = np.all(np.isfinite(P), axis=(1, 2))
    R = P[ok, :3, :3]
    if len(R) and (np.any(np.abs(np.einsum("nki,nkj->nij", R, R) - np.eye(3)) > 1e-4)
                   or np.any(np.linalg.det(R) < 0)):
        names.append("rotation")
    return names


def _write(path: Path, kind, P, status, times):
    """Write poses as ``kind``; returns the path."""
    from openemt.geometry import vector_from_pose
    from openemt.io import pose_dataset, write_dataset, write_poses_csv

    if kind == "pose-csv":
        write_poses_csv(path.with_suffix(".csv"), P, time=times)
        return path.with_suffix(".csv")
    if kind == "dataset":
        write_dataset(pose_dataset(P, file_index=np.zeros(len(P), int), files=["fuzz"],
                                   extra={"times": times}), path.with_suffix(".h5"))
        return path.with_suffix(".h5")
    if kind == "log-csv":
        v = vector_from_pose(P)
        rows = np.column_stack([times, v, status, np.zeros((len(P), 3))])
        np.savetxt(path.with_suffix(".csv"), rows, delimiter=",", comments="",
                   header="time_s,x_m,y_m,z_m,rx_rad,ry_rad,rz_rad,status,residual,distortion,"
                          "distorted", fmt=["%.6f"] + ["%.9g"] * 6 + ["%d", "%g", "%g", "%d"])
        return path.with_suffix(".csv")
    import h5py

    rng = np.random.default_rng(len(P) + int(np.nansum(np.isfinite(P))))
    with h5py.File(path.with_suffix(".h5"), "w") as f:
        f.attrs.update({"format": "openemt-track", "version": 1, "complete": True,
                        "rows": len(P)})
        f["times"], f["pose_vectors"] = times, np.zeros((len(P), 6))
        f["status"] = status.astype(np.int8)
        for k in ("residual", "distortion"):
            f[k] = np.zeros(len(P))
        f["distorted"] = np.zeros(len(P), bool)
        broken = str(rng.choice(["none"] * 6 + ["rows", "version", "shape", "status", "dtype",
                                                 "times"]))
        if broken == "rows":
            f.attrs["rows"] = ["x", -5, 10 ** 12, 2.5][int(rng.integers(0, 4))]
        elif broken == "version":
            f.attrs["version"] = [2, "two"][int(rng.integers(0, 2))]
        elif broken == "shape":
            P = P[:, :3, :3]
        elif broken == "status":
            del f["status"]
            f["status"] = np.zeros((len(P), 2), np.int8)
        elif broken == "dtype":
            P = P.astype(np.complex128) + 1j
        elif broken == "times":
            del f["times"]
            f["times"] = np.zeros(1)
        f["poses"] = P
    return path.with_suffix(".h5")


def _markups(rng, path, pts, labels):
    from openemt.navigate import write_markups

    write_markups(path, pts, labels)
    return path


def _case(rng, folder: Path):
    """(argv, expectations) of one generated case."""
    cmd = str(rng.choice(["pivot", "spin", "register", "assess", "points"]))
    n = int(rng.integers(5, 120))
    if cmd == "register":
        k = int(rng.integers(2, 12))
        moving = rng.uniform(-0.08, 0.08, (k, 3))
        fixed = _rotations(rng, 1, 1.0).apply(moving) + rng.uniform(-0.1, 0.1, 3)
        damage = []
        if rng.random() < 0.3:
            moving[:, 1:] = moving[:, :1] * [2.0, -1.0]                  # collinear
            damage.append("collinear")
        if rng.random() < 0.2:
            moving[rng.integers(0, k)] *= 10.0 ** rng.integers(3, 300)
            damage.append("huge")
        labels = [f"F-{i}" for i in range(k)]
        ml = list(labels)
        if rng.random() < 0.3:
            ml[int(rng.integers(0, k))] = "X"
            damage.append("labels")
        perm = rng.permutation(k)
        f = _markups(rng, folder / "fixed.mrk.json", fixed, labels)
        m = _markups(rng, folder / ("moving.fcsv" if rng.random() < 0.5 else "moving.mrk.json"),
                     moving[perm], [ml[i] for i in perm])
        argv = ["register", f, m, "-o", folder / "reg.json", "--slicer-transform",
                folder / "reg.tfm", "--json"]
        return argv, {"rows": None, "damage": damage}
    motion = {"pivot": "pivot", "spin": "spin"}.get(cmd, "dwells")
    P, times = _poses(rng, motion, n)
    if cmd == "assess":                           # a grid, rotated, shifted, with noise
        from openemt.navigate import regular_grid

        shape = [int(rng.integers(1, 6)) for _ in range(3)]
        pitch = rng.uniform(5, 60)
        nodes = regular_grid(1e-3 * pitch, shape)
        n = len(nodes)
        P = np.tile(P[:1], (n, 1, 1))
        P[:, :3, 3] = _rotations(rng, 1, 1.0).apply(nodes) + rng.normal(0, 2e-4, (n, 3))
        times = np.arange(n) / 40.0
    status = np.zeros(n, np.int64)
    kind = str(rng.choice(["pose-csv", "log-csv", "log-h5", "dataset"]))
    damage = _damage(rng, P, status, times, matrices=kind in ("log-h5", "dataset"))
    path = _write(folder / "poses", kind, P, status, times)
    if cmd == "assess":
        match = str(rng.choice(["order", "nearest"]))
        argv = ["assess", path, "--grid-pitch-mm", f"{pitch:.6f}",
                "--grid-shape", ",".join(map(str, shape)), "--match", match, "--json"]
    elif cmd == "points":
        argv = ["points", path, "-o", folder / "pts.mrk.json", "--json"]
    else:
        argv = [cmd, path, "-o", folder / f"{cmd}.json", "--json"]
        if rng.random() < 0.3:
            argv += ["--method", "ransac"]
    return argv, {"rows": n, "damage": damage}


def _outcome(argv, expect, rc, out, err) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    if rc == 2:
        return "refused" if len(lines) == 1 and lines[0].startswith("error: ") else "vague"
    if rc != 0:
        return "crash"
    try:
        s = json.loads(out)
    except ValueError:
        return "garbage"
    if "rotation" in expect["damage"] and argv[0] in ("pivot", "spin", "points", "assess"):
        return "garbage"                         # an answer from blocks that are not rotations
    finite = {"pivot": ("tip_mm", "pivot_mm", "rms_mm"), "spin": ("axis", "rms_deg"),
              "register": ("transform", "fre_rms_mm"), "assess": ("rigid_rms_mm",),
              "points": ("points_mm",)}[argv[0]]
    if not all(np.all(np.isfinite(np.asarray(s[k], dtype=float))) for k in finite):
        return "garbage"
    if expect["rows"] is not None and argv[0] in ("pivot", "spin"):
        if s["n"] + sum(s["dropped"].values()) != expect["rows"]:
            return "garbage"
    return "ok"


def fuzz_navigate(n_cases: int, seed: int = 0, *, time_limit: float = 30.0,
                  progress=lambda k: None) -> dict:
    """Run ``n_cases`` generated navigation cases; counts, examples and the largest cost."""
    from openemt.cli import main

    rng = np.random.default_rng(random.Random(seed).getrandbits(64))
    counts: dict = {}
    examples: list = []
    worst_s, worst_rss = 0.0, 0
    with tempfile.TemporaryDirectory(prefix="openemt-fuzz-nav-") as tmp:
        for k in range(n_cases):
            folder = Path(tmp) / f"c{k}"
            folder.mkdir()
            out, err = io.StringIO(), io.StringIO()
            argv, expect = _case(rng, folder)           # a failure here is the harness's
            rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
            t0 = time.perf_counter()
            try:
                with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
                    rc = main([str(a) for a in argv])
                kind = _outcome(argv, expect, rc, out.getvalue(), err.getvalue())
            except Exception as exc:  # noqa: BLE001 - counted as a finding
                kind = "crash"
                err.write(f"{type(exc).__name__}: {exc}")
            dt = time.perf_counter() - t0
            if dt > time_limit:
                kind = "slow"
            worst_s = max(worst_s, dt)
            worst_rss = max(worst_rss, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss0)
            by = counts.setdefault(str(argv[0]), {})
            by[kind] = by.get(kind, 0) + 1
            if kind in _FINDINGS and len(examples) < 20:
                examples.append({"command": str(argv[0]), "outcome": kind,
                                 "damage": expect["damage"],
                                 "message": (err.getvalue().strip()[-300:])})
            progress(1)
    findings = sum(c.get(k, 0) for c in counts.values() for k in _FINDINGS)
    return {"cases": n_cases, "findings": findings, "by_command": counts,
            "examples": examples, "max_seconds_per_case": round(worst_s, 3),
            "max_peak_rss_growth_mib": round(worst_rss / 1024, 1)}
