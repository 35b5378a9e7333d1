"""``openemt register``: thin layer over :func:`openemt.navigate.register` (options:
:class:`openemt.navigate.RegisterOptions`)."""

from __future__ import annotations

__all__ = ["register"]


def register(sub) -> None:
    from ..navigate import RegisterOptions
    from ..navigate import register as workflow
    from ._navcommon import add_step

    add_step(sub, "register", RegisterOptions, workflow)
