"""``openemt demo``: the whole pipeline on the simulated tracker (no hardware): simulate,
calibrate, correct, solve and score, ending in an HTML report and the next commands to try.

The steps are :func:`openemt.report.run_demo`'s; each is announced before it runs.
"""

from __future__ import annotations

from ._common import add_command, run_workflow


def register(sub) -> None:
    from ..report import DemoOptions

    add_command(sub, "demo", run, DemoOptions)


def run(args) -> int:
    from ..report import DemoOptions, run_demo

    return run_workflow(args, run_demo, DemoOptions)
