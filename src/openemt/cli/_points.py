"""``openemt points``: thin layer over :func:`openemt.navigate.points` (options:
:class:`openemt.navigate.PointsOptions`)."""

from ._navcommon import step

__all__ = ["register"]

register = step("points", "PointsOptions", "points")
