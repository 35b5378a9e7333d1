"""``openemt calibrate`` as a library workflow: one calibration mode fitted to a dataset
(:func:`calibrate_dataset`, options :class:`CalibrateOptions`, result
:class:`CalibrateResult`), every mode scored on rows it did not fit: the paper's test rows for
the rig modes and ``improved``, a held-out part of the grid or of the reference poses for
``planar`` and ``reference`` (docs/calibration.md)."""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .._errors import InputError
from .._options import option as _opt
from .._result import Result
from ._modes import MODES

__all__ = ["CalibrateOptions", "CalibrateResult", "calibrate_dataset", "load_dataset"]


@dataclass(frozen=True)
class CalibrateOptions:
    """The options of :func:`calibrate_dataset` (``openemt calibrate``; the help texts are the
    command's)."""

    dataset: Path | None = _opt(None, "ILEMT folder, dataset .h5 or .csv", positional=True,
                                metavar="DATASET")
    start: Path | None = _opt(None, "starting calibration (.json or ILEMT .mat); default: the "
                              "folder's base_calibration.mat", flag="--from", metavar="CAL")
    mode: str = _opt(
        "XYZ", "calibration mode (default XYZ); 'improved': openemt's rig and octupole model "
        "on the md rows (start from an XYZ calibration); 'planar': per-coil gain and offset "
        "of an Anser-style board from a grid CSV (x, y, z, ux, uy, uz, one column per coil) "
        "or a simulated dataset with known poses; 'reference': coil model and the X, Y of A "
        "X = Y B against the reference poses of a robot arm or optical tracker "
        "(docs/reference-calibration.md)",
        choices=tuple(sorted(MODES)) + ("improved", "planar", "reference"))
    holdout: str | None = _opt(
        None, "reference mode: hold out this fraction of the poses at random, or 'location' "
        "(alternate regions of the volume), and report their error with the calibration "
        "fitted on the others; planar mode: 'checkerboard' fits on alternate grid points and "
        "solves the others, 'location' holds out alternate regions; the rig modes and "
        "'improved' always score the paper's test rows (docs/calibration.md)",
        metavar="FRACTION|checkerboard|location")
    seed: int = _opt(0, "reference mode: seed of the held-out choice (default 0)")
    weighting: str = _opt(
        "auto", "reference mode: 'errors-in-variables' weights each pose's couplings by the "
        "covariance the stated reference noise gives them, 'ordinary' weights every coupling "
        "alike (the paper's residual); default 'auto': errors-in-variables when the dataset "
        "states its reference noise (docs/reference-calibration.md#errors-in-variables)",
        choices=("auto", "errors-in-variables", "ordinary"))
    accept_reference_residual: bool = _opt(
        False, "reference mode: keep a fit whose reference residual exceeds the stated "
        "reference noise more than 10 times (refused otherwise)")
    hemisphere: str | None = _opt(None, "reference mode: hemisphere of the sensor for the start "
                                  "solve (+x, -x, ...; default: the dataset's, else +x)")
    sensor_length: float | None = _opt(
        None, "planar mode: sensor coil length (m) for the field average (default: the board "
        "file's sensor length)", metavar="M")
    board: str | None = _opt(None, "planar mode: board geometry file (.toml/.json) or built-in "
                             "name (default: anser); see docs/planar.md", metavar="BOARD")
    tilt: bool = _opt(False, "planar mode: also fit a small tilt of each coil (the same as "
                      "--environment tilt)")
    environment: str = _opt(
        "auto", "environment terms (metal near the tracker, the acquisition): 'auto' "
        "(default) chooses them by cross-validation on the training rows ('improved': induced "
        "dipole, gain non-linearity, ... by md cross-validation; 'planar': none, tilt, an "
        "induced dipole or both by grid cross-validation), 'none', or a list of dipoles:K, "
        "gain, offset, tilt (planar: tilt and dipoles:K); the "
        "choice and each candidate's held-out error go to the calibration's provenance "
        "(docs/calibration.md#environment-terms-environment); the paper's modes fit none",
        metavar="auto|none|dipoles:K,gain,offset,tilt")
    output: Path | None = _opt(None, "write the calibration here", flag=("-o", "--output"),
                               metavar="CAL.json")
    all_rows: bool = _opt(False, "fit every row instead of the rows the mode names (then no "
                          "row is held out)")
    optimize: str | None = _opt(None, "override the free parameter groups", metavar="G1,G2")
    freeze: str | None = _opt(None, "override the frozen parameter groups", metavar="G1,G2")
    correction: str = _opt("auto", "fit the DLT output correction on the calibration rows with "
                           "this pose solver (auto: kim18 for concentric modes, lm otherwise)",
                           choices=("auto", "none", "lm", "kim18"))

    def __post_init__(self):
        if self.dataset is None:
            raise InputError("expected a dataset (ILEMT folder, .h5 or .csv), got none")
        if self.weighting != "auto" and self.mode != "reference":
            raise InputError(f"expected --weighting with --mode reference only, got --mode "
                             f"{self.mode}")
        from ._environment import parse_environment

        env = parse_environment(self.environment)
        if env.mode == "given" and self.mode not in ("improved", "planar"):
            raise InputError(f"expected --environment auto or none in mode {self.mode} (the "
                             f"paper's and the reference modes fit no environment terms), got "
                             f"{self.environment!r}")
        if self.mode == "planar" and (env.gain or env.offset):
            raise InputError(f"expected --environment auto, none or a list of tilt and "
                             f"dipoles:K in planar mode, got {self.environment!r}")
        if self.mode == "improved" and (env.dipoles > 1 or env.tilt):
            raise InputError(f"expected --environment with at most dipoles:1 and without tilt "
                             f"in improved mode (the rig model fits one induced dipole; its "
                             f"coil moments' directions are fitted anyway), got "
                             f"{self.environment!r}")
        if self.holdout is not None and self.mode not in ("planar", "reference"):
            raise InputError(f"expected --holdout with --mode planar or reference only (mode "
                             f"{self.mode} scores the paper's test rows), got {self.holdout!r}")


