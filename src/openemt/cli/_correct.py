"""``openemt correct fit|apply``: output correction of tracker poses against a reference.

``fit`` reads pose-pair files (CSV with ``ref_`` columns, or pose datasets; ``openemt align``
writes them), fits a correction (or picks one, "none" included, with ``--method auto``) and
prints its in-sample and held-out errors beside those of no correction. ``apply`` corrects the
poses inside the correction's fitted box, passes the others through, and writes a status per
row. The workflows are :func:`openemt.correct.fit_correction_files` and
:func:`openemt.correct.apply_correction_file` (docs/correction.md).
"""

from __future__ import annotations

import sys

from ..correct import ApplyOptions, FitOptions, apply_correction_file, fit_correction_files
from . import command_help
from ._common import add_common, add_options, emit, options_from

__all__ = ["register", "run_apply", "run_fit"]


def register(sub) -> None:
    p = sub.add_parser("correct", help=command_help("correct"),
                       description=__doc__.splitlines()[0])
    actions = p.add_subparsers(dest="action", metavar="ACTION")
    actions.required = True
    f = actions.add_parser("fit", help="fit a correction to pose pairs (CSV)")
    add_options(f, FitOptions)
    add_common(f)
    f.set_defaults(func=run_fit)
    a = actions.add_parser("apply", help="apply a correction to poses inside its fitted box")
    add_options(a, ApplyOptions)
    add_common(a)
    a.set_defaults(func=run_apply)


def _warn(args, warnings) -> None:
    if not args.quiet:
        for w in warnings:
            print(f"warning: {w}", file=sys.stderr)


def run_fit(args) -> int:
    res = fit_correction_files(options_from(FitOptions, args))
    emit(args, res.to_dict(), res.lines())
    _warn(args, res.warnings)
    return 0


def run_apply(args) -> int:
    res = apply_correction_file(options_from(ApplyOptions, args))
    emit(args, res.to_dict(), res.lines())
    _warn(args, res.warnings)
    return 0
