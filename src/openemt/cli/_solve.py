"""``openemt solve``: poses from a dataset file and a calibration, streamed in blocks."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from .._constants import MAX_RANGE_M, MAX_RELATIVE_RESIDUAL
from .._errors import InputError

__all__ = ["RowFixtures", "failure_reasons", "register", "run"]


def register(subparsers) -> None:
    from . import command_help
    from ._common import add_common

    p = subparsers.add_parser(
        "solve", help=command_help("solve"),
        description="Solve sensor poses for every row of an openemt HDF5 dataset with a "
                    "calibration's model and write them to an HDF5 poses file. Large files are "
                    "streamed in blocks (Dask; local by default, --scheduler for a cluster).")
    p.add_argument("dataset", type=Path, help="openemt dataset HDF5 file")
    p.add_argument("--calibration", "-c", type=Path, required=True,
                   help="calibration (openemt JSON or ILEMT .mat)")
    p.add_argument("--solver", choices=("lm", "svd", "kuipers", "kim18"), default="lm")
    p.add_argument("-o", "--output", type=Path, required=True, help="output poses HDF5 file")
    p.add_argument("--hemisphere", default="auto",
                   help="hemisphere of the sensor: +x, -x, +y, -y, +z, -z; 'auto' (default): "
                        "per source fixture, from the calibration's fixture transforms, when "
                        "the dataset records each row's fixtures (ILEMT imports, simulations), "
                        "else +x; 'none': unconstrained (lm only)")
    p.add_argument("--concentric-calibration", type=Path, default=None,
                   help="concentric calibration whose Kim18 solution starts the LM solver")
    p.add_argument("--initial", default=None,
                   choices=("kim18", "svd", "kuipers", "track", "multistart"),
                   help="LM start: 'track' warm-starts each row from the previous converged "
                        "one (a failed or suspicious row is solved again cold); a closed form "
                        "(kim18, svd, kuipers) or multistart solves every row independently. "
                        "Default: track when the dataset is a recording (its meta says so), "
                        "else kim18")
    p.add_argument("--max-iter", type=int, default=100)
    p.add_argument("--max-relative-residual", type=float, default=MAX_RELATIVE_RESIDUAL,
                   help="largest relative coupling residual ||C_pred - C||/||C|| of a "
                        f"converged pose (default {MAX_RELATIVE_RESIDUAL}; all solvers)")
    p.add_argument("--max-range", type=float, default=MAX_RANGE_M,
                   help="largest plausible sensor distance from the source in m (default "
                        f"{MAX_RANGE_M}); farther poses are out_of_volume")
    p.add_argument("--bounds", type=float, default=None,
                   help="position box half-width in m (LM); solutions on it are out_of_volume")
    p.add_argument("--no-correction", action="store_true",
                   help="do not apply the calibration's linear output correction")
    p.add_argument("--chunk-rows", type=int, default=262144, help="rows per block")
    p.add_argument("--scheduler", default=None,
                   help="dask.distributed scheduler address (default: local, in process); "
                        "the workers read their blocks from DATASET and write them into the "
                        "output's folder, so they must see both")
    p.add_argument("--progress", action="store_true",
                   help="a line on stderr about every second: rows done, rate and time left "
                        "(across the cluster with --scheduler)")
    add_common(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..field import DipoleModel
    from ..io import read_calibration
    from ._solve_planar import solve_board

    cal = read_calibration(args.calibration)
    if not isinstance(cal.model, DipoleModel):   # no dipole batch kernel: docs/planar.md#solving
        return solve_board(args, cal)

    from .._compile_notice import announce_compile
    from ..io import open_dataset_couplings
    from ..io._h5safe import open_h5
    from ..solve import solve_to_file
    from ..solve._hemisphere import DEFAULT_HEMISPHERE, hemisphere_vectors
    from ..solve._result import status_count_names
    from ._common import emit

    options = {"max_relative_residual": args.max_relative_residual,
               "max_range": args.max_range}
    spec = args.hemisphere.strip().lower()
    hemisphere = None if spec == "none" else DEFAULT_HEMISPHERE if spec == "auto" else \
        args.hemisphere
    if hemisphere is not None:
        hemisphere_vectors(hemisphere, 1)  # a bad spec is refused before any work
    if hemisphere is None and args.solver != "lm":
        raise InputError(f"expected a hemisphere such as +x for --solver {args.solver}, got "
                         f"'none'")
    if args.solver == "lm":
        options.update(max_iter=args.max_iter, bounds=args.bounds)
        if args.concentric_calibration is not None:
            options["concentric_model"] = read_calibration(args.concentric_calibration).model
    elif args.bounds is not None or args.concentric_calibration is not None \
            or args.initial is not None:
        raise InputError(f"expected --bounds/--concentric-calibration/--initial only with "
                         f"--solver lm, got --solver {args.solver}")
    if args.chunk_rows < 1:
        raise InputError(f"expected a positive --chunk-rows, got {args.chunk_rows}")
    t0 = time.perf_counter()
    with open_dataset_couplings(args.dataset) as reader, \
            open_h5(args.dataset, "an openemt dataset HDF5 file") as side:
        n = reader.shape[0]
        if (reader.shape[1], reader.shape[2]) != (cal.model.n_source, cal.model.n_sensor):
            raise InputError(f"expected couplings of shape (N, {cal.model.n_source}, "
                             f"{cal.model.n_sensor}) for this calibration, got {reader.shape}")
        fixtures = RowFixtures.read(side, n, args.chunk_rows, cal)
        if spec == "auto" and fixtures is not None and fixtures.usable:
            hemisphere = fixtures
        recording = _is_recording(side)
        initial = None
        if args.solver == "lm":
            initial = args.initial or ("track" if recording else "kim18")
            options["initial"] = initial
        meta = {"dataset": str(args.dataset), "calibration": str(args.calibration),
                "hemisphere": ("per source fixture" if hemisphere is fixtures
                               else args.hemisphere if spec != "auto" else DEFAULT_HEMISPHERE),
                "correction_applied": bool(cal.linear_correction is not None
                                           and not args.no_correction)}
        if initial is not None:
            meta["initial"] = initial
        announce_compile(args, "solver kernels")       # inputs checked: before the first
        with _Progress(args, n) as shown:
            done = solve_to_file(reader, cal, args.output, chunk_rows=args.chunk_rows,
                                 scheduler=args.scheduler, solver=args.solver,
                                 hemisphere=hemisphere,
                                 apply_correction=not args.no_correction, meta=meta,
                                 groups=None if fixtures is None else
                                 (fixtures.index, len(fixtures.pairs)),
                                 on_block=shown.update, **options)
        if fixtures is not None:
            fixtures.add(done)
    elapsed = time.perf_counter() - t0
    counts = status_count_names(done.counts)
    failed = failure_reasons(done.counts, args, fixtures,
                             None if hemisphere is fixtures else hemisphere)
    summary = {"dataset": str(args.dataset), "calibration": str(args.calibration),
               "output": str(args.output), "solver": args.solver, "n_samples": n,
               "hemisphere": meta["hemisphere"], "status_counts": counts, "failed": failed,
               "correction_applied": meta["correction_applied"],
               "elapsed_s": elapsed, "poses_per_s": n / elapsed if elapsed > 0 else None}
    if initial is not None:
        summary.update(initial=initial, recording=recording, cold_retries=done.cold_retries)
    if hemisphere is fixtures:
        summary["hemispheres"] = fixtures.hemisphere_summary()
    human = [f"solved {n} samples with {args.solver} in {elapsed:.2f} s -> {args.output}"]
    if initial == "track":
        why = "the dataset is a recording" if args.initial is None else "--initial track"
        human.append(f"rows solved as a time series ({why}; --initial kim18 solves them "
                     f"independently): {done.cold_retries} failed or suspicious rows solved "
                     f"again cold")
    if hemisphere is fixtures:
        axes: dict = {}
        for key, v in summary["hemispheres"].items():
            axes.setdefault(key.split("/")[0], []).append(v["axis"])
        human.append("hemisphere per source fixture (the calibration's fixture transforms): "
                     + ", ".join(f"{code} {'/'.join(dict.fromkeys(a))}"
                                 for code, a in axes.items()))
    else:
        human.append(f"hemisphere: {meta['hemisphere']}")
    human.append("status: " + ", ".join(f"{k} {v}" for k, v in counts.items() if v))
    human += [f"  {f['status']} {f['rows']}: {f['reason']}" for f in failed]
    emit(args, summary, human)
    return 0


def _is_recording(side) -> bool:
    """True if the open dataset's ``meta`` marks its rows as one recording in time order."""
    import json

    from ..io import is_recording

    text = side.attrs.get("meta")
    if isinstance(text, bytes):
        text = text.decode("utf-8", "replace")
    try:
        return is_recording(json.loads(text)) if isinstance(text, str) else False
    except ValueError:
        return False


