"""``openemt points``: thin layer over :func:`openemt.navigate.points` (options:
:class:`openemt.navigate.PointsOptions`)."""

from __future__ import annotations

__all__ = ["register"]


def register(sub) -> None:
    from ..navigate import PointsOptions, points
    from ._navcommon import add_step

    add_step(sub, "points", PointsOptions, points)