@dataclass(frozen=True)
class CalibrateResult(Result):
    """What :func:`calibrate_dataset` fitted: the ``calibration`` (written to ``output`` when
    given), the mode's fit figures (``details``), the error on rows it did not fit
    (``holdout``; None with the reason in ``warnings`` where the dataset has none), warnings
    and times. ``to_dict()`` is ``openemt calibrate --json``."""

    _not_in_dict = ("calibration", "human")

    mode: str
    output: str | None
    start: str | None
    details: dict
    holdout: dict | None
    warnings: list
    seconds: object
    calibration: object = None
    human: tuple = ()

    def _items(self) -> dict:
        d = dict(self.details)
        # one name per concept across openemt (rms_residual, n_points: the planar fit's); the
        # ILEMT names rms_residue / num_points stay beside them for one deprecation period
        for new, old in (("rms_residual", "rms_residue"), ("n_points", "num_points")):
            if old in d and new not in d:
                d[new] = d[old]
        return {"mode": self.mode, "output": self.output, "start": self.start, **d,
                "holdout": self.holdout, "warnings": self.warnings, "seconds": self.seconds}

    def lines(self) -> list[str]:
        """The human summary (stderr of ``openemt calibrate``)."""
        return list(self.human) + [f"warning: {w}" for w in self.warnings] + \
            ([f"wrote {self.output}"] if self.output else [])


def load_dataset(path):
    """A Dataset from an ILEMT folder, a dataset file or a CSV export."""
    from ..io import import_csv, import_ilemt_folder, read_dataset

    path = Path(path)
    if path.is_dir():
        return import_ilemt_folder(path)
    if not path.exists():
        raise FileNotFoundError(f"expected a dataset folder or file, got missing {str(path)!r}")
    if path.suffix.lower() == ".csv":
        return import_csv(path)
    return read_dataset(path)


