"""``openemt spin``: thin layer over :func:`openemt.navigate.spin` (options:
:class:`openemt.navigate.SpinOptions`)."""

from ._navcommon import step

__all__ = ["register"]

register = step("spin", "SpinOptions", "spin")
