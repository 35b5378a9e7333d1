"""``openemt design``: accuracy maps, board and rig-source optimisation, carrier plans (docs/design.md)."""

from __future__ import annotations

from . import command_help
from ._common import add_common, add_options, emit, options_from

__all__ = ["register"]


def register(sub) -> None:
    from .. import design

    p = sub.add_parser("design", help=command_help("design"),
                       description="Design a tracker before building it: accuracy maps, board "
                                   "layout optimisation and carrier plans (docs/design.md).")
    actions = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    for name, cls, run, text in (
            ("map", design.MapOptions, design.design_map,
             "the Cramer-Rao bound of the pose over a volume, beside Monte Carlo solves."),
            ("optimize", design.OptimizeOptions, design.optimize_layout,
             "optimise a board's coil layout (or a rig source) for its position bound."),
            ("carriers", design.CarrierOptions, design.carrier_plan,
             "carrier plans: crosstalk, mains and intermodulation in the demodulator.")):
        a = actions.add_parser(name, help=text, description=text)
        add_options(a, cls)
        add_common(a)
        a.set_defaults(func=lambda args, c=cls, f=run: _run(args, c, f))


def _run(args, cls, workflow) -> int:
    r = workflow(options_from(cls, args))
    emit(args, r.to_dict(), r.lines())
    return 0