def calibrate_dataset(options: CalibrateOptions, *, stage=None, compiling=None,
                      nominal=None) -> CalibrateResult:
    """Fit the calibration of ``options.mode`` to ``options.dataset`` and score it on rows it
    did not fit; write it to ``options.output`` (atomically) when given.

    ``stage(text)`` is told what the workflow does next, ``compiling(what, kernels)`` before
    the first compiled kernels run (both optional). ``nominal(preset)`` gives the start of
    a reference calibration of a simulated dataset without ``--from``
    (:func:`openemt.simulate.nominal_calibration`, a layer above this one).
    """
    from .._compile_notice import PLANAR_KERNELS, SOLVER_KERNELS

    say = stage or (lambda text: None)

    def compile_(what, kernels=SOLVER_KERNELS):
        if compiling is not None:
            compiling(what, kernels)

    t0 = time.perf_counter()
    if options.mode == "planar":
        run = _planar(options, say,
                      lambda extra=(): compile_("finite-coil kernels", PLANAR_KERNELS + extra))
    elif options.mode == "reference":
        run = _reference(options, nominal, say, compile_)
    else:
        run = _rig(options, say, lambda: compile_("solver kernels"))
    total = time.perf_counter() - t0
    result = replace(run, seconds=total)
    if isinstance(run.seconds, dict):          # a fit's seconds, and the total in its stats
        cal = run.calibration
        result = replace(run, seconds={**run.seconds, "total": total},
                         calibration=cal.replace(stats={**cal.stats, "seconds": total}))
    if options.output:
        from ..io import write_calibration

        write_calibration(result.calibration, options.output)        # atomic
    return result


def _groups(text):
    if text is None:
        return None
    return tuple(g.strip() for g in text.split(",") if g.strip())


def _path(p):
    return None if p is None else str(p)


