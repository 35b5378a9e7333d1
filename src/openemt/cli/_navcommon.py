"""The navigation commands (``pivot``, ``spin``, ``register``, ``assess``, ``points``,
``align``): each builds its options from its workflow's options record, calls the workflow
and prints; the texts live with the workflows in :mod:`openemt.navigate`."""

from __future__ import annotations

import sys

from ._common import add_command, emit, options_from

__all__ = ["add_step", "run_step", "step"]


def add_step(sub, name: str, options_cls, workflow, after=None):
    """Add command ``name``: the fields of ``options_cls`` as options; running it calls
    ``workflow(options)`` and then ``after(args, run)`` if given."""
    return add_command(sub, name, lambda args: run_step(args, options_cls, workflow, after),
                       options_cls, description=" ".join(options_cls.__doc__.split()))


def run_step(args, options_cls, workflow, after=None) -> int:
    run = workflow(options_from(options_cls, args))
    if after is not None:
        after(args, run)
    emit(args, run.to_dict(), run.lines)
    for w in run.warnings:
        print(f"warning: {w}", file=sys.stderr)
    return 0


def step(name: str, options: str, workflow: str, after=None):
    """``register(sub)`` of command ``name``: :func:`add_step` with the options record and the
    workflow of :mod:`openemt.navigate` so named (imported when the command is registered)."""
    def register(sub) -> None:
        from .. import navigate

        add_step(sub, name, getattr(navigate, options), getattr(navigate, workflow), after)

    return register
