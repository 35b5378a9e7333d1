"""``openemt solve`` as a library workflow: every row of a dataset file solved with a
calibration's model into a poses file (:func:`solve_file`, options :class:`SolveFileOptions`,
result :class:`SolveFileResult`), block by block in this process or on a Dask cluster
(:func:`~openemt.solve.solve_to_file`), with the reasons of the failed rows and, where the
dataset carries the true poses, the accuracy (docs/solve.md#command-line)."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._errors import InputError
from .._options import option as _opt
from .._result import Result
from ._bands import BAND_METHODS, DEFAULT_BAND_TIME_CONSTANT_S
from ._factory import SOLVERS
from ._hemisphere import DEFAULT_HEMISPHERE, hemisphere_vectors
from ._validity import MAX_RANGE_M, MAX_RELATIVE_RESIDUAL

__all__ = ["RowFixtures", "SolveFileOptions", "SolveFileResult", "failure_reasons",
           "solve_file"]


@dataclass(frozen=True)
class SolveFileOptions:
    """The options of :func:`solve_file` (``openemt solve``; the help texts are the
    command's)."""

    dataset: Path | None = _opt(None, "openemt dataset HDF5 file", positional=True)
    calibration: Path | None = _opt(None, "calibration (openemt JSON or ILEMT .mat)",
                                    flag=("--calibration", "-c"))
    output: Path | None = _opt(None, "output poses HDF5 file", flag=("-o", "--output"))
    solver: str = _opt("lm", "pose solver (closed forms: concentric 3x3 dipole models only)",
                       choices=SOLVERS)
    hemisphere: str = _opt(
        "auto", "hemisphere of the sensor: +x, -x, +y, -y, +z, -z; 'auto' (default): per "
        "source fixture, from the calibration's fixture transforms, when the dataset records "
        "each row's fixtures (ILEMT imports, simulations), else +x; 'none': unconstrained (lm "
        "only); a finite-coil board: its front side, always")
    concentric_calibration: Path | None = _opt(
        None, "concentric calibration whose Kim18 solution starts the LM solver")
    initial: str | None = _opt(
        None, "LM start: 'track' warm-starts each row from the previous converged one (a "
        "failed or suspicious row is solved again cold); a closed form (kim18, svd, kuipers) "
        "or multistart solves every row independently. Default: track when the dataset is a "
        "recording (its meta says so), else kim18",
        choices=("kim18", "svd", "kuipers", "track", "multistart"))
    max_iter: int = _opt(100, "iteration limit of the LM solver")
    max_relative_residual: float = _opt(
        MAX_RELATIVE_RESIDUAL, "largest relative coupling residual ||C_pred - C||/||C|| of a "
        f"converged pose (default {MAX_RELATIVE_RESIDUAL}; all solvers)")
    max_range: float = _opt(MAX_RANGE_M, "largest plausible sensor distance from the source "
                            f"in m (default {MAX_RANGE_M}); farther poses are out_of_volume")
    bounds: float | None = _opt(None, "position box half-width in m (LM); solutions on it "
                                "are out_of_volume")
    no_correction: bool = _opt(False, "do not apply the calibration's linear output "
                               "correction")
    bands: str = _opt(
        "auto", "carrier bands of a dataset with band couplings: fast, slow, fuse (the fast "
        "band corrected from the slow one through a low-pass; rows in time order), eddy-free "
        "(extrapolated to zero frequency where the quadrature flags eddy currents), sheet "
        "(where it flags them, the pose and a conducting sheet fitted together and the "
        "sheet's part taken out; dipole calibrations); 'auto' "
        "(default): fuse on a recording with a sample rate, else band 0 as without bands",
        choices=BAND_METHODS)
    band_time_constant: float = _opt(
        DEFAULT_BAND_TIME_CONSTANT_S, "time constant of the fuse low-pass in seconds "
        f"(default {DEFAULT_BAND_TIME_CONSTANT_S})")
    chunk_rows: int = _opt(262144, "rows per block")
    scheduler: str | None = _opt(
        None, "dask.distributed scheduler address (default: local, in process); the workers "
        "read their blocks from DATASET and write them into the output's folder, so they "
        "must see both")

    def __post_init__(self):
        for name, what in (("dataset", "a dataset file"),
                           ("calibration", "--calibration CAL (a calibration file)"),
                           ("output", "-o POSES.h5 (the output file)")):
            if getattr(self, name) is None:
                raise InputError(f"expected {what}, got none")
            object.__setattr__(self, name, Path(getattr(self, name)))
        if isinstance(self.chunk_rows, bool) or not isinstance(self.chunk_rows, int) \
                or self.chunk_rows < 1:
            raise InputError(f"expected a positive --chunk-rows, got {self.chunk_rows}")


@dataclass(frozen=True)
class SolveFileResult(Result):
    """What :func:`solve_file` did (its ``to_dict()`` is ``openemt solve --json``; keys that
    do not apply, such as ``initial`` for a closed form, are left out)."""

    dataset: str
    calibration: str
    output: str
    solver: str
    model: str
    dof: int
    n_samples: int
    hemisphere: str | None
    status_counts: dict
    failed: list
    correction_applied: bool
    elapsed_s: float
    poses_per_s: float | None
    initial: str | None = None
    recording: bool | None = None
    cold_retries: int | None = None
    hemispheres: dict | None = None
    accuracy: dict | None = None
    initial_given: bool = False
    bands: str | None = None

    _OPTIONAL = ("hemisphere", "initial", "recording", "cold_retries", "hemispheres",
                 "accuracy", "bands")

    def _items(self) -> dict:
        return {k: v for k, v in super()._items().items()
                if k != "initial_given" and not (k in self._OPTIONAL and v is None)}

    def lines(self) -> list[str]:
        """The human summary (stderr of ``openemt solve``)."""
        what = self.solver if self.model == "dipole" else \
            f"the {self.dof}-DOF {self.model} solver"
        out = [f"solved {self.n_samples} samples with {what} in {self.elapsed_s:.2f} s -> "
               f"{self.output}"]
        if self.initial == "track":
            why = "--initial track" if self.initial_given else "the dataset is a recording"
            out.append(f"rows solved as a time series ({why}; --initial kim18 solves them "
                       f"independently): {self.cold_retries} failed or suspicious rows solved "
                       f"again cold")
        if self.hemispheres is not None:
            axes: dict = {}
            for key, v in self.hemispheres.items():
                axes.setdefault(key.split("/")[0], []).append(v["axis"])
            out.append("hemisphere per source fixture (the calibration's fixture transforms): "
                       + ", ".join(f"{code} {'/'.join(dict.fromkeys(a))}"
                                   for code, a in axes.items()))
        elif self.hemisphere is not None:
            out.append(f"hemisphere: {self.hemisphere}")
        if self.bands is not None:
            out.append(f"carrier bands: {self.bands} (--bands)")
        out.append("status: " + ", ".join(f"{k} {v}" for k, v in self.status_counts.items()
                                          if v))
        out += [f"  {f['status']} {f['rows']}: {f['reason']}" for f in self.failed]
        acc = self.accuracy
        if acc is not None:
            rot = ("axis", acc["axis_rms_deg"]) if "axis_rms_deg" in acc else \
                ("rotation", acc["rot_rms_deg"])
            out.append(f"accuracy against the dataset's poses: {acc['position_rms_mm']:.4f} mm "
                       f"RMS, {acc['position_max_mm']:.4f} mm max, {rot[1]:.4f} deg "
                       f"{rot[0]} RMS over {acc['n']} converged samples")
        return out


def _cold_start_table(model, dipole: bool, initial, options) -> bool:
    """Whether the solve's Kim18 start (also of the first and the lost samples of a tracked
    recording) is the invariant table's: its cold-start kernel then runs."""
    from ._prepared import uses_invariant_table

    return dipole and initial in ("kim18", "track") and uses_invariant_table(
        model, options.concentric_model is not None, options.retry_resnorm)


def solve_file(options: SolveFileOptions, *, on_block=None, on_start=None) -> SolveFileResult:
    """Solve every row of ``options.dataset`` with the model of ``options.calibration`` and
    write the poses file ``options.output`` (atomically: no file on any failure).

    The solver is the one :func:`~openemt.solve.prepare` picks for the model's solver family:
    a dipole model's (LM or a closed form; per-source-fixture hemispheres, time-series
    tracking of recordings) or a finite-coil board's (tracked from sample to sample; the
    sensor on the board's front side, ``hemisphere`` and ``initial`` do not apply).
    ``on_start(n_rows, model, cold_start_table)`` is called once the inputs are checked,
    before the first block, with the model solved with and whether its cold start's table runs
    (for a compile notice: :func:`openemt._compile_notice.solve_kernels`);
    ``on_block(rows, summary)`` after each block.
    """
    from ..io import is_recording, open_dataset_couplings, read_calibration
    from ..io._h5safe import open_h5
    from ._options import DEFAULT, SolveOptions
    from ._result import status_count_names
    from ._tofile import solve_to_file

    o = options
    cal = read_calibration(o.calibration)
    model = cal.model
    dipole = getattr(model, "solver_family", "model") in ("dipole", "dipole-refined")
    rule = {"max_relative_residual": o.max_relative_residual, "max_range": o.max_range,
            "max_iter": o.max_iter, "bounds": o.bounds}
    spec = o.hemisphere.strip().lower()
    if not dipole:
        if o.solver != "lm":
            raise InputError(f"expected --solver lm with a {model.kind!r} calibration, got "
                             f"--solver {o.solver}")
        if o.concentric_calibration is not None:
            raise InputError(f"expected no --concentric-calibration with a {model.kind!r} "
                             f"calibration (its solver starts from its own cold start), got "
                             f"one")
        hemisphere, name = DEFAULT, ("planar-lm" if model.dof == 5 else f"{model.kind}-lm")
    else:
        hemisphere = None if spec == "none" else DEFAULT_HEMISPHERE if spec == "auto" \
            else o.hemisphere
        if hemisphere is not None:
            hemisphere_vectors(hemisphere, 1)     # a bad spec is refused before any work
        elif o.solver != "lm":
            raise InputError(f"expected a hemisphere such as +x for --solver {o.solver}, got "
                             f"'none'")
        if o.solver != "lm":
            if o.bounds is not None or o.concentric_calibration is not None \
                    or o.initial is not None:
                raise InputError(f"expected --bounds/--concentric-calibration/--initial only "
                                 f"with --solver lm, got --solver {o.solver}")
            rule = {k: rule[k] for k in ("max_relative_residual", "max_range")}
        elif o.concentric_calibration is not None:
            rule["concentric_model"] = read_calibration(o.concentric_calibration).model
        name = o.solver
    checked = SolveOptions.of(None, rule)         # the options checked before any work
    t0 = time.perf_counter()
    with open_dataset_couplings(o.dataset, real=not dipole) as reader, \
            open_h5(o.dataset, "an openemt dataset HDF5 file") as side:
        n = reader.shape[0]
        if tuple(reader.shape[1:]) != (model.n_source, model.n_sensor):
            raise InputError(f"expected couplings of shape (N, {model.n_source}, "
                             f"{model.n_sensor}) for this {model.kind!r} calibration, got "
                             f"{reader.shape}")
        fixtures = RowFixtures.read(side, n, o.chunk_rows, cal) if dipole else None
        per_fixture = spec == "auto" and fixtures is not None and fixtures.usable
        if per_fixture:
            hemisphere = fixtures
        recording = is_recording(_meta(side))
        bands = _band_stage(o, side, dipole, recording, model,
                            hemisphere if isinstance(hemisphere, str) else None)
        if bands is not None:
            from ._bands import BandReader

            solved_rows = BandReader(o.dataset, bands, o.chunk_rows)
        else:
            solved_rows = reader
        initial = None
        if dipole and o.solver == "lm":
            initial = rule["initial"] = o.initial or ("track" if recording else "kim18")
        truth = _TruthScore(side.get("poses"), model, n, o.dataset) if not dipole else None
        shown = ("per source fixture" if per_fixture else None if not dipole
                 else o.hemisphere if spec != "auto" else DEFAULT_HEMISPHERE)
        applied = bool(cal.linear_correction is not None and not o.no_correction and dipole)
        meta = {"dataset": str(o.dataset), "calibration": str(o.calibration),
                **({"hemisphere": shown} if dipole else {"model": model.kind,
                                                         "dof": model.dof}),
                "correction_applied": applied,
                **({"board": model.board.name} if hasattr(model, "board") else {}),
                **({"initial": initial} if initial is not None else {}),
                **({"bands": bands.method} if bands is not None else {})}
        if on_start is not None:
            on_start(n, model, _cold_start_table(model, dipole, initial, checked))
        done = solve_to_file(solved_rows, cal, o.output, chunk_rows=o.chunk_rows,
                             scheduler=o.scheduler, solver=o.solver, hemisphere=hemisphere,
                             apply_correction=not o.no_correction, meta=meta,
                             groups=None if fixtures is None else
                             (fixtures.index, len(fixtures.pairs)),
                             on_block=on_block, solver_name=name, **rule)
        if fixtures is not None:
            fixtures.add(done)
        accuracy = truth.score(reader, o.output) if truth is not None else None
    elapsed = time.perf_counter() - t0
    return SolveFileResult(
        dataset=str(o.dataset), calibration=str(o.calibration), output=str(o.output),
        solver=name, model=model.kind, dof=model.dof, n_samples=n, hemisphere=shown,
        status_counts=status_count_names(done.counts),
        failed=failure_reasons(done.counts, o, fixtures,
                               None if per_fixture or not dipole else hemisphere),
        correction_applied=applied, elapsed_s=elapsed,
        poses_per_s=n / elapsed if elapsed > 0 else None, initial=initial,
        recording=recording if initial is not None else None,
        cold_retries=done.cold_retries if initial is not None else None,
        hemispheres=fixtures.hemisphere_summary() if per_fixture else None,
        accuracy=accuracy, initial_given=o.initial is not None,
        bands=None if bands is None else bands.method)


def _meta(side) -> dict:
    """The open dataset's ``meta`` attribute as a dict ({} where it has none or no JSON
    object)."""
    text = side.attrs.get("meta")
    if isinstance(text, bytes):
        text = text.decode("utf-8", "replace")
    try:
        d = json.loads(text) if isinstance(text, str) else {}
    except ValueError:
        return {}
    return d if isinstance(d, dict) else {}


def _band_stage(o: SolveFileOptions, side, dipole: bool, recording: bool, model=None,
                hemisphere=None):
    """The :class:`~openemt.solve.BandStage` of ``--bands`` for the open dataset ``side``, or
    None where band 0 is solved as it is."""
    from ._bands import BandStage, band_dataset_shape, resolve_bands

    shape = band_dataset_shape(side)
    n_bands = 1 if shape is None else int(shape[1])
    meta = _meta(side)
    rec = meta.get("recording") if isinstance(meta.get("recording"), dict) else {}
    rate = rec.get("sample_rate_hz")
    rate = float(rate) if isinstance(rate, (int, float)) and rate > 0 else None
    if not dipole:
        if o.bands == "auto" or n_bands < 2:
            return None if o.bands in ("auto", "fast") else resolve_bands(
                o.bands, n_bands, ordered=recording, rate=rate)
        raise InputError(f"expected --bands auto with a finite-coil board calibration (its "
                         f"solver takes band 0), got --bands {o.bands}")
    method = resolve_bands(o.bands, n_bands, ordered=recording, rate=rate)
    if method is None:
        return None
    f = meta.get("band_frequencies_hz")
    if f is None:
        raise InputError(f"{o.dataset}: expected the carriers of its bands (meta "
                         f"band_frequencies_hz) for --bands {o.bands}, got none")
    return BandStage(method, f, time_constant=o.band_time_constant, rate=rate, signed=True,
                     model=model, hemisphere=hemisphere)


class _TruthScore:
    """The accuracy block of a dataset that carries the true sensor poses (a simulated or
    measured grid): the keys of the planar calibration's accuracy blocks
    (docs/planar.md#accuracy), from the tracked solution instead of cold starts. ``poses`` is
    the dataset's ``poses`` (an h5py dataset read block by block) or None."""

    def __init__(self, poses, model, n, path):
        import h5py

        if poses is not None and (not isinstance(poses, h5py.Dataset)
                                  or poses.shape != (n, 4, 4)):
            got = poses.shape if isinstance(poses, h5py.Dataset) else "a group"
            raise InputError(f"{path}: expected `poses` to have shape ({n}, 4, 4) beside the "
                             f"couplings, got {got}")
        self.poses, self.model = poses, model

    def score(self, reader, output, rows: int = 262144) -> dict | None:
        """The accuracy of the solved poses file ``output`` against the true poses, block by
        block; None without true poses or where a row has none."""
        if self.poses is None:
            return None
        from ..evaluate import error_summary, pose_error_magnitudes
        from ._grid import GridData, PlanarErrors, planar_errors
        from ._output import read_poses
        from ._result import SolveResult

        solved = read_poses(output)
        parts = []
        for a in range(0, len(solved), rows):
            res = solved.select(np.arange(a, min(a + rows, len(solved))))
            P = np.asarray(self.poses[a:a + rows], dtype=np.float64)
            C = np.asarray(reader[a:a + rows], dtype=np.float64)
            if not (np.all(np.isfinite(P)) and np.all(np.isfinite(C))):
                return None                       # rows without a truth: no accuracy block
            parts.append((res, P) if self.model.dof == 6 else planar_errors(
                self.model, GridData(P[:, :3, 3], P[:, :3, 2], C.reshape(len(res), -1)),
                result=res))
        if not parts:
            return None
        if self.model.dof != 6:
            return PlanarErrors.concatenate(parts).summary()
        res = SolveResult.concatenate([r for r, _ in parts])
        ok = res.valid
        t, r = pose_error_magnitudes(res.poses[ok], np.concatenate([P for _, P in parts])[ok])
        s = error_summary(t, r)
        return {"n": int(ok.sum()), "n_failed": int((~ok).sum()),
                "position_rms_mm": s["trans_rms_mm"], "position_max_mm": s["trans_max_mm"],
                "rot_rms_deg": s["rot_rms_deg"], "rot_max_deg": s["rot_max_deg"]}


#: Cosine of the largest angle between the sensor's home direction and the hemisphere axis for
#: which a fixture's rows count as inside the hemisphere (60 degrees).
_INSIDE_COS = 0.5


class RowFixtures:
    """The fixture codes of a dataset's rows, as an index into the distinct (source, sensor)
    pairs, and the rig hemisphere of each pair (:func:`openemt.solve.rig_hemispheres`).

    Sliced by rows (``obj[a:b]``) it gives the rows' hemisphere directions, so it can be
    passed to :func:`solve_to_file` as a per-row hemisphere; it pickles as two
    small arrays. ``add`` takes the status counts per pair gathered while the blocks go by.
    """

    def __init__(self, index, pairs, home):
        from ._result import Status

        self.index = index                  # (N,) int32 into pairs
        self.pairs = pairs                  # [(source code, sensor code)]
        self.home = home                    # (K, 3) home positions (m) or None
        self.shape = (len(index), 3)
        self.ndim = 2
        self.counts = np.zeros((len(pairs), len(Status)), dtype=np.int64)
        self.residual_sum = np.zeros((len(pairs), len(Status)))   # relative residuals
        self.residual_n = np.zeros((len(pairs), len(Status)), dtype=np.int64)

    @property
    def usable(self) -> bool:
        """Every pair has a home position clear of the source centre (at least 1 cm)."""
        return self.home is not None and bool(np.all(np.linalg.norm(self.home, axis=1) > 0.01))

    @classmethod
    def read(cls, side, n: int, rows: int, cal):
        """The fixtures of the open dataset ``side`` (h5py file), or None where it records
        none (pose datasets, files without the codes)."""
        import h5py

        from ._hemisphere import rig_hemispheres

        ds = [side.get(name) for name in ("source_fixture", "sensor_fixture")]
        if n == 0 or not all(isinstance(d, h5py.Dataset) and d.shape == (n,)
                             and h5py.check_string_dtype(d.dtype) is not None for d in ds):
            return None
        ids: dict = {}
        index = np.empty(n, dtype=np.int32)
        for a in range(0, n, rows):
            so = np.asarray(ds[0].asstr()[a:a + rows], dtype=str)
            se = np.asarray(ds[1].asstr()[a:a + rows], dtype=str)
            keys, inverse = np.unique(np.char.add(np.char.add(so, "\n"), se),
                                      return_inverse=True)
            table = np.array([ids.setdefault(tuple(k.split("\n")), len(ids)) for k in keys])
            index[a:a + rows] = table[inverse.ravel()]
        pairs = list(ids)
        home = None
        if all(p[0] and p[1] for p in pairs):
            try:
                home = rig_hemispheres(cal.source_fixture, cal.stage_fixture,
                                       cal.sensor_fixture, [p[0] for p in pairs],
                                       [p[1] for p in pairs])
            except InputError:  # codes the rig does not know: no fixture hemispheres
                home = None
        return cls(index, pairs, home)

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, key) -> np.ndarray:
        return self.home[self.index[key]]

    def add(self, summary) -> None:
        """Take the per-pair tallies gathered by :func:`openemt.solve.solve_to_file`."""
        self.counts += summary.group_counts
        self.residual_sum += summary.group_residual_sum
        self.residual_n += summary.group_residual_n

    def hemisphere_summary(self) -> dict:
        from ._hemisphere import hemisphere_from_positions

        axes = hemisphere_from_positions(self.home)
        return {f"{so}/{se}": {"direction": self.home[k] / np.linalg.norm(self.home[k]),
                               "axis": str(axes[k]), "rows": int(self.counts[k].sum())}
                for k, (so, se) in enumerate(self.pairs)}


