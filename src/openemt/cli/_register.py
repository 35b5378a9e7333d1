"""``openemt register``: thin layer over :func:`openemt.navigate.register` (options:
:class:`openemt.navigate.RegisterOptions`)."""

from ._navcommon import step

__all__ = ["register"]

register = step("register", "RegisterOptions", "register")
