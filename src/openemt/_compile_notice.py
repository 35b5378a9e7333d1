"""Compile the numba kernels a command needs before the step that needs them, under a line of
their own: the first run of a command after installation spends seconds compiling
(``openemt bench compile`` lists the time per kernel), and a step that compiles on the side
reads as a slow step, a silent terminal as a hang.

:func:`announce_compile` prints ``compiling N solver kernels (first run only) ...`` when the
on-disk numba cache of any of the named kernels is missing or stale, then compiles those kernels
there and then (a tiny call through the public function that runs each one, so the compiled
types are the ones the command passes), and prints nothing and compiles nothing when every
kernel will load from the cache. After it has run once the kernels are cached, so the next run
of the command is silent. :func:`cold_kernels` is the test underneath: it asks each kernel's
own numba cache (the dispatcher's cache index, where numba itself looks, ``NUMBA_CACHE_DIR``
included) whether an entry exists for the current source file; nothing is compiled to find out.

Kernels are named ``"module:function"`` (the compiled dispatchers, ``cache=True``); the tuples
below are the groups the commands use, and :func:`compile_kernels` compiles any of them. A
command calls :func:`announce_compile` after it has checked its inputs and before the first
compiled call, e.g. live tracking::

    announce_compile(args, "solver kernels", kernels=SOLVER_KERNELS + LIVE_KERNELS)

so that bad input stays one ``error:`` line and the compile has a line of its own.
"""

from __future__ import annotations

import contextlib
import importlib
import sys

__all__ = ["BOARD_LM_KERNELS", "COLD_START_KERNELS", "COMPLEX_KERNELS", "FILTER_KERNELS",
           "INDUCED_DIPOLE_KERNELS", "LIVE_KERNELS", "PLANAR_KERNELS", "SOLVER_KERNELS",
           "announce_compile", "cold_kernels", "compile_kernels", "dipole_kernels",
           "model_kernels",
           "serial_threads", "solve_kernels", "watch_compiles"]

#: The dipole model, closed forms and batch LM solver (``solve``, ``calibrate``, ``report``,
#: ``reproduce``, ``demo``).
SOLVER_KERNELS = (
    "openemt.field._dipole_kernel:dipole_batch",
    "openemt.field._dipole_kernel:dipole_batch_jac",
    "openemt.solve._closed_form:_spectral_norms",
    "openemt.solve._closed_form:_complex_norms",
    "openemt.solve._closed_form:_closed_form_batch",
    "openemt.solve._lm:lm_batch",
)

#: The closed forms' check of complex couplings (ILEMT's recordings are complex): in
#: :data:`SOLVER_KERNELS` for the commands that read recordings; a command whose couplings are
#: real by construction (``demo``: simulated; ``track``: the live pipeline solves the real
#: or signed parts) leaves it out, as it never runs it.
COMPLEX_KERNELS = ("openemt.solve._closed_form:_complex_norms",)

#: The finite-coil (board) model and its 5-DOF solver (``calibrate --mode planar``, board
#: ``solve``, ``report`` and ``track``).
PLANAR_KERNELS = (
    "openemt.field._segments:_coupling_batch_impl",
    "openemt.solve._planar:_batch",
)

#: The dipole model's Jacobian, which gives a board's induced dipoles (environment terms:
#: ``calibrate --mode planar`` with ``--environment auto`` or dipoles).
INDUCED_DIPOLE_KERNELS = ("openemt.field._dipole_kernel:dipole_batch_jac",)

#: The compiled LM kernels specialised for a board read by a sensor of 2 or 3 coils (6 DOF:
#: ``solve`` and ``track`` of such a board), beside the board's coupling. ``@board`` names
#: the specialisation: numba caches one entry per argument types, and the board's packed model
#: is another type than a dipole model's.
BOARD_LM_KERNELS = (
    "openemt.field._segments:_coupling_batch_impl",
    "openemt.solve._lm:lm_batch@board",
    "openemt.solve._lm:lm_track@board",
)

#: The dipole solver's cold start from its invariant table (``track`` of a dipole sensor, the
#: default start of a model with coil offsets).
COLD_START_KERNELS = ("openemt.solve._cold_start:table_candidates",)

