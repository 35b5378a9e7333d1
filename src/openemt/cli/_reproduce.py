"""``openemt reproduce TABLE ...``: the published tables from raw data, one command each:
Tables II, III and IV of MacLachlan et al. 2025 from an ILEMT data folder, and two simulation
studies of the calibration."""

from __future__ import annotations

from ._common import add_command, run_workflow


def register(sub) -> None:
    from ..paper import TABLES, ReproduceOptions

    p = add_command(sub, "reproduce")
    tables = p.add_subparsers(dest="table", metavar="TABLE", parser_class=type(p))
    tables.required = True
    for name, (help_, description, fields) in TABLES.items():
        add_command(tables, name, run, ReproduceOptions, fields, help=help_,
                    description=description)


def run(args) -> int:
    from ..paper import ReproduceOptions, reproduce

    return run_workflow(args, reproduce, ReproduceOptions, table=args.table)
