"""Generated cases for output corrections (``openemt bench fuzz``, section ``corrections``).

Every case starts from a correction fitted on pairs in a 0.1 m box (one per method) and is one
of:

``far_poses``
    poses at random distances outside the box (1 mm to 1e300 m, any direction), inside it,
    and non-finite rows, corrected with a random margin: every finite row comes out finite;
    rows beyond the margin keep their input values; a corrected row moves by at most the
    box's diagonal (50 mm at least); non-finite rows are flagged; the counts add up;
``degenerate_file``
    a valid-JSON correction file made degenerate (a projective denominator that vanishes at
    a random point of the box, huge or non-finite coefficients, a tiny or huge scale, a
    broken box, duplicated RBF centres without smoothing): either refused with one
    ``correction file ...: expected ...`` line, or read and then correcting poses of its box
    gives finite poses moved by at most the limit;
``huge_size``
    declared sizes far past the limits (RBF centres, polynomial orders, grid nodes, Bernstein
    degrees): refused with the limit named, within the time limit;
``workflow``
    ``apply_correction_file`` on a CSV of far and non-finite poses with a possibly degenerate
    file: an InputError leaves no output; an output holds a status per row that agrees with
    the poses written.

The summary counts cases, ``held`` and ``findings`` per kind, the largest time (s) of a case
and the largest peak resident memory of the process during a case (MB, Linux ``VmHWM`` reset
before each case; the process's own baseline included), and up to 20 examples.
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["KINDS", "fuzz_corrections"]

KINDS = ("far_poses", "degenerate_file", "huge_size", "workflow")
_TRACE = False
_METHODS = ("poly", "dlt", "rbf", "grid", "bernstein", "none")


def box_pairs(n: int = 150, seed: int = 0):
    """(measured, reference) poses in a 0.1 m box around (0, 0, 0.2) m with a smooth
    mm-level position distortion (identity rotations)."""
    rng = np.random.default_rng(seed)
    ref = np.tile(np.eye(4), (n, 1, 1))
    ref[:, :3, 3] = rng.uniform(-0.05, 0.05, (n, 3)) + [0, 0, 0.2]
    meas = ref.copy()
    meas[:, :3, 3] += 1e-3 * np.sin(20 * ref[:, :3, 3]) + 0.05 * ref[:, :3, 3] ** 2
    return meas, ref


def _seed_corrections():
    from openemt.correct import fit_correction

    meas, ref = box_pairs()
    return {m: fit_correction(meas, ref, m, cross_validate=False,
                              **({"degree": 2} if m == "bernstein" else {}))
            for m in _METHODS}


def _random_rotations(rng, n):
    from scipy.spatial.transform import Rotation

    return Rotation.random(n, random_state=int(rng.integers(2**31))).as_matrix()


def _poses(rng, box, n):
    """Poses inside the box, at random distances outside it and non-finite rows."""
    P = np.tile(np.eye(4), (n, 1, 1))
    P[:, :3, :3] = _random_rotations(rng, n)
    P[:, :3, 3] = rng.uniform(box.lower, box.upper, (n, 3))
    far = rng.random(n) < 0.6
    d = rng.standard_normal((n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    dist = 10.0 ** rng.uniform(-3, 300, n)
    with np.errstate(over="ignore", invalid="ignore"):
        P[far, :3, 3] += d[far] * dist[far, None]
    P[~np.all(np.isfinite(P[:, :3, 3]), axis=1), :3, 3] = 1e300  # overflowed: very far
    bad = rng.random(n) < 0.15
    P[bad, rng.integers(0, 3), rng.choice([3, 0])] = rng.choice([np.nan, np.inf, -np.inf])
    return P


def _check_applied(corr, P, res, margin) -> str | None:
    from openemt.correct import STATUS, max_shift

    code = {v: k for k, v in STATUS.items()}
    out, st = res.values, res.status
    finite = np.all(np.isfinite(P), axis=(1, 2))
    if sum(res.counts.values()) != len(P):
        return f"counts {res.counts} do not add up to {len(P)} rows"
    if np.any(st[~finite] != code["nonfinite_input"]):
        return "a non-finite row not flagged nonfinite_input"
    if not np.all(np.isfinite(out[finite])):
        return "a finite pose came out non-finite"
    moved = np.any(out != P, axis=(1, 2)) & finite
    if np.any(moved & ~np.isin(st, [code["corrected"], code["extrapolated"],
                                    code["unchecked"]])):
        return "a pose flagged as not corrected was changed"
    with np.errstate(all="ignore"):
        shift = np.linalg.norm(out[:, :3, 3] - P[:, :3, 3], axis=1)
    if np.any(shift[moved] > max_shift(corr.box) * (1 + 1e-12)):
        return f"a pose moved by {1e3 * shift[moved].max():.4g} mm"
    if corr.box is not None:
        beyond = corr.box.distance(P[:, :3, 3]) > margin
        if np.any(beyond & moved):
            return "a pose beyond the margin was corrected"
        inside = corr.box.distance(P[:, :3, 3]) == 0
        if np.any(inside & finite & (st == code["outside_box"])):
            return "a pose inside the box flagged outside_box"
    R = out[finite, :3, :3]
    if not np.allclose(R @ np.swapaxes(R, 1, 2), np.eye(3), atol=1e-6):
        return "a rotation block is not a rotation"
    return None


def _degenerate(rng, doc, box):
    """A random degenerate change of a correction document (in place); its name."""
    p = doc["params"]
    m = doc["method"]
    pt = rng.uniform(box.lower, box.upper)
    big = float(rng.choice([1e300, -1e300, 1e30, 1e6, -1e3, 2.0]))
    options = ["box_nan", "box_inverted", "box_huge"]
    if m == "dlt":
        options += ["dlt_vanish", "dlt_w_is_x", "dlt_huge"]
    if m in ("poly", "rbf"):
        options += ["tiny_scale", "huge_scale"]
    if m in ("poly", "bernstein"):
        options += ["huge_coef"]
    if m in ("grid", "rbf"):
        options += ["huge_value"]
    if m == "rbf":
        options += ["rbf_duplicates"]
    kind = str(rng.choice(options))
    if kind == "box_nan":
        doc["box"]["lower_m"][int(rng.integers(3))] = float("nan")
    elif kind == "box_inverted":
        doc["box"]["lower_m"], doc["box"]["upper_m"] = doc["box"]["upper_m"], doc["box"]["lower_m"]
    elif kind == "box_huge":
        doc["box"]["upper_m"] = [v + 10.0 ** rng.uniform(0, 300) for v in doc["box"]["upper_m"]]
    elif kind == "dlt_vanish":
        row = rng.standard_normal(3)
        p["matrix"][3] = [*row.tolist(), float(-row @ pt)]
    elif kind == "dlt_w_is_x":
        a = int(rng.integers(3))
        p["matrix"][3] = [1.0 if i == a else 0.0 for i in range(3)] + [float(-pt[a])]
    elif kind == "dlt_huge":
        p["matrix"][int(rng.integers(4))][int(rng.integers(4))] = big
    elif kind == "tiny_scale":
        p["scale"] = float(10.0 ** -rng.uniform(10, 300))
    elif kind == "huge_scale":
        p["scale"] = float(10.0 ** rng.uniform(3, 300))
    elif kind == "huge_coef":
        key = "pos_coef" if p.get("rot_coef") is None or rng.random() < 0.5 else "rot_coef"
        c = p[key]
        c[int(rng.integers(len(c)))][int(rng.integers(3))] = big
    elif kind == "huge_value":
        v = np.asarray(p["values"])
        flat = v.reshape(-1)
        flat[int(rng.integers(flat.size))] = big
        p["values"] = v.tolist()
    elif kind == "rbf_duplicates":
        p["points"] = [p["points"][0]] * len(p["points"])
        p["smoothing"] = 0.0
    return kind


def _huge(rng, doc):
    """Declare a size far past a limit; the limit's name the error must carry."""
    from openemt.correct import MAX_RBF_CENTRES

    p = doc["params"]
    m = doc["method"]
    if m == "rbf":
        n = int(rng.integers(MAX_RBF_CENTRES + 1, 4 * MAX_RBF_CENTRES))
        p["points"] = np.zeros((n, 3)).tolist()
        p["values"] = np.zeros((n, np.shape(p["values"])[1])).tolist()
        return "MAX_RBF_CENTRES"
    if m == "poly":
        p["pos_order"] = int(10 ** rng.uniform(1.5, 9))
        return "MAX_POLY_ORDER|pos_coef"
    if m == "bernstein":
        p["pos_degree"] = int(10 ** rng.uniform(1.2, 9))
        return "pos_degree"
    if m == "grid":
        p["shape"] = [int(10 ** rng.uniform(2, 9)) for _ in range(3)]
        return "values|shape"
    if m == "dlt":
        p["matrix"] = np.eye(int(rng.integers(5, 300))).tolist()
        return "shape"
    return None


