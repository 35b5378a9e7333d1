"""``openemt design``: Cramer-Rao maps of a tracker over a volume and layout optimisation of a
board (docs/design.md)."""

from __future__ import annotations

from . import command_help
from ._common import add_common, add_options, emit, options_from

__all__ = ["register"]


def register(sub) -> None:
    from ..design import MapOptions, OptimizeOptions

    p = sub.add_parser("design", help=command_help("design"), description=__doc__.split(".")[0])
    actions = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    for name, cls, run, text in (
            ("map", MapOptions, _map, "CRB of position and orientation over a volume"),
            ("optimize", OptimizeOptions, _optimize, "optimise a board's coil layout")):
        a = actions.add_parser(name, help=text, description=text)
        add_options(a, cls)
        add_common(a)
        a.set_defaults(func=run, options_cls=cls)


def _map(args) -> int:
    from ..design import design_map

    r = design_map(options_from(args.options_cls, args))
    s, mc = r.position_mm, r.montecarlo
    emit(args, r.to_dict(), [f"{r.target}: position bound median {s['median']:.4f} mm, p95 "
                             f"{s['p95']:.4f} mm, max {s['max']:.4f} mm (noise {r.noise_sigma:.3g})"]
         + ([f"Monte Carlo RMS / bound, median over {mc['n_points']} points: "
             f"{mc['ratio_median']:.3f}"] if mc else []))
    return 0


def _optimize(args) -> int:
    from ..design import optimize_layout

    r = optimize_layout(options_from(args.options_cls, args))
    emit(args, r.to_dict(), [f"{r.target}: p95 position bound {r.start['position_mm']['p95']:.4f}"
                             f" -> {r.optimized['position_mm']['p95']:.4f} mm "
                             f"({100 * r.improvement_p95:.1f} % lower)"])
    return 0