#: The live path beside the solvers' kernels: the tracking filter, the per-pose distortion
#: levels and OpenIGTLink packing (``track`` calls ``SOLVER_KERNELS + COLD_START_KERNELS +
#: LIVE_KERNELS`` for dipole sensors, ``LIVE_KERNELS + PLANAR_KERNELS`` for board sensors, less
#: :data:`COMPLEX_KERNELS` and, without a filter, :data:`FILTER_KERNELS`; the packing kernels
#: run when the first client connects, so they are compiled before the stream starts rather
#: than during it).
LIVE_KERNELS = (
    "openemt.live._filter:_kalman_kernel",
    "openemt.live._igtl_wire:_pack_kernel",
    "openemt.live._igtl_wire:_frame_kernel",
    "openemt.live._igtl_wire:packable",
    "openemt.live._igtl_wire:_v2_kernel",
    "openemt.live._igtl_meta:_levels",
    "openemt.signal._demod:_ratios",
)

#: The tracking filter's kernel, in :data:`LIVE_KERNELS`: ``track`` compiles it only when a
#: sensor has a filter.
FILTER_KERNELS = ("openemt.live._filter:_kalman_kernel",)


def _board_signature(sig) -> bool:
    from .solve._model_kernels import is_board

    return bool(sig) and is_board(sig[0])


#: Specialisations a kernel name may carry after ``@``: which cached signatures count.
_VARIANTS = {"board": _board_signature}


def _split(spec: str):
    """``"module:function@variant"`` -> ``(dispatcher, variant or None)``."""
    target, _, variant = str(spec).partition("@")
    module, _, name = target.partition(":")
    if variant and variant not in _VARIANTS:
        raise ValueError(f"expected a kernel variant in {sorted(_VARIANTS)}, got {variant!r}")
    return getattr(importlib.import_module(module), name), variant or None


def _is_cached(dispatcher, variant=None) -> bool | None:
    """True if numba's cache index of ``dispatcher`` holds an entry for its current source
    whose signature is the ``variant``'s specialisation (without: one that is no variant's),
    False if it holds none (missing, stale or another numba version), None if this cannot be
    told (not a caching dispatcher, or numba's cache layout changed)."""
    cache_file = getattr(getattr(dispatcher, "_cache", None), "_cache_file", None)
    load = getattr(cache_file, "_load_index", None)
    if load is None:
        return None
    try:
        index = load()  # {} when missing, stale (source stamp) or of another version
        if variant is not None:
            return any(_VARIANTS[variant](key[0]) for key in index)
        return any(not any(v(key[0]) for v in _VARIANTS.values()) for key in index)
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
        if not _is_cached(*_split(spec)):
            cold.append(spec)
    return cold


def dipole_kernels(*, cold_start_table: bool = False, complex_couplings: bool = True) -> tuple:
    """The dipole solver's compiled kernels (:data:`SOLVER_KERNELS`), with its cold start's
    table kernel when ``cold_start_table``, without the check of complex couplings when the
    couplings solved are real by construction (``complex_couplings=False``: the demo's
    simulated ones, the live pipeline's)."""
    kernels = SOLVER_KERNELS + (COLD_START_KERNELS if cold_start_table else ())
    return kernels if complex_couplings else tuple(k for k in kernels
                                                   if k not in COMPLEX_KERNELS)


def model_kernels(model) -> tuple:
    """The compiled kernels that solve with ``model``: a dipole-family model's
    (:func:`dipole_kernels`), a board's with a single-coil sensor (:data:`PLANAR_KERNELS`) or
    with a sensor of 2 or 3 coils (:data:`BOARD_LM_KERNELS`); none for another model."""
    if getattr(model, "solver_family", None) in ("dipole", "dipole-refined"):
        return dipole_kernels()
    if hasattr(model, "board"):
        return PLANAR_KERNELS if model.dof == 5 else BOARD_LM_KERNELS
    return ()


