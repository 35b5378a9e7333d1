"""``openemt align``: thin layer over :func:`openemt.navigate.align_poses` (options:
:class:`openemt.navigate.AlignOptions`)."""

from ._navcommon import step

__all__ = ["register"]

register = step("align", "AlignOptions", "align_poses")