def _one(kind, rng, seeds, folder) -> str | None:
    from openemt._errors import InputError
    from openemt.correct import (
        ApplyOptions,
        Correction,
        apply_correction_file,
        read_correction,
    )
    from openemt.io import read_poses_csv, write_poses_csv

    method = str(rng.choice(_METHODS if kind == "far_poses" else _METHODS[:5]))
    corr = seeds[method]
    margin = float(rng.choice([0.0, 0.0, 1e-3, 1.0, 1e6, 1e300]))
    if kind == "far_poses":
        P = _poses(rng, corr.box, int(rng.integers(1, 200)))
        if rng.random() < 0.3:  # positions only: checked as poses of identity rotation
            from types import SimpleNamespace

            P[:, :3, :3] = np.eye(3)
            res = corr.correct(P[:, :3, 3], extrapolate_margin=margin)
            out = P.copy()
            out[:, :3, 3] = res.values
            res = SimpleNamespace(values=out, status=res.status, counts=res.counts)
        else:
            res = corr.correct(P, extrapolate_margin=margin)
        return _check_applied(corr, P, res, margin)
    doc = json.loads(json.dumps(corr.to_dict()))
    path = Path(folder) / "corr.json"
    want = None
    if kind == "huge_size":
        want = _huge(rng, doc)
    else:
        _degenerate(rng, doc, corr.box)
    path.write_text(json.dumps(doc))
    if kind == "workflow":
        P = _poses(rng, corr.box, int(rng.integers(1, 60)))
        write_poses_csv(Path(folder) / "in.csv", P)
        out = Path(folder) / "out.csv"
        out.unlink(missing_ok=True)
        try:
            res = apply_correction_file(ApplyOptions(str(path), str(Path(folder) / "in.csv"),
                                                     str(out), extrapolate_margin=margin))
        except InputError as exc:
            if out.exists():
                return "an output was left after an error"
            return _one_line(exc)
        t = read_poses_csv(out)
        col = [ln.rsplit(",", 1)[1] for ln in out.read_text().splitlines()[1:]]
        if len(col) != len(P) or sum(res.counts.values()) != len(P):
            return "the status column or counts do not cover every row"
        fin = np.all(np.isfinite(P), axis=(1, 2))
        if not np.all(np.isfinite(t.poses[fin])):
            return "a finite pose was written non-finite"
        return None
    try:
        c = read_correction(path)
    except InputError as exc:
        msg = _one_line(exc)
        if msg is None and want is not None:
            import re

            if not re.search(want + "|at most", str(exc)):
                return f"refused without naming the limit ({want}): {exc}"[:200]
        return msg
    if want is not None:
        return f"a declared size past the limit was accepted ({want})"
    if not isinstance(c, Correction):
        return "read_correction returned something else"
    P = _poses(rng, c.box if c.box is not None else corr.box, 50)
    return _check_applied(c, P, c.correct(P, extrapolate_margin=margin,
                                          allow_unknown_box=True), margin)


