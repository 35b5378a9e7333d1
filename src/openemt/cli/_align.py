"""``openemt align``: thin layer over :func:`openemt.navigate.align_poses` (options:
:class:`openemt.navigate.AlignOptions`)."""

from __future__ import annotations

__all__ = ["register"]


def register(sub) -> None:
    from ..navigate import AlignOptions, align_poses
    from ._navcommon import add_step

    add_step(sub, "align", AlignOptions, align_poses)