class _Progress:
    """Progress of a solve on stderr: with ``--progress`` a plain line about every second
    (rows done, rate, time left; also when stderr is not a terminal), else the progress bar
    of the other commands (terminals only). ``update(rows, summary)`` after each block."""

    def __init__(self, args, total: int):
        self.args, self.total = args, int(total)
        self.lines = bool(getattr(args, "progress", False)) and not args.quiet
        self.done = 0
        self.t0 = self.last = time.perf_counter()

    def __enter__(self):
        from ._common import progress

        self.bar = None if self.lines else progress(total=self.total, desc="solve",
                                                    args=self.args, unit="pose")
        return self

    def update(self, rows: int, _summary=None) -> None:
        self.done += rows
        if self.bar is not None:
            self.bar.update(rows)
            return
        now = time.perf_counter()
        if self.lines and (now - self.last >= 1.0 or self.done >= self.total):
            self.last = now
            print(self.line(now), file=sys.stderr, flush=True)

    def line(self, now: float) -> str:
        elapsed = max(now - self.t0, 1e-9)
        rate = self.done / elapsed
        left = (self.total - self.done) / rate if rate > 0 else float("inf")
        pct = 100 * self.done / max(self.total, 1)
        return (f"solve: {self.done}/{self.total} rows ({pct:.1f} %), {rate:,.0f} rows/s, "
                f"{left:.1f} s left")

    def __exit__(self, *exc) -> None:
        if self.bar is not None:
            self.bar.close()


