"""``openemt pivot``: thin layer over :func:`openemt.navigate.pivot` (options:
:class:`openemt.navigate.PivotOptions`)."""

from ._navcommon import step

__all__ = ["register"]

register = step("pivot", "PivotOptions", "pivot")
