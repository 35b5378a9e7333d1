"""Running a library call that may crash or hang on a damaged file in a child process.

Some readers are compiled code that trusts the file (libhdf5, scipy's MATLAB reader): a damaged
file can crash the interpreter (a segmentation fault) or loop forever, out of reach of Python's
exception handling and signals. :func:`run_isolated` runs such a call in a forked child (a
spawned one where fork does not exist) and reports what happened instead.
"""

from __future__ import annotations

__all__ = ["Isolated", "run_isolated"]


class Isolated:
    """The outcome of :func:`run_isolated`: ``kind`` is ``"ok"`` (``value`` is the result),
    ``"raised"`` (``value`` is the exception the call raised), ``"died"`` (``value`` is the
    child's exit code, e.g. -11 for a segmentation fault) or ``"timeout"``."""

    __slots__ = ("kind", "value")

    def __init__(self, kind: str, value=None):
        self.kind, self.value = kind, value

    def __repr__(self) -> str:
        return f"Isolated({self.kind!r}, {self.value!r})"


def _child(fn, args, conn) -> None:  # pragma: no cover - runs in the child process
    import faulthandler

    # a crash here is an expected outcome that the parent reports; no traceback dump for it
    faulthandler.disable()
    try:
        out = ("ok", fn(*args))
    except BaseException as exc:  # noqa: BLE001 - handed to the parent, which decides
        out = ("raised", exc)
    try:
        conn.send(out)
    except Exception as exc:  # noqa: BLE001 - e.g. an unpicklable result
        conn.send(("raised", RuntimeError(f"{type(exc).__name__}: {exc}")))
    finally:
        conn.close()


def run_isolated(fn, args=(), *, timeout: float) -> Isolated:
    """Call ``fn(*args)`` in a child process; its result (or exception) must pickle."""
    import multiprocessing as mp

    method = "fork" if "fork" in mp.get_all_start_methods() else "spawn"
    ctx = mp.get_context(method)
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_child, args=(fn, args, child), daemon=True)
    proc.start()
    child.close()
    try:
        if not parent.poll(timeout):
            return Isolated("timeout")
        try:
            kind, value = parent.recv()
            return Isolated(kind, value)
        except EOFError:
            proc.join(5)
            return Isolated("died", proc.exitcode)
    finally:
        parent.close()
        if proc.is_alive():
            proc.kill()
        proc.join(5)
