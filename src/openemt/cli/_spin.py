"""``openemt spin``: thin layer over :func:`openemt.navigate.spin` (options:
:class:`openemt.navigate.SpinOptions`)."""

from __future__ import annotations

__all__ = ["register"]


def register(sub) -> None:
    from ..navigate import SpinOptions, spin
    from ._navcommon import add_step

    add_step(sub, "spin", SpinOptions, spin)
