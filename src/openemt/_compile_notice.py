"""Say so before the numba kernels compile: the first run of a command after installation spends
tens of seconds compiling (``openemt bench compile`` measures it), and a silent terminal for
that long reads as a hang.

:func:`announce_compile` prints one line, e.g. ``compiling solver kernels (first run only, about
30 s)``, when the on-disk numba cache of any of the named kernels is missing or stale, and
nothing when every kernel will load from the cache. :func:`cold_kernels` is the test underneath:
it asks each kernel's own numba cache (the dispatcher's cache index, where numba itself looks,
``NUMBA_CACHE_DIR`` included) whether an entry exists for the current source file; nothing is
compiled to find out.

Kernels are named ``"module:function"`` (the compiled dispatchers, ``cache=True``); the tuples
below are the groups the commands use. A command calls :func:`announce_compile` after it has
checked its inputs and before the first compiled call, e.g. live tracking::

    announce_compile(args, "tracking kernels", kernels=SOLVER_KERNELS + LIVE_KERNELS)

so that bad input stays one ``error:`` line and the notice comes before the silence.
"""

from __future__ import annotations

import importlib
import sys

__all__ = ["LIVE_KERNELS", "PLANAR_KERNELS", "SOLVER_KERNELS", "announce_compile",
           "cold_kernels"]

#: The dipole model, closed forms and batch LM solver (``solve``, ``calibrate``, ``report``,
#: ``reproduce``, ``demo``).
SOLVER_KERNELS = (
    "openemt.field._dipole_kernel:dipole_batch",
    "openemt.field._dipole_kernel:dipole_batch_jac",
    "openemt.solve._closed_form:_spectral_norms",
    "openemt.solve._closed_form:_closed_form_batch",
    "openemt.solve._lm:lm_batch",
)

#: The finite-coil (board) model and its 5-DOF solver (``calibrate --mode planar``, board
#: ``solve``, ``report`` and ``track``).
PLANAR_KERNELS = (
    "openemt.field._segments:_coupling_batch_impl",
    "openemt.solve._planar:_batch",
)

#: The live path beside the solver kernels: sample-by-sample LM tracking, tracking filter and
#: OpenIGTLink packing (``track`` calls ``SOLVER_KERNELS + LIVE_KERNELS``).
LIVE_KERNELS = (
    "openemt.solve._lm:lm_track",
    "openemt.live._filter:_kalman_kernel",
    "openemt.live._igtl_wire:_pack_kernel",
    "openemt.live._igtl_wire:_frame_kernel",
    "openemt.live._igtl_meta:_levels",
)


def _is_cached(dispatcher) -> bool | None:
    """True if numba's cache index of ``dispatcher`` holds an entry for its current source,
    False if it holds none (missing, stale or another numba version), None if this cannot be
    told (not a caching dispatcher, or numba's cache layout changed)."""
    cache_file = getattr(getattr(dispatcher, "_cache", None), "_cache_file", None)
    load = getattr(cache_file, "_load_index", None)
    if load is None:
        return None
    try:
        return bool(load())  # {} when missing, stale (source stamp) or of another version
    except Exception:  # noqa: BLE001 - an unreadable index is a cold cache to numba as well
        return False


def cold_kernels(kernels=SOLVER_KERNELS) -> list[str]:
    """The kernels among ``kernels`` (``"module:function"``) that would compile on first call.

    A kernel counts as cold when its numba cache index is missing, stale or unreadable, or when
    its cache cannot be inspected at all (so an unknown state is announced, never hidden).
    Importing the modules compiles nothing.

    Examples
    --------
    >>> from openemt._compile_notice import cold_kernels
    >>> isinstance(cold_kernels(), list)
    True
    """
    cold = []
    for spec in kernels:
        module, _, name = str(spec).partition(":")
        dispatcher = getattr(importlib.import_module(module), name)
        if not _is_cached(dispatcher):
            cold.append(spec)
    return cold


def announce_compile(out=None, what: str = "solver kernels", *, kernels=SOLVER_KERNELS,
                     seconds: float = 30) -> bool:
    """Print ``compiling {what} (first run only, about {seconds} s)`` if any of ``kernels`` will
    compile; return whether it printed.

    Parameters
    ----------
    out : argparse.Namespace or text stream, optional
        A command's parsed arguments (the line goes to stderr unless ``--quiet``) or a stream to
        write to; default stderr.
    what : str
        What compiles, in words.
    kernels : sequence of str
        ``"module:function"`` of the compiled kernels the command is about to call
        (:data:`SOLVER_KERNELS`, :data:`PLANAR_KERNELS`, :data:`LIVE_KERNELS` or a mix).
    seconds : float
        The announced compile time.
    """
    if out is None or not hasattr(out, "write"):
        if getattr(out, "quiet", False):
            return False
        out = sys.stderr
    if not cold_kernels(kernels):
        return False
    out.write(f"compiling {what} (first run only, about {seconds:g} s)\n")
    out.flush()
    return True