def _planar(o, say, compile_) -> CalibrateResult:
    """Planar mode: fit a finite-coil board to a grid CSV (docs/planar.md#calibration)."""
    from ..board import BoardModel
    from ..io import load_board, read_calibration
    from ..solve import planar_accuracy
    from ._environment import (
        PLANAR_CANDIDATES,
        fit_board_environment,
        parse_environment,
        planar_environment_cv,
    )
    from ._planar import check_grid_units, fit_planar, read_grid
    from ._split import holdout_split

    if o.holdout not in (None, "checkerboard", "location"):
        raise InputError(f"expected --holdout checkerboard (or location) in planar mode, got "
                         f"{o.holdout!r}")
    data = read_grid(o.dataset)
    check_grid_units(data, o.sensor_length)
    if o.start is not None:
        start = read_calibration(o.start)
        if not isinstance(start.model, BoardModel):
            raise InputError(f"expected a finite-coil (planar) calibration for --from in planar "
                             f"mode, got a {start.model.kind!r} model calibration")
        if o.board is not None:
            raise InputError("expected either --from CAL or --board BOARD in planar mode, "
                             "got both")
        start_model = start.model
    else:
        start_model = load_board(o.board)           # least-squares gains, zero offsets
    if o.sensor_length is not None:
        board = start_model.board if isinstance(start_model, BoardModel) else start_model
        board = replace(board, sensor=replace(board.sensor, length=float(o.sensor_length)))
        start_model = (start_model.replace(board=board)
                       if isinstance(start_model, BoardModel) else board)
    fit_mask = (~holdout_split(o.holdout, len(data.points), points=data.points)
                if o.holdout else np.ones(len(data.points), bool))
    need = 7 if o.tilt else 5                     # more points than parameters per coil
    if fit_mask.sum() < need or (o.holdout and (~fit_mask).sum() < 1):
        raise InputError(f"expected at least {need} grid points to fit"
                         f"{' and one to hold out' if o.holdout else ''}, got "
                         f"{len(data.points)} points")

    env = parse_environment(o.environment)
    # the induced dipoles' fields (the cross-validated choice tries them) come from the dipole
    # model's Jacobian kernel
    from .._compile_notice import INDUCED_DIPOLE_KERNELS

    compile_(INDUCED_DIPOLE_KERNELS if (env.mode == "auto" and not o.tilt) or env.dipoles
             else ())
    tilt, dipoles, env_prov = bool(o.tilt or env.tilt), env.dipoles, None
    if env.mode == "auto" and not o.tilt:
        say(f"choosing the environment terms by cross-validation on {int(fit_mask.sum())} "
            f"grid points ...")
        chosen, scores = planar_environment_cv(
            data.subset(fit_mask), start_model,
            lambda d, m, tilt=False: fit_planar(d, m, fit_tilt=tilt, uncertainty=False))
        tilt = bool(PLANAR_CANDIDATES[chosen].get("tilt"))
        dipoles = int(PLANAR_CANDIDATES[chosen].get("dipoles", 0))
        env_prov = {"chosen": [] if chosen == "none" else chosen.split(","),
                    "method": "cross-validation", "candidates": scores}
    else:
        env_prov = {"chosen": (["tilt"] if tilt else []) +
                    ([f"dipoles:{dipoles}"] if dipoles else []), "method": "given",
                    "candidates": {}}
    say(f"fitting the gains and offsets{' and tilts' if tilt else ''} of "
        f"{data.couplings.shape[1]} coils{f' and {dipoles} induced dipole(s)' if dipoles else ''}"
        f" on {int(fit_mask.sum())} grid points ...")
    both = fit_board_environment(data.subset(fit_mask), start_model,
                                 lambda d, m, tilt=False: fit_planar(d, m, fit_tilt=tilt),
                                 tilt=tilt, dipoles=dipoles)
    fit, model = both.board, both.model
    say("solving the grid points with the fitted board (5-DOF) to score it ...")
    insample = planar_accuracy(model, data.subset(fit_mask))
    holdout = None
    if o.holdout:
        holdout = {**planar_accuracy(model, data.subset(~fit_mask)), "scheme": o.holdout}
    warns = []
    if fit.status != "converged":
        warns.append(f"the planar fit ended with status {fit.status!r} after {fit.iterations} "
                     f"iterations (condition {fit.condition:.3g}): its parameters are not a "
                     f"converged least-squares solution")
    if holdout is None:
        warns.append("no held-out score: give --holdout checkerboard (or location) to score "
                     "the board on grid points it did not fit")
    cal = fit.to_calibration(
        insample=insample, holdout=holdout,
        provenance={"grid_file": str(o.dataset), "start_file": _path(o.start),
                    "board": o.board or (None if o.start else "anser"),
                    "fit_tilt": tilt, "holdout": o.holdout, "environment": env_prov})
    if both.terms is not None:
        cal = cal.replace(extra={**cal.extra, "environment": both.terms.to_dict()})
    human = [(f"planar: {len(fit.model.gains)} coils, fit {fit.status} in {fit.iterations} "
              f"iterations, max |offset| {np.abs(fit.model.offsets).max() * 1e3:.3f} mm, "
              f"in-sample {insample['position_rms_mm']:.3f} mm RMS over {insample['n']} "
              f"points")]
    if holdout is not None:
        human.append(f"held out ({o.holdout}): {holdout['position_rms_mm']:.3f} mm RMS, "
                     f"{holdout['position_max_mm']:.3f} mm max, {holdout['axis_rms_deg']:.3f} "
                     f"deg RMS over {holdout['n']} points")
    if env_prov["method"] == "cross-validation":
        human.append("environment (auto): " + ", ".join(
            f"{k} {v['cv_position_rms_mm']:.3f} mm" for k, v in env_prov["candidates"].items()
            if v["cv_position_rms_mm"] is not None) + " cross-validated on the fitted grid "
            f"points -> {','.join(env_prov['chosen']) or 'none'}")
    return CalibrateResult("planar", _path(o.output), _path(o.start),
                           {"board": fit.model.board.name, **fit.to_dict(),
                            "insample": insample, "environment": env_prov}, holdout, warns,
                           0.0, cal, tuple(human))


