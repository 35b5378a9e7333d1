"""The ``correct fit`` and ``correct apply`` workflows: an options record in, a result out.

``fit_correction_files`` reads pose-pair files (CSV with ``ref_`` columns, or pose datasets
with reference poses), fits a correction (or chooses one with ``method="auto"``) and writes
it; ``apply_correction_file`` corrects the poses of a file inside the correction's fitted box
and writes them with a status per row (docs/correction.md#the-fitted-box).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .._errors import InputError, check_nonnegative
from .._options import option
from .._result import Result
from ._model import _summary, check_margin, read_correction, write_correction
from ._region import STATUS

__all__ = ["ApplyOptions", "ApplyResult", "FitOptions", "FitResult", "apply_correction_file",
           "fit_correction_files"]

_METHODS = ("auto", "none", "dlt", "poly", "bernstein", "grid", "rbf")
_UNITS = {
    "length_unit": option("m", "unit of position columns without a _m/_mm suffix",
                          choices=("m", "mm")),
    "angle_unit": option("rad", "unit of rotation-vector columns without a _rad/_deg suffix",
                         choices=("rad", "deg")),
}


def _out(help_text):
    return option(None, help_text, flag=("-o", "--output"))


@dataclass(frozen=True)
class FitOptions:
    """Options of :func:`fit_correction_files` (``openemt correct fit``)."""

    pairs: tuple[str, ...] | None = option(
        None, "pose-pair CSV file(s) with ref_ columns (or pose datasets with reference poses)",
        positional=True)
    output: str | None = _out("correction JSON to write (required)")
    method: str = option("poly", "correction method; auto: the lowest held-out error, none "
                         "included", choices=_METHODS)
    folds: int = option(5, "k of the k-fold held-out errors (2 to 20)")
    seed: int = option(0, "seed of the folds (and RBF subsample)")
    holdout_files: bool = option(False, "hold out one input file at a time instead of k random "
                                 "folds")
    order: int | None = option(None, "poly: position order (default: by CV, 1-5)")
    rot_order: int | None = option(None, "poly: orientation order (default: by CV)")
    degree: int | None = option(None, "bernstein: position degree per axis (default: by CV, "
                                "1-6)")
    rot_degree: int | None = option(None, "bernstein: orientation degree (default: by CV)")
    grid_shape: str | None = option(None, "grid: nodes per axis, e.g. 5,5,5")
    smoothing: float | None = option(None, "grid/rbf smoothing (default: by CV)")
    positions_only: bool = option(False, "correct positions only, even if orientations are "
                                  "given")
    average_static: bool = option(False, "average samples with the same pose_id before "
                                  "fitting")
    length_unit: str = _UNITS["length_unit"]
    angle_unit: str = _UNITS["angle_unit"]


@dataclass(frozen=True)
class ApplyOptions:
    """Options of :func:`apply_correction_file` (``openemt correct apply``)."""

    correction: str | None = option(None, "correction JSON written by 'correct fit'",
                                    positional=True)
    poses: str | None = option(
        None, "pose CSV or pose dataset (.h5) to correct (reference poses optional)",
        positional=True)
    output: str | None = _out("corrected poses to write: pose dataset if it ends in .h5, "
                              "else CSV (required); a status per row says what was corrected")
    extrapolate_margin: float = option(
        0.0, "also correct poses up to M metres outside the fitted box (flagged "
        "'extrapolated'); default 0: poses outside the box are passed through uncorrected "
        "and flagged 'outside_box'", metavar="M")
    allow_unknown_box: bool = option(
        False, "apply a version-1 DLT or polynomial file (no fitted box recorded) to every "
        "pose, flagged 'unchecked' (refused otherwise)")
    length_unit: str = _UNITS["length_unit"]
    angle_unit: str = _UNITS["angle_unit"]


def _is_h5(path) -> bool:
    return str(path).lower().endswith((".h5", ".hdf5"))


def _need_output(output) -> str:
    if not output:
        raise InputError("expected an output file (-o/--output), got none")
    return str(output)


def _read_one(opts, path):
    """(measured, reference, pose_id or None, has_rotations, row report) of one pairs file."""
    from ..io import read_pose_dataset, read_poses_csv

    if _is_h5(path):
        ds = read_pose_dataset(path)
        ref = ds.extra.get("reference_poses")
        if ref is None:
            raise InputError(f"expected reference poses (extra/reference_poses) in {path}, got "
                             f"none (write pose pairs with 'openemt align')")
        ok = np.all(np.isfinite(ds.poses), axis=(1, 2)) & np.all(np.isfinite(ref), axis=(1, 2))
        bad = np.flatnonzero(~ok)
        row = {"file": str(path), "n_rows": ds.n_samples, "n_bad_rows": 0, "bad_lines": [],
               "n_nonfinite_rows": len(bad), "nonfinite_rows": bad[:20].tolist(),
               "nonfinite_lines": []}
        return ds.poses, np.asarray(ref, dtype=float), None, True, row
    t = read_poses_csv(path, length_unit=opts.length_unit, angle_unit=opts.angle_unit)
    if t.reference is None:
        raise InputError(f"expected reference columns ref_x, ref_y, ref_z in {path}, got none")
    row = {"file": str(path), "n_rows": len(t), "n_bad_rows": len(t.bad_lines),
           "bad_lines": list(t.bad_lines[:20]), "n_nonfinite_rows": len(t.nonfinite_lines),
           "nonfinite_lines": list(t.nonfinite_lines[:20])}
    return (t.poses, t.reference, t.group,
            t.has_orientation and t.reference_has_orientation, row)


def _read_pairs(opts):
    from ..io import average_static

    if not opts.pairs:
        raise InputError("expected at least one pose-pair file, got none")
    M, D, groups, rot, rows = [], [], [], True, []
    for i, path in enumerate(opts.pairs):
        Pm, Pd, group, has_rot, row = _read_one(opts, path)
        rot &= has_rot
        rows.append(row)
        if opts.average_static:
            if group is None:
                raise InputError(f"expected a pose_id column for --average-static in {path}, "
                                 f"got none")
            # rows not used (reported above) must not shift the groups of either side
            ok = np.all(np.isfinite(Pm), axis=(1, 2)) & np.all(np.isfinite(Pd), axis=(1, 2))
            Pm, Pd, group = Pm[ok], Pd[ok], group[ok]
            Pm, Pd = average_static(Pm, group).poses, average_static(Pd, group).poses
        M.append(Pm)
        D.append(Pd)
        groups.append(np.full(len(Pm), i))
    return np.concatenate(M), np.concatenate(D), np.concatenate(groups), rot, rows


def _method_options(opts, method) -> dict:
    out = {}
    for name, for_method in (("order", "poly"), ("rot_order", "poly"), ("degree", "bernstein"),
                             ("rot_degree", "bernstein")):
        if method == for_method and getattr(opts, name) is not None:
            out[name] = getattr(opts, name)
    if method in ("grid", "rbf") and opts.smoothing is not None:
        out["smoothing"] = check_nonnegative(opts.smoothing, "--smoothing")
    if method == "grid" and opts.grid_shape:
        try:
            out["shape"] = tuple(int(v) for v in opts.grid_shape.split(","))
        except ValueError:
            raise InputError(f"expected --grid-shape like 5,5,5, got {opts.grid_shape!r}") \
                from None
    return out


def _row_warnings(rows) -> list:
    out = []
    for r in rows:
        parts = []
        if r["n_bad_rows"]:
            parts.append(f"{r['n_bad_rows']} of the wrong length (lines "
                         f"{', '.join(map(str, r['bad_lines']))})")
        if r["n_nonfinite_rows"]:
            where = (f"lines {', '.join(map(str, r['nonfinite_lines']))}"
                     if r["nonfinite_lines"] else
                     f"rows {', '.join(map(str, r.get('nonfinite_rows', [])))}")
            parts.append(f"{r['n_nonfinite_rows']} with missing or non-finite values ({where})")
        if parts:
            out.append(f"{r['file']}: rows not used: " + "; ".join(parts))
    return out


def _selected(corr) -> dict:
    p = corr.params
    keys = {"none": (), "dlt": ("method", "refined"), "poly": ("pos_order", "rot_order"),
            "bernstein": ("pos_degree", "rot_degree", "lower", "upper"),
            "grid": ("shape", "smoothing"), "rbf": ("smoothing", "kernel")}[corr.method]
    return {k: p.get(k) for k in keys}


def _fmt(s) -> str:
    rot = f", {s['rot_rms_deg']:.4f} deg" if "rot_rms_deg" in s else ""
    return f"{s['trans_rms_mm']:.4f} mm{rot}"


@dataclass(frozen=True)
class FitResult(Result):
    """What :func:`fit_correction_files` did (``--json`` of ``correct fit``); ``correction`` is
    the fitted :class:`~openemt.correct.Correction` (not in ``to_dict()``)."""

    output: str
    method: str
    method_requested: str
    n: int
    n_dropped: int
    input_rows: list
    positions_only: bool
    selected: dict
    in_sample: dict
    held_out: dict
    requirements: dict
    worse_than_none: bool
    box: dict
    warnings: list
    auto: dict | None = None
    correction: object = None
    _not_in_dict = ("correction",)

    def _items(self) -> dict:
        d = super()._items()
        if d["auto"] is None:
            del d["auto"]
        return d

    def lines(self) -> list:
        """Human summary: RMS errors per method, in-sample beside held-out (an exact
        interpolant's 0 mm in-sample figure never stands alone), "none" first."""
        ho = self.held_out
        lines = [f"{self.method} correction on {self.n} pairs (RMS):",
                 f"  {'method':<14s} {'in sample':<28s} held out ({ho['scheme']})"]
        rows = [("none", self.in_sample["uncorrected"], ho["uncorrected"])]
        if self.auto is not None:
            for m, c in self.auto["candidates"].items():
                if m == "none":
                    continue
                if "skipped" in c:
                    rows.append((f"  {m:<14s} skipped: {c['skipped']}", None, None))
                    continue
                rows.append((m + (" (chosen)" if m == self.method else ""), c["in_sample"],
                             c["held_out"]))
        elif self.method != "none":
            rows.append((self.method, self.in_sample["corrected"], ho["corrected"]))
        for label, ins, out in rows:
            lines.append(label if ins is None else f"  {label:<14s} {_fmt(ins):<28s} "
                                                   f"{_fmt(out)}")
        lo, hi = self.box["lower_m"], self.box["upper_m"]
        lines.append("  fitted box (mm): " + ", ".join(
            f"{1e3 * a:.1f}..{1e3 * b:.1f}" for a, b in zip(lo, hi))
            + " - 'correct apply' passes poses outside it through, flagged")
        return lines


def fit_correction_files(options: FitOptions) -> FitResult:
    """Read the pose pairs of ``options.pairs``, fit the correction and write it to
    ``options.output`` (see :func:`openemt.correct.fit_correction`; ``method="auto"``:
    :func:`openemt.correct.fit_auto_correction`)."""
    from ._crossval import check_folds
    from ._model import fit_correction
    from ._select import fit_auto_correction

    opts = options
    output = _need_output(opts.output)
    if not opts.holdout_files:
        check_folds(opts.folds, "--folds")
    M, D, file_groups, has_rot, rows = _read_pairs(opts)
    positions_only = opts.positions_only or not has_rot
    measured = M[:, :3, 3] if positions_only else M
    reference = D[:, :3, 3] if positions_only else D
    groups = file_groups if opts.holdout_files else None
    meta = {"inputs": [str(p) for p in opts.pairs], "positions_only": positions_only}
    if opts.method == "auto":
        corr = fit_auto_correction(
            measured, reference, k=opts.folds, seed=opts.seed, groups=groups, meta=meta,
            method_options={m: _method_options(opts, m)
                            for m in ("poly", "bernstein", "grid", "rbf")})
    else:
        corr = fit_correction(measured, reference, opts.method, k=opts.folds, seed=opts.seed,
                              groups=groups, meta=meta, **_method_options(opts, opts.method))
    write_correction(corr, output)
    st = corr.stats
    return FitResult(
        output=output, method=corr.method, method_requested=opts.method, n=st["n"],
        n_dropped=int(sum(r["n_bad_rows"] + r["n_nonfinite_rows"] for r in rows)),
        input_rows=rows, positions_only=positions_only, selected=_selected(corr),
        in_sample=st["in_sample"], held_out=st["held_out"], requirements=st["requirements"],
        worse_than_none=st["worse_than_none"], box=corr.box.to_dict(),
        warnings=_row_warnings(rows) + list(st["warnings"]), auto=st.get("auto"),
        correction=corr)


@dataclass(frozen=True)
class ApplyResult(Result):
    """What :func:`apply_correction_file` did (``--json`` of ``correct apply``).

    ``counts`` holds the rows per status (:data:`openemt.correct.STATUS`); ``errors`` (with
    reference poses in the input) the errors of the input and of the written poses over the
    rows finite in both; ``max_outside_mm`` the largest distance of a finite pose outside the
    box (0 if all inside, None without a known box).
    """

    output: str
    method: str
    n: int
    orientation_corrected: bool
    box: dict | None
    extrapolate_margin_m: float
    counts: dict
    max_outside_mm: float | None
    warnings: list
    errors: dict | None = None

    def lines(self) -> list:
        c = self.counts
        out = [f"applied {self.method} correction to {c['corrected'] + c['extrapolated']} of "
               f"{self.n} poses -> {self.output}"]
        out += [f"  {name}: {v}" for name, v in c.items() if v and name != "corrected"]
        if self.errors is not None:
            for label in ("uncorrected", "corrected"):
                s = self.errors[label]
                rot = (f", rot rms {s['rot_rms_deg']:.4f} max {s['rot_max_deg']:.4f} deg"
                       if "rot_rms_deg" in s else "")
                out.append(f"  {label:<22s} trans rms {s['trans_rms_mm']:.4f} max "
                           f"{s['trans_max_mm']:.4f} mm" + rot)
        return out


def _read_poses(opts):
    from ..io import read_pose_dataset, read_poses_csv

    if _is_h5(opts.poses):
        ds = read_pose_dataset(opts.poses)
        return ds, ds.poses, ds.extra.get("reference_poses"), True, True, None, None, \
            ds.extra.get("frame")
    t = read_poses_csv(opts.poses, length_unit=opts.length_unit, angle_unit=opts.angle_unit)
    return (None, t.poses, t.reference, t.has_orientation, t.reference_has_orientation,
            t.group, t.time, t.frame)


def apply_correction_file(options: ApplyOptions) -> ApplyResult:
    """Correct the poses of ``options.poses`` with the correction file ``options.correction``
    and write them to ``options.output`` with a status per row: the ``correction`` column of
    a CSV, ``extra/correction_status`` (codes of :data:`openemt.correct.STATUS`, also in the
    file's meta) of a pose dataset. See :meth:`openemt.correct.Correction.correct`."""
    from ..io import pose_dataset, write_dataset, write_poses_csv

    opts = options
    output = _need_output(opts.output)
    if not opts.correction or not opts.poses:
        raise InputError(f"expected a correction file and a poses file, got "
                         f"{opts.correction!r} and {opts.poses!r}")
    margin = check_margin(opts.extrapolate_margin)
    corr = read_correction(opts.correction)
    ds, poses, reference, has_rot, ref_rot, group, tm, frame = _read_poses(opts)
    res = corr.correct(poses if has_rot else poses[:, :3, 3], extrapolate_margin=margin,
                       allow_unknown_box=opts.allow_unknown_box)
    P = res.values
    if not has_rot:
        P = poses.copy()
        P[:, :3, 3] = res.values
    codes = {str(k): v for k, v in STATUS.items()}
    if _is_h5(output):
        info = {"corrected_by": str(opts.correction), "correction_method": corr.method,
                "correction_status_codes": codes, "extrapolate_margin_m": margin}
        if ds is None:
            extra = {} if reference is None else {"reference_poses": reference}
            if frame is not None:
                extra["frame"] = frame
            extra["correction_status"] = res.status
            out_ds = pose_dataset(P, file_index=np.zeros(len(P), np.int64),
                                  files=[Path(opts.poses).name], extra=extra, meta=info)
        else:
            out_ds = replace(ds, poses=P, meta={**ds.meta, **info},
                             extra={**ds.extra, "correction_status": res.status})
        write_dataset(out_ds, output)
    else:
        names = np.array([STATUS[int(s)] for s in res.status], dtype=object)
        write_poses_csv(output, P, reference, group=group, time=tm, frame=frame,
                        columns={"correction": names})
    warnings = []
    c = res.counts
    if corr.box is None:
        max_out = None
        if len(P):
            warnings.append(f"{opts.correction} records no fitted box (a version-1 file): "
                            f"{c['unchecked']} poses corrected without the box check")
    else:
        d = corr.box.distance(poses[:, :3, 3])
        d = d[np.isfinite(d)]
        max_out = float(1e3 * d.max()) if d.size else 0.0
    if c["outside_box"] or c["extrapolated"]:
        warnings.append(f"{c['outside_box'] + c['extrapolated']} of {len(P)} poses are outside "
                        f"the correction's fitted box (x, y, z in mm: "
                        f"{corr.box.describe_mm()}), up to {max_out:.4g} mm: "
                        f"{c['extrapolated']} corrected within the margin of {margin:g} m, "
                        f"{c['outside_box']} passed through uncorrected")
    if c["nonfinite_input"]:
        warnings.append(f"{c['nonfinite_input']} poses with non-finite values written as read")
    if c["rejected"]:
        warnings.append(f"{c['rejected']} poses whose correction came out non-finite or moved "
                        f"the position by more than the box's diagonal, passed through")
    errors = None
    if reference is not None:
        both = has_rot and ref_rot
        ok = np.all(np.isfinite(poses), axis=(1, 2)) & np.all(np.isfinite(reference),
                                                               axis=(1, 2))
        sel = (lambda A: A[ok]) if both else (lambda A: A[ok, :3, 3])
        split = (lambda A: (A[:, :3, 3], A[:, :3, :3])) if both else (lambda A: (A, None))
        if ok.any():
            errors = {"uncorrected": _summary(*split(sel(poses)), *split(sel(reference))),
                      "corrected": _summary(*split(sel(P)), *split(sel(reference))),
                      "n": int(ok.sum())}
    return ApplyResult(
        output=output, method=corr.method, n=len(P),
        orientation_corrected=bool(corr.corrects_orientation and has_rot),
        box=None if corr.box is None else corr.box.to_dict(), extrapolate_margin_m=margin,
        counts=c, max_outside_mm=max_out, warnings=warnings, errors=errors)
