"""Exception types shared by the library and the CLI, and the checks that raise them."""

import math

__all__ = ["InputError", "check_nonnegative"]


class InputError(ValueError):
    """Bad input from a user or a file: the message is one line naming what was expected and
    what arrived. The CLI prints it as ``error: <message>`` and exits with status 2."""


def check_nonnegative(value, name: str) -> float:
    """``value`` as a float if it is finite and >= 0; :class:`InputError` naming ``name``
    otherwise (NaN, infinity and negative values included)."""
    v = float(value)
    if not math.isfinite(v) or v < 0:
        raise InputError(f"expected a finite {name} >= 0, got {value!r}")
    return v