#: Cosine of the largest angle between the sensor's home direction and the hemisphere axis for
#: which a fixture's rows count as inside the hemisphere (60 degrees).
_INSIDE_COS = 0.5


class RowFixtures:
    """The fixture codes of a dataset's rows, as an index into the distinct (source, sensor)
    pairs, and the rig hemisphere of each pair (:func:`openemt.solve.rig_hemispheres`).

    Sliced by rows (``obj[a:b]``) it gives the rows' hemisphere directions, so it can be
    passed to :func:`openemt.solve.solve_to_file` as a per-row hemisphere; it pickles as two
    small arrays. ``add`` takes the status counts per pair gathered while the blocks go by.
    """

    def __init__(self, index, pairs, home):
        from ..solve import Status

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

        from ..solve import rig_hemispheres

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
        from ..solve import hemisphere_from_positions

        axes = hemisphere_from_positions(self.home)
        return {f"{so}/{se}": {"direction": self.home[k] / np.linalg.norm(self.home[k]),
                               "axis": str(axes[k]), "rows": int(self.counts[k].sum())}
                for k, (so, se) in enumerate(self.pairs)}


def _generic_reason(status, args) -> str:
    from ..solve import Status

    if status == Status.MAX_ITERATIONS:
        return f"the solver reached --max-iter {args.max_iter} before its convergence tests held"
    if status == Status.INVALID_INPUT:
        return "the coupling matrix is NaN/inf, zero or rank deficient (pose NaN)"
    if status == Status.AMBIGUOUS:
        return ("the position lies on the hemisphere boundary, so the +/- dipole ambiguity "
                "cannot be resolved")
    if status == Status.OUT_OF_VOLUME:
        return (f"the solution is farther than --max-range {args.max_range:g} m from the source"
                + (f" or on the --bounds {args.bounds:g} m box" if args.bounds else "")
                + " or not finite")
    return (f"the relative coupling residual is above --max-relative-residual "
            f"{args.max_relative_residual:g}: the calibration's model does not explain these "
            f"couplings (distortion, a wrong calibration or the sensor in the other "
            f"hemisphere)")


def _span(values) -> str:
    lo, hi = f"{np.min(values):.0f}", f"{np.max(values):.0f}"
    return lo if lo == hi else f"{lo}-{hi}"


def _residual_note(fixtures, status, mask) -> str:
    """'; mean relative residual 1.2 % on these rows, 0.1 % on the converged rows' and the
    source fixtures of these rows, from the per-pair sums of ``fixtures.tally``."""
    from ..solve import Status

    def mean(sel, st):
        n = fixtures.residual_n[sel, st].sum()
        return fixtures.residual_sum[sel, st].sum() / n if n else None

    bad = mean(mask, status)
    good = mean(np.ones(len(fixtures.pairs), bool), Status.CONVERGED)
    if bad is None:
        return ""
    by_code: dict = {}
    for k in np.flatnonzero(mask & (fixtures.counts[:, status] > 0)):
        by_code[fixtures.pairs[k][0]] = by_code.get(fixtures.pairs[k][0], 0) + \
            int(fixtures.counts[k, status])
    where = ", ".join(f"{c} {n}" for c, n in sorted(by_code.items()))
    return (f"; mean relative residual {100 * bad:.2f} % on these rows ({where})"
            + (f", {100 * good:.2f} % on the converged rows" if good is not None else ""))


def failure_reasons(counts, args, fixtures=None, hemisphere=None) -> list[dict]:
    """One entry per class of failed rows: ``{"status", "rows", "reason"}`` (plus
    ``source_fixtures``, the rows per source fixture, when the dataset records them).

    With one hemisphere for all rows, the rows of fixture pairs whose sensor home lies more
    than 60 degrees from its axis are a class of their own: they straddle or cross the
    hemisphere boundary, and ``--hemisphere auto`` is the remedy.
    """
    from ..solve import Status, hemisphere_vectors

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
                reason = _generic_reason(status, args)
                if status == Status.NOT_CONVERGED and fixtures is not None:
                    reason += _residual_note(fixtures, status,
                                             np.ones(len(fixtures.pairs), bool)
                                             if mask is None else mask)
            entry = {"status": status.name.lower(), "rows": rows, "reason": reason}
            if per_pair is not None:
                sel = np.ones(len(fixtures.pairs), bool) if mask is None else mask
                by_code: dict = {}
                for k in np.flatnonzero(sel & (per_pair > 0)):
                    code = fixtures.pairs[k][0]
                    by_code[code] = by_code.get(code, 0) + int(per_pair[k])
                entry["source_fixtures"] = by_code
            out.append(entry)
    return out