def solve_kernels(model, cold_start_table: bool = False) -> tuple[str, tuple]:
    """``(what, kernels)`` of a solve with ``model`` for the compile notice: its kernels
    (:func:`model_kernels`) named ``"solver kernels"`` (a dipole model, with the cold start's
    table kernel when ``cold_start_table``) or ``"finite-coil kernels"`` (a board)."""
    if hasattr(model, "board"):
        return "finite-coil kernels", model_kernels(model)
    return "solver kernels", dipole_kernels(cold_start_table=cold_start_table)


def _dipole_case():
    """A 3x3 dipole model, its concentric model, two poses, their couplings and pose vectors:
    the inputs of the warm-up calls (the types every command passes, not its sizes)."""
    import numpy as np

    from .field import DipoleModel
    from .geometry import pose_from_vector

    v = np.array([[0.30, 0.02, 0.01, 0.1, -0.2, 0.3], [0.25, -0.03, 0.05, -0.4, 0.1, 0.2]])
    model = DipoleModel(np.diag([0.01, -0.01, 0.02]), np.eye(3), np.zeros((3, 3)), np.eye(3))
    P = pose_from_vector(v)
    return model, DipoleModel.concentric(), P, model.coupling(P), v


def _warm_dipole(which):
    from .field import coupling_jacobians
    from .solve import solve_kim18, solve_lm

    model, conc, P, C, v = _dipole_case()
    if which == "jacobians":
        coupling_jacobians(model, P)
    elif which == "closed_form":
        solve_kim18(conc.coupling(P), conc)
    elif which == "complex":                 # the closed forms' check of complex couplings
        solve_kim18(conc.coupling(P) * (1.0 + 1e-3j), conc)
    elif which == "lm_batch":
        solve_lm(C, model, initial=v)
    elif which == "lm_track":
        solve_lm(C, model, initial="track")
    elif which == "spectral":
        from .solve import spectral_norms

        spectral_norms(C)
    elif which == "table":
        solve_lm(C, model)   # the default start of a model with coil offsets: the table


def _warm_planar():
    import numpy as np

    from .board import BoardModel
    from .solve import solve_planar

    model = BoardModel.from_board("anser")
    P = np.repeat(np.eye(4)[None], 2, axis=0)
    P[:, :3, 3] = [[0.0, 0.0, 0.12], [0.02, 0.01, 0.15]]
    solve_planar(model.coupling(P), model)


def _warm_board_lm():
    """The LM kernels' board specialisation: a 6-DOF board sensor tracked (``lm_track``) and
    solved from given starts (``lm_batch``), as ``solve`` and ``track`` call them."""
    import numpy as np

    from .board import BoardModel
    from .geometry import vector_from_pose
    from .solve import prepare

    model = BoardModel.from_board("anser-6dof")
    P = np.repeat(np.eye(4)[None], 2, axis=0)
    P[:, :3, 3] = [[0.0, 0.0, 0.12], [0.02, 0.01, 0.15]]
    C = model.coupling(P)
    prepare(model, initial="track")(C)
    prepare(model)(C, vector_from_pose(P))


def _warm_ratios():
    import numpy as np

    from .signal import distortion_ratio

    distortion_ratio(np.ones((1, 1, 1), np.complex128))


#: How each kernel is compiled: one small call through the public function that runs it
#: (the live kernels' modules add theirs, :func:`warm_up_with`).
_WARM_UP = {
    "openemt.field._dipole_kernel:dipole_batch": lambda: _dipole_case(),
    "openemt.field._dipole_kernel:dipole_batch_jac": lambda: _warm_dipole("jacobians"),
    "openemt.solve._closed_form:_spectral_norms": lambda: _warm_dipole("spectral"),
    "openemt.solve._closed_form:_complex_norms": lambda: _warm_dipole("complex"),
    "openemt.solve._closed_form:_closed_form_batch": lambda: _warm_dipole("closed_form"),
    "openemt.solve._lm:lm_batch": lambda: _warm_dipole("lm_batch"),
    "openemt.solve._lm:lm_track": lambda: _warm_dipole("lm_track"),
    "openemt.solve._cold_start:table_candidates": lambda: _warm_dipole("table"),
    "openemt.field._segments:_coupling_batch_impl": _warm_planar,
    "openemt.solve._planar:_batch": _warm_planar,
    "openemt.solve._lm:lm_batch@board": _warm_board_lm,
    "openemt.solve._lm:lm_track@board": _warm_board_lm,
    "openemt.signal._demod:_ratios": _warm_ratios,
}