def _rig(o, say, compile_) -> CalibrateResult:
    """A rig mode (XYZ, concentric, ...) or ``improved``, on an ILEMT-style dataset."""
    from ..field import solver_family
    from ..io import read_calibration
    from ._check import held_out_rows, solve_held_out
    from ._fit import check_fit_inputs, fit
    from ._modes import get_mode, select_rows
    from ._sequence import fit_output_correction

    dataset = load_dataset(o.dataset)
    start_path = _start_file(o)
    if start_path is None:
        raise InputError("expected --from CAL (no base_calibration.mat in the dataset "
                         "folder), got none")
    start = read_calibration(start_path)
    if solver_family(start.model) != "dipole":       # the rig's modes name dipole groups
        what = "finite-coil board" if start.model.kind == "finite" else \
            f"{start.model.kind!r} model"
        raise InputError(f"expected a dipole-model calibration for --from in mode "
                         f"{o.mode}, got a {what} calibration (--mode planar)")
    test = held_out_rows(dataset)
    if o.mode == "improved":
        from ._environment import improved_environment, parse_environment
        from ._heldout import improved_calibration

        compile_()
        env = parse_environment(o.environment)
        say(f"fitting the improved rig and octupole model on the md rows of {o.dataset}"
            + (", choosing its terms by md cross-validation" if env.mode == "auto" else "")
            + " ...")
        imp = improved_calibration(dataset, start, None, **improved_environment(env))
        cal = imp.to_calibration(start)
        details = imp.to_dict()
        human = [(f"improved: rms_residue {imp.rms_residue:.7g}, {imp.n_free} free parameters "
                  f"({imp.extra_parameters()} beyond XYZ)")]
        ep = imp.environment_provenance()
        details["environment"] = ep
        human.append(f"environment ({env.label()}): "
                     + (", ".join(ep["chosen"]) or "none")
                     + "".join(f"; {c['term']} {'kept' if c['kept'] else 'not kept'} (md CV "
                               f"{c['cv_trans_rms_mm_before']:.4f} -> "
                               f"{c['cv_trans_rms_mm_after']:.4f} mm)"
                               for c in ep["candidates"]))
        caught, seconds = [], 0.0
        score = (lambda rows: imp.test(rows).to_dict()) if test.any() else None
    else:
        mode = get_mode(o.mode)
        opt, frz = _groups(o.optimize), _groups(o.freeze)
        check_fit_inputs(dataset, start, mode, select=not o.all_rows, optimize=opt, freeze=frz)
        compile_()
        say(f"fitting mode {mode.name} from {start_path} ...")
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            f = fit(dataset, start, mode, select=not o.all_rows, optimize=opt, freeze=frz)
        cal, stats = f.calibration, dict(f.calibration.stats)
        solver = o.correction if o.correction != "auto" else \
            "kim18" if mode.concentric else "lm"
        corr = None
        if solver != "none":
            rows = dataset if o.all_rows else dataset.select(select_rows(dataset, mode))
            say(f"fitting the output correction on {len(rows)} rows ({solver} poses) ...")
            corr = fit_output_correction(rows, cal, solver=solver)
            stats.update(num_invalid=corr.n_invalid, uncorrected=corr.rms_uncorrected,
                         corrected=corr.rms_corrected, correction_method=corr.method)
            cal = cal.replace(linear_correction=corr.matrix)
        cal = cal.replace(stats=stats)
        ident = f.identifiability
        details = {
            "rms_residue": stats["rms_residue"],
            "sum_squared_residue": stats["sum_squared_residue"],
            "num_points": stats["num_points"], "n_free": int(f.free.size),
            "free_groups": list(cal.free), "frozen_groups": list(cal.frozen),
            "jacobian_rank": ident.rank, "condition": ident.to_dict()["condition"],
            "undetermined_groups": list(ident.undetermined),
            "correction": None if corr is None else {
                "method": corr.method, "n_invalid": corr.n_invalid,
                "rms_uncorrected_mm": corr.rms_uncorrected * 1e3,
                "rms_corrected_mm": corr.rms_corrected * 1e3}}
        human = [(f"{mode.name}: rms_residue {stats['rms_residue']:.7g} over "
                  f"{stats['num_points']} rows, {f.free.size} free parameters (rank "
                  f"{ident.rank}, condition {ident.condition:.3g})")]
        if corr is not None:
            human.append(f"output correction ({corr.method}): {corr.rms_uncorrected * 1e3:.4f}"
                         f" -> {corr.rms_corrected * 1e3:.4f} mm on "
                         f"{corr.n_points - corr.n_invalid} valid rows")
        seconds = {"fit": f.seconds}
        fitted = test & (np.ones(len(test), bool) if o.all_rows
                         else select_rows(dataset, mode))
        score = None if not test.any() or fitted.any() else (
            lambda rows: solve_held_out(rows, cal, concentric_model=None,
                                        apply_correction=cal.linear_correction is not None
                                        ).to_dict())
    warns = [str(w.message) for w in caught]
    holdout = None
    if score is None:
        warns.append("no held-out score: the dataset has none of the paper's test rows (ld "
                     "rows of the home source fixture)" if not test.any() else
                     "no held-out score: --all-rows fits the paper's test rows too")
    else:
        say(f"solving the {int(test.sum())} held-out test rows (ld, home source fixture) ...")
        holdout = {"rows": "the paper's test rows (ld, home source fixture)",
                   "n": int(test.sum()), **score(dataset.select(test))}
        s = holdout.get("summary") or holdout.get("improved_corrected") or \
            holdout.get("improved") or {}
        if "trans_rms_mm" in s:
            human.append(f"held out ({holdout['n']} test rows): {s['trans_rms_mm']:.4f} mm RMS, "
                         f"{s['rot_rms_deg']:.4f} deg RMS")
    cal = cal.replace(provenance={**cal.provenance, "start_file": str(start_path)})
    return CalibrateResult(o.mode if o.mode == "improved" else get_mode(o.mode).name,
                           _path(o.output), str(start_path), details, holdout, warns, seconds,
                           cal, tuple(human))


