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
    p.add_argument("table", choices=("table2",), help="which table")
    p.add_argument("folder", metavar="ILEMT_DIR", help="ILEMT data folder")
    p.add_argument("--improved", action="store_true",
                   help="also run openemt's improved calibration (fitted on md data only) and "
                        "report rows 'improved' and 'improved_corrected'")
    add_common(p)
    p.set_defaults(func=run)


def _fmt(name, row):
    if row is None:
        return f"{name:20s} (no correction: too few valid calibration solutions)"
    return (f"{name:20s} {row['trans_rms_mm']:8.5f} {row['trans_max_mm']:8.5f} mm  "
            f"{row['rot_rms_deg']:8.5f} {row['rot_max_deg']:8.5f} deg")


def run(args) -> int:
    from ..calibrate import reproduce_table2

    out = reproduce_table2(args.folder, improved=args.improved)
    human = [f"Table II on {args.folder} ({out['n_test']} test rows): trans rms/max, "
             "rot rms/max"]
    for name in ("default", "corrected", "concentric", "improved", "improved_corrected"):
        if name in out:
            human.append(_fmt(name, out[name]))
            if name in out["paper"]:
                human.append(_fmt("  paper", out["paper"][name]))
    human.append(f"total {out['seconds']['total']:.2f} s")
    emit(args, out, human)
    return 0
