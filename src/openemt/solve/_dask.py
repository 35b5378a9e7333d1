"""The Dask side of the block runner: connect to a scheduler only after it has answered the
scheduler protocol, and gather block results while watching that workers are left, so a run
with a wrong address or no worker says so within seconds instead of waiting forever
(docs/solve.md#command-line)."""

from __future__ import annotations

import socket
import struct
import time
from contextlib import contextmanager

from .._errors import InputError

__all__ = ["cluster", "probe_scheduler", "run_blocks"]

#: Seconds to wait for a scheduler's handshake, and for a worker to be there.
CONNECT_TIMEOUT_S = 5.0
NO_WORKER_S = 10.0
#: Largest handshake message a scheduler sends (it is a few dozen bytes).
_MAX_HANDSHAKE = 1 << 16


def _host_port(address: str):
    """(host, port) of a ``tcp://host:port`` or ``host:port`` address; None for other
    transports (tls, inproc, ucx: left to Dask)."""
    proto, _, rest = address.rpartition("://")
    if proto not in ("", "tcp"):
        return None
    host, _, port = rest.rpartition(":")
    try:
        return host.strip("[]") or "127.0.0.1", int(port)
    except ValueError:
        raise InputError(f"expected a Dask scheduler address such as tcp://host:8786, got "
                         f"{address!r}") from None


def probe_scheduler(address: str, timeout: float = CONNECT_TIMEOUT_S) -> None:
    """Raise InputError unless ``address`` answers as a Dask scheduler: a scheduler sends its
    handshake (a small msgpack message in Dask's framing) as soon as a connection opens."""
    hp = _host_port(address)
    if hp is None:
        return
    what = f"a Dask scheduler at {address!r}"
    deadline = time.monotonic() + timeout

    def read(sock, n):
        buf = b""
        while len(buf) < n:
            sock.settimeout(max(deadline - time.monotonic(), 0.01))
            part = sock.recv(n - len(buf))
            if not part:
                raise InputError(f"expected {what}, got a connection closed before the "
                                 f"scheduler's handshake")
            buf += part
        return buf

    try:
        with socket.create_connection(hp, timeout=timeout) as sock:
            (n,) = struct.unpack("<Q", read(sock, 8))
            if not 16 <= n <= _MAX_HANDSHAKE:
                raise InputError(f"expected {what}, got a server that does not speak the "
                                 f"scheduler protocol (a first message of {n} bytes)")
            body = read(sock, n)
    except TimeoutError:
        raise InputError(f"expected {what}, got no handshake within {timeout:g} s (not a "
                         f"Dask scheduler, or it does not answer)") from None
    except OSError as exc:
        raise InputError(f"expected {what}, got {exc.strerror or exc}") from None
    import msgpack
    from distributed.protocol.utils import unpack_frames

    try:
        frames = unpack_frames(body)
        info = msgpack.unpackb(bytes(frames[-1]), raw=False)
    except Exception:
        info = None
    if not (isinstance(info, dict) and "python" in info):
        raise InputError(f"expected {what}, got a server that does not speak the scheduler "
                         f"protocol")


def _result(future, k: int):
    from distributed import KilledWorker

    try:
        return future.result()
    except KilledWorker:
        raise InputError(f"expected the Dask workers to stay up, got every worker that ran "
                         f"block {k} killed (the scheduler gave it up)") from None


def _workers(client) -> int:
    return len(client.nthreads())


def _await_worker(client, address, since: float) -> None:
    if time.monotonic() - since > NO_WORKER_S:
        raise InputError(f"expected a Dask worker at the scheduler {address}, got none for "
                         f"{NO_WORKER_S:g} s (every worker gone or none started)")


@contextmanager
def cluster(scheduler):
    """A ``dask.distributed.Client`` for ``scheduler`` (an address, probed first, or a Client
    used as it is), with at least one worker within :data:`NO_WORKER_S` seconds; closed on
    exit when opened here."""
    from dask.distributed import Client

    own = not isinstance(scheduler, Client)
    if own:
        if not isinstance(scheduler, str):
            raise InputError(f"expected a Dask scheduler address or Client, got "
                             f"{type(scheduler).__name__}")
        probe_scheduler(scheduler)
        try:
            client = Client(scheduler, timeout=f"{CONNECT_TIMEOUT_S}s")
        except (OSError, TimeoutError) as exc:
            raise InputError(f"expected a Dask scheduler at {scheduler!r}, got "
                             f"{' '.join(str(exc).split())[:120]}") from None
    else:
        client = scheduler
    try:
        t0 = time.monotonic()
        while not _workers(client):
            _await_worker(client, client.scheduler.address, t0)
            time.sleep(0.2)
        yield client
    finally:
        if own:
            client.close()


def run_blocks(client, submit, n_blocks: int, *, max_in_flight: int | None = None,
               ordered: bool = True):
    """Yield ``(k, value)`` of the tasks ``submit(k)`` (a future) for k in ``range(n_blocks)``,
    in order (``ordered``) or as they finish, with at most ``max_in_flight`` submitted and not
    yet yielded; raise InputError when no worker is left for :data:`NO_WORKER_S` seconds while
    tasks are pending. Tasks left are cancelled on the way out."""
    from dask.distributed import wait

    limit = n_blocks if max_in_flight is None else max(int(max_in_flight), 1)
    pending, seen = {}, {}
    k_next = k_out = 0
    lonely = None
    try:
        while k_out < n_blocks:
            while k_next < n_blocks and len(pending) + len(seen) < limit:
                pending[k_next] = submit(k_next)
                k_next += 1
            if pending and not any(f.done() for f in pending.values()):
                try:
                    wait(list(pending.values()), timeout=1.0, return_when="FIRST_COMPLETED")
                except TimeoutError:
                    pass
            done = [k for k, f in pending.items() if f.done()]
            for k in done:
                seen[k] = _result(pending.pop(k), k)
            ready = ([k_out] if k_out in seen else []) if ordered else sorted(seen)
            while ready:
                k = ready.pop(0)
                k_out += 1
                yield k, seen.pop(k)
                if ordered and k_out in seen:
                    ready.append(k_out)
            if done or not pending:
                lonely = None
            elif _workers(client):
                lonely = None
            else:
                lonely = time.monotonic() if lonely is None else lonely
                _await_worker(client, client.scheduler.address, lonely)
    finally:
        left = [f for f in pending.values() if not f.done()]
        if left:
            client.cancel(left)