def _generic_reason(status, options) -> str:
    from ._result import Status

    if status == Status.MAX_ITERATIONS:
        return f"the solver reached --max-iter {options.max_iter} before its convergence tests held"
    if status == Status.INVALID_INPUT:
        return "the coupling matrix is NaN/inf, zero or rank deficient (pose NaN)"
    if status == Status.AMBIGUOUS:
        return ("the position lies on the hemisphere boundary, so the +/- dipole ambiguity "
                "cannot be resolved")
    if status == Status.OUT_OF_VOLUME:
        return (f"the solution is farther than --max-range {options.max_range:g} m from the source"
                + (f" or on the --bounds {options.bounds:g} m box" if options.bounds else "")
                + " or not finite")
    return (f"the relative coupling residual is above --max-relative-residual "
            f"{options.max_relative_residual:g}: the calibration's model does not explain these "
            f"couplings (distortion, a wrong calibration or the sensor in the other "
            f"hemisphere)")


def _span(values) -> str:
    lo, hi = f"{np.min(values):.0f}", f"{np.max(values):.0f}"
    return lo if lo == hi else f"{lo}-{hi}"


def _by_source(fixtures, per_pair, mask) -> dict:
    """Rows per source fixture code of the pairs in ``mask`` (``per_pair``: rows per pair)."""
    by_code: dict = {}
    for k in np.flatnonzero(mask & (per_pair > 0)):
        by_code[fixtures.pairs[k][0]] = by_code.get(fixtures.pairs[k][0], 0) + int(per_pair[k])
    return by_code