def _start_file(o):
    """``--from``, else the dataset folder's ``base_calibration.mat``, else None."""
    if o.start is not None:
        return o.start
    cand = Path(o.dataset) / "base_calibration.mat"
    return cand if cand.is_file() else None


def _reference_start(o, dataset, nominal):
    from ..io import read_calibration

    path = _start_file(o)
    if path is not None:
        return read_calibration(path), str(path)
    preset = dataset.meta.get("preset")
    if preset is None or nominal is None:
        raise InputError("expected --from CAL (the dataset names no simulated preset and has "
                         "no base_calibration.mat), got none")
    return nominal(preset), f"nominal model of preset {preset}"


def reference_kernels(model) -> tuple[str, tuple]:
    """``(what, kernels)``: the compiled kernels a reference calibration of ``model`` runs
    (its solves of the training and held-out rows; a board's per-coil cold starts run the
    5-DOF solver), named for the compile notice."""
    from .._compile_notice import PLANAR_KERNELS, solve_kernels

    what, kernels = solve_kernels(model, cold_start_table=True)
    if hasattr(model, "board"):             # and the couplings' spectral norms (weights)
        kernels = tuple(dict.fromkeys(
            kernels + PLANAR_KERNELS + ("openemt.solve._closed_form:_spectral_norms",)))
    return what, kernels


