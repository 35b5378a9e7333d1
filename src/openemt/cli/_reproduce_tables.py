"""``openemt reproduce table3|table4 ILEMT_DIR``: MacLachlan et al. 2025, Tables III and IV from raw data.

:func:`add_table_commands` adds the two subcommands to the ``reproduce`` command's subparsers.
"""

from __future__ import annotations

from .._compile_notice import announce_compile
from ._common import add_common, emit, stage

__all__ = ["add_table_commands", "run_table3", "run_table4"]


def add_table_commands(reproduce_subparsers) -> None:
    """Add ``table3`` and ``table4`` to the subparsers of ``openemt reproduce``."""
    p = reproduce_subparsers.add_parser(
        "table3", help="MacLachlan et al. 2025, Table III (calibration vs test dimensionality)",
        description="MacLachlan et al. 2025, Table III from an ILEMT folder: the paper's calibration sequence "
                    "from base_calibration.mat, then the translation-only, sensor-fixture and "
                    "both-fixture calibrations tested (uncorrected) on the ldtrans, "
                    "sensor-fixture and source+sensor-fixture test sets, with the paper's "
                    "values and ratios.")
    p.add_argument("folder", metavar="ILEMT_DIR", help="ILEMT data folder")
    add_common(p)
    p.set_defaults(func=run_table3)

    p = reproduce_subparsers.add_parser(
        "table4", help="MacLachlan et al. 2025, Table IV (axis-sweep cross-coupling and nonlinearity)",
        description="MacLachlan et al. 2025, Table IV from the sweep files of an ILEMT folder: XYZ_hr_cal from "
                    "the paper's sequence, stage and sensor fixtures re-optimised in pose "
                    "space, direct/cross absolute error and Savitzky-Golay nonlinearity. The "
                    "paper's values (another collection) are listed for comparison.")
    p.add_argument("folder", metavar="ILEMT_DIR", help="ILEMT data folder")
    p.add_argument("--uncorrected", action="store_true",
                   help="report the uncorrected solutions as the main rows (default: with the "
                        "output correction, the paper's condition)")
    add_common(p)
    p.set_defaults(func=run_table4)


def _cell(c) -> str:
    return (f"{c['trans_rms_mm']:7.3f} {c['trans_max_mm']:7.3f} {c['rot_rms_deg']:6.3f} "
            f"{c['rot_max_deg']:6.3f}")


def run_table3(args) -> int:
    from ..io import import_ilemt_folder
    from ..paper import TABLE3_COLUMNS, TABLE3_ROWS, reproduce_table3
    from ..paper._run import check_paper_folder

    check_paper_folder(args.folder)      # bad input refused before any stage line
    dataset = import_ilemt_folder(args.folder)
    announce_compile(args, "solver kernels")
    stage(args, f"reproducing Table III on {args.folder}: three calibrations and their tests "
                "...")
    out = reproduce_table3(args.folder, dataset=dataset).to_dict()
    human = [(f"Table III on {args.folder}: per test set trans rms/max (mm), rot rms/max (deg); "
              "paper below")]
    human.append(f"{'calibration':17s}" + "".join(f"{c:>30s}" for c in TABLE3_COLUMNS))
    for row in TABLE3_ROWS:
        human.append(f"{row:17s}" + "".join(f"{_cell(out[row][c]):>30s}"
                                            for c in TABLE3_COLUMNS))
        human.append(f"{'  paper':17s}" + "".join(f"{_cell(out[row][c]['paper']):>30s}"
                                                  for c in TABLE3_COLUMNS))
    human.append(f"max |ours/paper - 1| = {100 * out['max_deviation']:.2f} %; "
                 f"total {out['seconds']['total']:.2f} s")
    emit(args, out, human)
    return 0


def run_table4(args) -> int:
    from ..io import import_ilemt_folder
    from ..paper import reproduce_table4
    from ..paper._run import check_paper_folder

    check_paper_folder(args.folder)      # bad input refused before any stage line
    dataset = import_ilemt_folder(args.folder)
    announce_compile(args, "solver kernels")
    stage(args, f"reproducing Table IV on {args.folder}: calibration, sweep solves and fixture "
                "re-optimisation ...")
    out = reproduce_table4(args.folder, correction=not args.uncorrected,
                           dataset=dataset).to_dict()
    human = [(f"Table IV on {args.folder} ({out['condition']}; {out['n_curves']['xyz']} "
              f"translation and {out['n_curves']['rot']} rotation sweeps): ours (paper)")]
    for row in ("direct", "cross"):
        for k, v in out[row].items():
            human.append(f"  {row:6s} {k:28s} {v:9.4f}  ({out['paper'][row][k]:g})")
    human.append(f"total {out['seconds']['total']:.2f} s")
    emit(args, out, human)
    return 0


#: ``reproduce`` table name -> command function, for a parser with a positional table choice.