def _residual_note(fixtures, status, mask) -> str:
    """'; mean relative residual 1.2 % on these rows, 0.1 % on the converged rows' and the
    source fixtures of these rows, from the per-pair sums of ``fixtures.tally``."""
    from ._result import Status

    def mean(sel, st):
        n = fixtures.residual_n[sel, st].sum()
        return fixtures.residual_sum[sel, st].sum() / n if n else None

    bad = mean(mask, status)
    good = mean(np.ones(len(fixtures.pairs), bool), Status.CONVERGED)
    if bad is None:
        return ""
    by_code = _by_source(fixtures, fixtures.counts[:, status], mask)
    where = ", ".join(f"{c} {n}" for c, n in sorted(by_code.items()))
    return (f"; mean relative residual {100 * bad:.2f} % on these rows ({where})"
            + (f", {100 * good:.2f} % on the converged rows" if good is not None else ""))


def failure_reasons(counts, options, fixtures=None, hemisphere=None) -> list[dict]:
    """One entry per class of failed rows: ``{"status", "rows", "reason"}`` (plus
    ``source_fixtures``, the rows per source fixture, when the dataset records them).

    With one hemisphere for all rows, the rows of fixture pairs whose sensor home lies more
    than 60 degrees from its axis are a class of their own: they straddle or cross the
    hemisphere boundary, and ``--hemisphere auto`` is the remedy.
    """
    from ._hemisphere import hemisphere_vectors
    from ._result import Status

    out = []
    outside = np.zeros(0, dtype=bool)
    if fixtures is not None and fixtures.usable and hemisphere is not None:
        axis = hemisphere_vectors(hemisphere, 1)[0]
        home = fixtures.home / np.linalg.norm(fixtures.home, axis=1, keepdims=True)
        outside = home @ axis < _INSIDE_COS
    for status in Status:
        if status == Status.CONVERGED or not counts[status]:
            continue
        per_pair = fixtures.counts[:, status] if fixtures is not None else None
        classes = [(int(counts[status]), None)]
        if per_pair is not None and outside.any() and per_pair[outside].sum():
            classes = [(int(per_pair[outside].sum()), outside),
                       (int(per_pair[~outside].sum()), ~outside)]
        for rows, mask in classes:
            if not rows:
                continue
            if mask is not None and mask is outside:
                angles = np.rad2deg(np.arccos(np.clip(home[outside] @ axis, -1, 1)))
                codes = sorted({fixtures.pairs[k][0] for k in np.flatnonzero(outside)})
                reason = (f"source fixture{'s' if len(codes) > 1 else ''} {', '.join(codes)} "
                          f"put{'' if len(codes) > 1 else 's'} the sensor "
                          f"{_span(angles)} deg from the "
                          f"{hemisphere} hemisphere's axis (the calibration's fixture "
                          f"transforms), so these rows straddle or cross its boundary; "
                          f"--hemisphere auto picks the hemisphere per source fixture")
            else:
                reason = _generic_reason(status, options)
                if status == Status.NOT_CONVERGED and fixtures is not None:
                    reason += _residual_note(fixtures, status,
                                             np.ones(len(fixtures.pairs), bool)
                                             if mask is None else mask)
            entry = {"status": status.name.lower(), "rows": rows, "reason": reason}
            if per_pair is not None:
                entry["source_fixtures"] = _by_source(
                    fixtures, per_pair, np.ones(len(fixtures.pairs), bool) if mask is None
                    else mask)
            out.append(entry)
    return out