def _reference(o, nominal, say, compile_) -> CalibrateResult:
    from .._compile_notice import watch_compiles
    from ._reference import fit_reference, reference_poses

    dataset = load_dataset(o.dataset)
    reference_poses(dataset)                  # none: one error line, exit 2
    # a simulated board preset's nominal start computes its gain scale with the board's
    # compiled coupling: said when that compiles
    with watch_compiles(say, "finite-coil kernels"):
        start, start_path = _reference_start(o, dataset, nominal)
    kind, kernels = reference_kernels(start.model)
    compile_(kind, kernels)
    with warnings.catch_warnings(record=True) as caught, watch_compiles(say):
        warnings.simplefilter("always")
        f = fit_reference(dataset, start, hemisphere=o.hemisphere,
                          freeze=_groups(o.freeze) or (), holdout=_fraction(o.holdout),
                          seed=o.seed, weighting=o.weighting,
                          accept_residual=o.accept_reference_residual)
    cal = f.calibration
    cal = cal.replace(provenance={**cal.provenance, "start_file": start_path})
    ident = f.identifiability
    ref = cal.extra["reference"]
    details = {
        "start_xy": f.start, "weighting": f.weighting, "rms_residue": f.rms_residue,
        "num_points": f.n_train, "n_free": int(f.free.size), "jacobian_rank": ident["rank"],
        "condition": ident["condition"], "xy_condition": ident["xy_condition"],
        "undetermined": ident["undetermined"], "ill_conditioned": ident["ill_conditioned"],
        "X": f.X, "Y": f.Y, "X_se": f.X_se, "Y_se": f.Y_se,
        "se_units": "m, m, m, rad, rad, rad (translation; left rotation about parent axes)",
        "reference": {k: v for k, v in ref.items()
                      if k in ("kind", "noise_trans_m", "noise_rot_rad")},
        "note": None}
    human = [(f"reference: rms_residue {f.rms_residue:.7g} over {f.n_train} poses, "
              f"{f.free.size} free parameters (rank {ident['rank']}), X/Y condition "
              f"{ident['xy_condition'] or float('inf'):.3g}")]
    w = f.weighting
    stated = ("" if ref.get("noise_trans_m") is None else
              f" (stated {1e3 * ref['noise_trans_m']:.4g} mm, "
              f"{np.rad2deg(ref['noise_rot_rad']):.4g} deg)")
    human.append(f"weighting: {w['method']}; the reference poses' residual "
                 f"{1e3 * w['reference_residual_trans_m']:.4g} mm, "
                 f"{np.rad2deg(w['reference_residual_rot_rad']):.4g} deg RMS{stated}")
    if f.holdout:
        h = f.holdout
        human.append(f"held out {h['n']} poses: {h['trans_rms_mm']:.4f} mm RMS "
                     f"({h['trans_max_mm']:.4f} max), {h['rot_rms_deg']:.4f} deg RMS")
    warns = [str(x.message) for x in caught]
    if not f.holdout:
        warns.append("no held-out score: give --holdout FRACTION (or location) to score the "
                     "calibration on reference poses it did not fit")
    return CalibrateResult("reference", _path(o.output), start_path, details,
                           f.holdout or None, warns, {"fit": f.seconds}, cal, tuple(human))


def _fraction(value):
    """``--holdout`` of the reference mode: a fraction in [0, 1) or ``'location'``."""
    if value is None:
        return 0.0
    if value == "location":
        return value
    try:
        f = float(value)
    except ValueError:
        f = math.nan
    if not 0.0 <= f < 1.0:
        raise InputError(f"expected --holdout FRACTION in [0, 1) (or location) in reference "
                         f"mode, got {value!r}")
    return f