def _one_line(exc) -> str | None:
    msg = str(exc)
    if "\n" in msg or not msg.startswith(("correction file", "expected")):
        return f"not one clear line: {msg[:160]!r}"
    return None


def _reset_peak() -> None:
    """Reset the process's peak resident memory (Linux: ``clear_refs`` 5), where allowed."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        pass


def _peak_mb() -> float | None:
    """Peak resident memory (MB) of this process since :func:`_reset_peak` (VmHWM)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return None


def fuzz_corrections(n_cases: int, seed: int = 0, *, time_limit: float = 30.0,
                     progress=None) -> dict:
    """Run ``n_cases`` generated correction cases (kinds in turn); the summary described in
    the module docstring."""
    rng = np.random.default_rng(seed)
    seeds = _seed_corrections() if n_cases else {}
    counts = {k: {"cases": 0, "held": 0, "findings": 0} for k in KINDS}
    examples = []
    worst_s, worst_mb = 0.0, 0.0
    with tempfile.TemporaryDirectory(prefix="openemt-fuzz-correct-") as folder:
        for i in range(n_cases):
            kind = KINDS[i % len(KINDS)]
            _reset_peak()
            t0 = time.perf_counter()
            try:
                with np.errstate(all="ignore"):
                    problem = _one(kind, rng, seeds, folder)
            except Exception as exc:  # noqa: BLE001 - any other exception is a finding
                problem = f"crash: {type(exc).__name__}: {exc}"[:200]
            dt = time.perf_counter() - t0
            peak = _peak_mb()
            if _TRACE:
                print(i, kind, round(dt, 2), round(peak, 1), problem, flush=True)
            if problem is None and dt > time_limit:
                problem = f"took {dt:.1f} s (limit {time_limit:g} s)"
            worst_s = max(worst_s, dt)
            worst_mb = None if peak is None or worst_mb is None else max(worst_mb, peak)
            c = counts[kind]
            c["cases"] += 1
            if problem is None:
                c["held"] += 1
            else:
                c["findings"] += 1
                if len(examples) < 20:
                    examples.append({"case": i, "kind": kind, "problem": problem})
            if progress is not None:
                progress(1)
    return {"cases": n_cases, "findings": sum(c["findings"] for c in counts.values()),
            "by_kind": counts, "max_seconds_per_case": round(worst_s, 3),
            "max_peak_rss_mb_per_case": None if worst_mb is None else round(worst_mb, 1), "seed": seed, "examples": examples}