def warm_up_with(spec: str, warm) -> None:
    """Register ``warm()``, one small call that compiles kernel ``spec`` (``"module:function"``)
    through its public function; the kernel's own module registers it when imported (which
    :func:`cold_kernels` does), so this module needs no import of the packages above it."""
    _WARM_UP[spec] = warm


def compile_kernels(kernels) -> list[str]:
    """Compile (or load from the cache) each of ``kernels`` now, in order; the ones that were
    cold before (:func:`cold_kernels`). A kernel without a warm-up call compiles on its first
    call, as before."""
    cold = cold_kernels(kernels)
    _ANNOUNCED[0] += 1
    try:
        for spec in cold:
            warm = _WARM_UP.get(spec)
            if warm is not None and spec in cold_kernels([spec]):   # one call may serve several
                warm()
    finally:
        _ANNOUNCED[0] -= 1
    return cold


#: Depth of :func:`compile_kernels` calls running: their compiles were announced.
_ANNOUNCED = [0]


def _say(out, line: str) -> bool:
    """Print ``line`` as :func:`announce_compile` does; whether it was said."""
    if callable(out) and not hasattr(out, "write"):
        out(line)
    elif getattr(out, "quiet", False):
        return False
    else:
        stream = out if hasattr(out, "write") else sys.stderr
        stream.write(line + "\n")
        stream.flush()
    return True


@contextlib.contextmanager
def watch_compiles(out=None, what: str = "kernels"):
    """Within the block, the first numba compile that no :func:`announce_compile` announced
    (one that a set-up step runs on the side, e.g. a simulated board preset's gain scale)
    prints ``compiling {what} (first run only) ...`` (``out`` as for
    :func:`announce_compile`), so that such a first run is not silent; nothing when nothing
    compiles. Yields a list that collects the ``"module:function"`` of each such compile."""
    from numba.core import event

    seen: list = []

    class _Watch(event.Listener):
        def on_start(self, ev):
            d = ev.data.get("dispatcher")
            if _ANNOUNCED[0] or d is None:
                return
            if not seen:
                _say(out, f"compiling {what} (first run only) ...")
            seen.append(f"{d.py_func.__module__}:{d.py_func.__qualname__}")

        def on_end(self, ev):
            pass

    watch = _Watch()
    event.register("numba:compile", watch)
    try:
        yield seen
    finally:
        event.unregister("numba:compile", watch)


def announce_compile(out=None, what: str = "solver kernels", *, kernels=SOLVER_KERNELS,
                     seconds: float | None = None) -> bool:
    """If any of ``kernels`` would compile: print ``compiling N {what} (first run only) ...``
    (not with ``--quiet``) and compile them (:func:`compile_kernels`); return whether it
    printed.

    Parameters
    ----------
    out : argparse.Namespace, text stream or callable, optional
        A command's parsed arguments (the line goes to stderr unless ``--quiet``), a stream to
        write to, or a progress callable ``say(text)``; default stderr.
    what : str
        What compiles, in words (``"solver kernels"``: the line counts the cold ones).
    kernels : sequence of str
        ``"module:function"`` of the compiled kernels the command is about to call
        (:data:`SOLVER_KERNELS`, :data:`PLANAR_KERNELS`, :data:`LIVE_KERNELS` or a mix).
    seconds : float, optional
        An expected compile time to add to the line.
    """
    cold = cold_kernels(kernels)
    if not cold:
        return False
    noun = what.split(" ", 1)
    label = (f"{len(cold)} {what}" if len(cold) != 1
             else " ".join(["1", *noun[:-1], noun[-1].removesuffix("s")]))
    line = (f"compiling {label} (first run only"
            + (f", about {seconds:g} s" if seconds is not None else "") + ") ...")
    said = _say(out, line)
    compile_kernels(cold)
    return said


@contextlib.contextmanager
def serial_threads():
    """numba's parallel regions started from this thread on one thread meanwhile (a rate per
    core in the benchmarks; a live chunk too small to wake a thread pool for)."""
    import numba

    before = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(before)
