"""``openemt reproduce table2 ILEMT_DIR``: the paper's calibration procedure as one command."""

from __future__ import annotations

from ._common import add_common, emit

__all__ = ["register", "run"]


def register(sub) -> None:
    p = sub.add_parser(
        "reproduce", help="reproduce a table of the seed papers from raw data",
        description="Reproduce seed 000 Table II from an ILEMT data folder: import, the "
                    "paper's calibration sequence from base_calibration.mat, output correction, "
                    "test solves on the soYoutZup ld files.")
    p.add_argument("table", choices=("table2", "dipole-cost", "recovery"),
                   help="table2: seed 000 Table II from ILEMT_DIR; dipole-cost: accuracy cost of "
                        "the dipole model for finite coils (simulated); recovery: calibration "
                        "parameters against simulated exact-dipole truth, in standard errors")
    p.add_argument("folder", metavar="ILEMT_DIR", nargs="?",
                   help="ILEMT data folder (table2 only)")
    p.add_argument("--preset", default="concentric",
                   help="simulation preset for dipole-cost / recovery (default concentric)")
    p.add_argument("--seed", type=int, default=0, help="simulation seed")
    p.add_argument("--improved", action="store_true",
                   help="also run openemt's improved calibration (fitted on md data only) and "
                        "report rows 'improved' and 'improved_corrected'")
    p.add_argument("--cv", action="store_true",
                   help="with --improved: also cross-validate every model variant on the md "
                        "rows (slower)")
    add_common(p)
    p.set_defaults(func=run)


def _fmt(name, row):
    if row is None:
        return f"{name:20s} (no correction: too few valid calibration solutions)"
    return (f"{name:20s} {row['trans_rms_mm']:8.5f} {row['trans_max_mm']:8.5f} mm  "
            f"{row['rot_rms_deg']:8.5f} {row['rot_max_deg']:8.5f} deg")


def _simulated(args) -> int:
    from ..calibrate import dipole_cost, parameter_recovery

    if args.table == "dipole-cost":
        out = dipole_cost(args.preset, seed=args.seed)
        human = [f"{args.preset}: r/d {out['r_over_d'][0]:.1f}-{out['r_over_d'][1]:.1f}"]
        for k in ("dipole_equivalent_no_fit", "dipole_calibrated", "octupole_calibrated"):
            human.append(_fmt(k, out[k]))
    else:
        out = parameter_recovery(args.preset, seed=args.seed)
        human = [(f"{args.preset}: {out['n_free']} free parameters, max |z| "
                  f"{out['max_abs_z']:.2f}, {100 * out['fraction_within_3']:.0f}% within 3 "
                  "standard errors")]
    emit(args, out, human)
    return 0


def run(args) -> int:
    from ..calibrate import reproduce_table2

    if args.table != "table2":
        return _simulated(args)
    if args.folder is None:
        raise ValueError("expected an ILEMT_DIR for table2, got none")
    out = reproduce_table2(args.folder, improved=args.improved, cross_validation=args.cv)
    human = [(f"Table II on {args.folder} ({out['n_test']} test rows): trans rms/max, "
              "rot rms/max")]
    for name in ("default", "corrected", "concentric", "improved", "improved_corrected"):
        if name in out:
            human.append(_fmt(name, out[name]))
            if name in out["paper"]:
                human.append(_fmt("  paper", out["paper"][name]))
    human.append(f"total {out['seconds']['total']:.2f} s")
    emit(args, out, human)
    return 0
