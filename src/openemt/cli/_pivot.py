"""``openemt pivot``: thin layer over :func:`openemt.navigate.pivot` (options:
:class:`openemt.navigate.PivotOptions`)."""

from __future__ import annotations

__all__ = ["register"]


def register(sub) -> None:
    from ..navigate import PivotOptions, pivot
    from ._navcommon import add_step

    add_step(sub, "pivot", PivotOptions, pivot)
