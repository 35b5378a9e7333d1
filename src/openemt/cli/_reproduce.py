"""``openemt reproduce TABLE ...``: the published tables from raw data, one command each."""

from __future__ import annotations

from .._compile_notice import announce_compile
from . import command_help
from ._common import add_common, emit, stage
from ._reproduce_tables import add_table_commands

__all__ = ["register", "run_table2"]


def register(sub) -> None:
    p = sub.add_parser(
        "reproduce", help=command_help("reproduce"),
        description="Reproduce the published tables: Table II, III and IV of MacLachlan et al. 2025 from an "
                    "ILEMT data folder, and two simulation studies of the calibration.")
    tables = p.add_subparsers(dest="table", metavar="TABLE", parser_class=type(p))
    tables.required = True

    t2 = tables.add_parser(
        "table2", help="MacLachlan et al. 2025, Table II (default, corrected, concentric)",
        description="MacLachlan et al. 2025, Table II from an ILEMT data folder: import, the paper's "
                    "calibration sequence from base_calibration.mat, output correction, test "
                    "solves on the soYoutZup ld files.")
    t2.add_argument("folder", metavar="ILEMT_DIR", help="ILEMT data folder")
    t2.add_argument("--improved", action="store_true",
                    help="also run openemt's improved calibration (fitted on md data only) and "
                         "report rows 'improved' and 'improved_corrected'")
    t2.add_argument("--cv", action="store_true",
                    help="with --improved: also cross-validate every model variant on the md "
                         "rows (slower)")
    add_common(t2)
    t2.set_defaults(func=run_table2)

    add_table_commands(tables)

    for name, help_ in (
            ("dipole-cost", "accuracy cost of the dipole model for finite coils (simulated)"),
            ("recovery", ("calibration parameters against simulated exact-dipole truth, in "
                         "standard errors"))):
        sp = tables.add_parser(name, help=help_, description=help_)
        sp.add_argument("--preset", default="concentric",
                        help="simulation preset (default concentric)")
        sp.add_argument("--seed", type=int, default=0, help="simulation seed")
        add_common(sp)
        sp.set_defaults(func=_simulated)


def _fmt(name, row):
    if row is None:
        return f"{name:20s} (no correction: too few valid calibration solutions)"
    return (f"{name:20s} {row['trans_rms_mm']:8.5f} {row['trans_max_mm']:8.5f} mm  "
            f"{row['rot_rms_deg']:8.5f} {row['rot_max_deg']:8.5f} deg")


def _simulated(args) -> int:
    from ..paper import dipole_cost, parameter_recovery

    announce_compile(args, "solver kernels")
    stage(args, f"simulating preset {args.preset} and calibrating it ({args.table}) ...")
    if args.table == "dipole-cost":
        out = dipole_cost(args.preset, seed=args.seed).to_dict()
        human = [f"{args.preset}: r/d {out['r_over_d'][0]:.1f}-{out['r_over_d'][1]:.1f}"]
        for k in ("dipole_equivalent_no_fit", "dipole_calibrated", "octupole_calibrated"):
            human.append(_fmt(k, out[k]))
    else:
        out = parameter_recovery(args.preset, seed=args.seed).to_dict()
        human = [(f"{args.preset}: {out['n_free']} free parameters, max |z| "
                  f"{out['max_abs_z']:.2f}, {100 * out['fraction_within_3']:.0f}% within 3 "
                  "standard errors")]
    emit(args, out, human)
    return 0


def _improved_lines(out) -> list:
    """Human lines of ``--improved``: the terms tried and why, the held-out breakdown before
    and after each term, and the noise floor."""
    lines = ["improved: terms tried on md rows only (ld rows only score):"]
    lines += [f"  {d['term']}: {d['reason']}" for d in out["improved_model"]["terms"]]
    steps = {"default": {"breakdown": out["breakdown"]["default"], "kept": True},
             **out["breakdown"]["improved_steps"]}
    names = list(steps)
    lines.append("held-out trans RMS (mm) by group; columns: "
                 + ", ".join(n + ("" if steps[n]["kept"] else " (not kept)") for n in names))
    groups = [r["group"] for r in _rows_of(steps[names[0]]["breakdown"])]
    table = {n: {r["group"]: r for r in _rows_of(steps[n]["breakdown"])} for n in names}
    for g in groups:
        vals = [table[n].get(g, {}).get("trans_rms_mm") for n in names]
        n_rows = table[names[0]][g]["n"]
        lines.append(f"  {g:28s} n={n_rows:5d} " + " ".join(
            "    -" if v is None else f"{v:6.3f}" for v in vals))
    nf = out["noise_floor"]
    if nf["n_pairs"]:
        lines.append(f"noise floor (md/ld repeat-pose scatter, {nf['n_pairs']} pairs): "
                     f"{nf['trans_rms_mm']:.3f} mm, {nf['rot_rms_deg']:.4f} deg")
    return lines


def _rows_of(b: dict) -> list:
    """Flat rows of an ErrorBreakdown dict (as ErrorBreakdown.rows)."""
    from ..evaluate import ErrorBreakdown

    return ErrorBreakdown(**b).rows()


def run_table2(args) -> int:
    from ..io import import_ilemt_folder
    from ..paper import reproduce_table2
    from ..paper._run import check_paper_folder, load_paper_run

    check_paper_folder(args.folder)      # bad input refused before any stage line
    dataset = import_ilemt_folder(args.folder)
    announce_compile(args, "solver kernels")
    stage(args, f"reproducing Table II on {args.folder}: the paper's calibration sequence, "
                "output correction and test solves"
                + (", then the improved calibration" if args.improved else "") + " ...")
    out = reproduce_table2(load_paper_run(args.folder, dataset=dataset), improved=args.improved,
                           cross_validation=args.cv).to_dict()
    human = [(f"Table II on {args.folder} ({out['n_test']} test rows): trans rms/max, "
              "rot rms/max")]
    paper = out["paper"] or {}
    for name in ("default", "corrected", "concentric", "improved", "improved_corrected"):
        if name in out:
            human.append(_fmt(name, out[name]))
            if name in paper:
                human.append(_fmt("  paper", paper[name]))
    if out.get("breakdown"):
        human += _improved_lines(out)
    human.append(f"paper column: {out['paper_column']['note']}")
    human.append(f"total {out['seconds']['total']:.2f} s")
    emit(args, out, human)
    return 0
