"""The ``openemt reproduce`` workflow: a table name and its options in, the reproduction out."""

from __future__ import annotations

import dataclasses

from .._options import SILENT, option
from .._result import Result

__all__ = ["TABLES", "ReproduceOptions", "Reproduction", "improved_lines", "reproduce"]

#: The tables ``reproduce`` makes: name -> (one-line help, description, options it takes).
TABLES = {
    "table2": ("MacLachlan et al. 2025, Table II (default, corrected, concentric)",
               "MacLachlan et al. 2025, Table II from an ILEMT data folder: import, the paper's "
               "calibration sequence from base_calibration.mat, output correction, test solves "
               "on the soYoutZup ld files.", ("folder", "improved", "cv")),
    "table3": ("MacLachlan et al. 2025, Table III (calibration vs test dimensionality)",
               "MacLachlan et al. 2025, Table III from an ILEMT folder: the paper's calibration "
               "sequence from base_calibration.mat, then the translation-only, sensor-fixture "
               "and both-fixture calibrations tested (uncorrected) on the ldtrans, "
               "sensor-fixture and source+sensor-fixture test sets, with the paper's values and "
               "ratios.", ("folder",)),
    "table4": ("MacLachlan et al. 2025, Table IV (axis-sweep cross-coupling and nonlinearity)",
               "MacLachlan et al. 2025, Table IV from the sweep files of an ILEMT folder: "
               "XYZ_hr_cal from the paper's sequence, stage and sensor fixtures re-optimised in "
               "pose space, direct/cross absolute error and Savitzky-Golay nonlinearity. The "
               "paper's values (another collection) are listed for comparison.",
               ("folder", "uncorrected")),
    "dipole-cost": ("accuracy cost of the dipole model for finite coils (simulated)", None,
                    ("preset", "seed")),
    "recovery": ("calibration parameters against simulated exact-dipole truth, in standard "
                 "errors", None, ("preset", "seed")),
}


@dataclasses.dataclass(frozen=True)
class ReproduceOptions:
    """A reproduction (field metadata: the command-line help)."""

    table: str = option("table2", "the table", choices=tuple(TABLES), cli=False)
    folder: str | None = option(None, "ILEMT data folder", positional=True, metavar="ILEMT_DIR")
    improved: bool = option(False, "also run openemt's improved calibration (fitted on md data "
                            "only) and report rows 'improved' and 'improved_corrected'")
    cv: bool = option(False, "with --improved: also cross-validate every model variant on the "
                      "md rows (slower)")
    uncorrected: bool = option(False, "report the uncorrected solutions as the main rows "
                               "(default: with the output correction, the paper's condition)")
    preset: str = option("concentric", "simulation preset (default concentric)")
    seed: int = option(0, "simulation seed")


@dataclasses.dataclass(frozen=True)
class Reproduction(Result):
    """A reproduced table: ``to_dict()`` is the table's own (``result``)."""

    options: ReproduceOptions
    result: Result

    def to_dict(self) -> dict:
        return self.result.to_dict()

    def lines(self) -> list[str]:
        """The human-readable table, ours beside the paper's."""
        return _LINES[self.options.table](self.options, self.result.to_dict())


def reproduce(o: ReproduceOptions, say=None) -> Reproduction:
    """Reproduce table ``o.table`` (bad input refused before any work is announced)."""
    from .._compile_notice import announce_compile

    say = say or SILENT
    if o.table in ("dipole-cost", "recovery"):
        from ._simstudies import dipole_cost, parameter_recovery

        announce_compile(say, "solver kernels")
        say(f"simulating preset {o.preset} and calibrating it ({o.table}) ...")
        fn = dipole_cost if o.table == "dipole-cost" else parameter_recovery
        return Reproduction(o, fn(o.preset, seed=o.seed))
    from ..io import import_ilemt_folder
    from ._run import check_paper_folder, load_paper_run

    check_paper_folder(o.folder)
    dataset = import_ilemt_folder(o.folder)
    announce_compile(say, "solver kernels")
    say({"table2": f"reproducing Table II on {o.folder}: the paper's calibration "
                   "sequence, output correction and test solves"
                   + (", then the improved calibration" if o.improved else "") + " ...",
         "table3": f"reproducing Table III on {o.folder}: three calibrations and their "
                   "tests ...",
         "table4": f"reproducing Table IV on {o.folder}: calibration, sweep solves and "
                   "fixture re-optimisation ..."}[o.table])
    # imported here, at call time, so a test may stand in for a table's function
    if o.table == "table2":
        from ._table2 import reproduce_table2

        out = reproduce_table2(load_paper_run(o.folder, dataset=dataset),
                               improved=o.improved, cross_validation=o.cv)
    elif o.table == "table3":
        from ._table3 import reproduce_table3

        out = reproduce_table3(o.folder, dataset=dataset)
    else:
        from ._table4 import reproduce_table4

        out = reproduce_table4(o.folder, correction=not o.uncorrected, dataset=dataset)
    return Reproduction(o, out)


