"""``openemt design``: accuracy maps, board and rig-source optimisation, carrier plans (docs/design.md)."""

from __future__ import annotations

from ._common import add_actions, add_command

__all__ = ["register"]


def register(sub) -> None:
    from .. import design

    p = add_command(sub, "design",
                    description="Design a tracker before building it: accuracy maps, board "
                                "layout optimisation and carrier plans (docs/design.md).")
    add_actions(p, (
        ("map", "the Cramer-Rao bound of the pose over a volume, beside Monte Carlo solves",
         design.MapOptions, design.design_map),
        ("optimize", "optimise a board's coil layout (or a rig source) for its position bound",
         design.OptimizeOptions, design.optimize_layout),
        ("carriers", "carrier plans: crosstalk, mains and intermodulation in the demodulator",
         design.CarrierOptions, design.carrier_plan)),
        # its models' and solvers' kernels compile inside the workflows (no list names them
        # all): a first run says so when the first one starts
        watch_compiles=True)