def _fmt(name, row):
    if row is None:
        return f"{name:20s} (no correction: too few valid calibration solutions)"
    return (f"{name:20s} {row['trans_rms_mm']:8.5f} {row['trans_max_mm']:8.5f} mm  "
            f"{row['rot_rms_deg']:8.5f} {row['rot_max_deg']:8.5f} deg")


def _simulated_lines(o, out) -> list:
    if o.table == "dipole-cost":
        return [f"{o.preset}: r/d {out['r_over_d'][0]:.1f}-{out['r_over_d'][1]:.1f}"] + [
            _fmt(k, out[k]) for k in ("dipole_equivalent_no_fit", "dipole_calibrated",
                                      "octupole_calibrated")]
    return [f"{o.preset}: {out['n_free']} free parameters, max |z| {out['max_abs_z']:.2f}, "
            f"{100 * out['fraction_within_3']:.0f}% within 3 standard errors"]


def improved_lines(out) -> list:
    """Human lines of ``table2 --improved``: the terms tried and why, the held-out breakdown
    before and after each term, and the noise floor."""
    from ..evaluate import ErrorBreakdown

    lines = ["improved: terms tried on md rows only (ld rows only score):"]
    lines += [f"  {d['term']}: {d['reason']}" for d in out["improved_model"]["terms"]]
    steps = {"default": {"breakdown": out["breakdown"]["default"], "kept": True},
             **out["breakdown"]["improved_steps"]}
    names = list(steps)
    lines.append("held-out trans RMS (mm) by group; columns: "
                 + ", ".join(n + ("" if steps[n]["kept"] else " (not kept)") for n in names))
    table = {n: {r["group"]: r for r in ErrorBreakdown(**steps[n]["breakdown"]).rows()}
             for n in names}
    for g in table[names[0]]:
        vals = [table[n].get(g, {}).get("trans_rms_mm") for n in names]
        lines.append(f"  {g:28s} n={table[names[0]][g]['n']:5d} " + " ".join(
            "    -" if v is None else f"{v:6.3f}" for v in vals))
    nf = out["noise_floor"]
    if nf["n_pairs"]:
        lines.append(f"noise floor (md/ld repeat-pose scatter, {nf['n_pairs']} pairs): "
                     f"{nf['trans_rms_mm']:.3f} mm, {nf['rot_rms_deg']:.4f} deg")
    return lines


def _table2_lines(o, out) -> list:
    human = [f"Table II on {o.folder} ({out['n_test']} test rows): trans rms/max, rot rms/max"]
    paper = out["paper"] or {}
    for name in ("default", "corrected", "concentric", "improved", "improved_corrected"):
        if name in out:
            human.append(_fmt(name, out[name]))
            if name in paper:
                human.append(_fmt("  paper", paper[name]))
    if out.get("breakdown"):
        human += improved_lines(out)
    return human + [f"paper column: {out['paper_column']['note']}",
                    f"total {out['seconds']['total']:.2f} s"]


def _cell(c) -> str:
    return (f"{c['trans_rms_mm']:7.3f} {c['trans_max_mm']:7.3f} {c['rot_rms_deg']:6.3f} "
            f"{c['rot_max_deg']:6.3f}")


def _table3_lines(o, out) -> list:
    from ._table3 import TABLE3_COLUMNS, TABLE3_ROWS

    human = [f"Table III on {o.folder}: per test set trans rms/max (mm), rot rms/max (deg); "
             "paper below", f"{'calibration':17s}" + "".join(f"{c:>30s}" for c in TABLE3_COLUMNS)]
    for row in TABLE3_ROWS:
        human.append(f"{row:17s}" + "".join(f"{_cell(out[row][c]):>30s}"
                                            for c in TABLE3_COLUMNS))
        human.append(f"{'  paper':17s}" + "".join(f"{_cell(out[row][c]['paper']):>30s}"
                                                  for c in TABLE3_COLUMNS))
    return human + [f"max |ours/paper - 1| = {100 * out['max_deviation']:.2f} %; "
                    f"total {out['seconds']['total']:.2f} s"]


def _table4_lines(o, out) -> list:
    human = [f"Table IV on {o.folder} ({out['condition']}; {out['n_curves']['xyz']} "
             f"translation and {out['n_curves']['rot']} rotation sweeps): ours (paper)"]
    for row in ("direct", "cross"):
        for k, v in out[row].items():
            human.append(f"  {row:6s} {k:28s} {v:9.4f}  ({out['paper'][row][k]:g})")
    return human + [f"total {out['seconds']['total']:.2f} s"]


_LINES = {"table2": _table2_lines, "table3": _table3_lines, "table4": _table4_lines,
          "dipole-cost": _simulated_lines, "recovery": _simulated_lines}
