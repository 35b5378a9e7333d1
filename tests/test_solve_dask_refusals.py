"""``solve --scheduler``: an address that is not a Dask scheduler, or a scheduler without a worker,
is one error line within seconds (exit 2), never a hang or a huge allocation."""

from __future__ import annotations

import socket
import threading
import time

import numpy as np
import pytest

pytest.importorskip("distributed")

from openemt._errors import InputError  # noqa: E402
from openemt.solve import _dask  # noqa: E402


class _Server:
    """A TCP server on localhost that sends ``reply`` to each connection (None: says nothing)
    and keeps it open."""

    def __init__(self, reply):
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.reply, self.conns = reply, []
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self):
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            self.conns.append(conn)
            if self.reply is not None:
                conn.sendall(self.reply)

    def close(self):
        for c in self.conns:
            c.close()
        self.sock.close()


@pytest.mark.parametrize("reply", [b"\xff" * 64, b"HTTP/1.1 200 OK\r\n\r\nhello" * 3,
                                   b"\x20\x00\x00\x00\x00\x00\x00\x00" + b"\x00" * 32, None],
                         ids=["huge-length", "http", "not-msgpack", "silent"])
def test_an_address_that_is_no_scheduler_is_refused_within_seconds(reply):
    server = _Server(reply)
    try:
        t0 = time.monotonic()
        with pytest.raises(InputError, match="Dask scheduler"):
            with _dask.cluster(f"tcp://127.0.0.1:{server.port}"):
                pass
        assert time.monotonic() - t0 < _dask.CONNECT_TIMEOUT_S + 3
    finally:
        server.close()


def test_a_closed_port_is_refused():
    s = socket.create_server(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    with pytest.raises(InputError, match="Dask scheduler"):
        _dask.probe_scheduler(f"tcp://127.0.0.1:{port}")


def test_no_worker_left_is_an_error_not_a_wait(monkeypatch):
    from dask.distributed import Client, LocalCluster

    monkeypatch.setattr(_dask, "NO_WORKER_S", 1.0)
    with LocalCluster(n_workers=0, processes=False, dashboard_address=None) as lc:
        _dask.probe_scheduler(lc.scheduler_address)          # a real scheduler answers
        t0 = time.monotonic()
        with pytest.raises(InputError, match="no.*worker|got none"):
            with _dask.cluster(lc.scheduler_address):
                pass
        with Client(lc) as client:                           # workers gone during a run
            with pytest.raises(InputError, match="got none for 1 s"):
                list(_dask.run_blocks(client, lambda k: client.submit(np.ones, k), 3))
        assert time.monotonic() - t0 < 15


def test_solve_command_says_so_in_one_line(tmp_path, capsys):
    from openemt.cli import main
    from openemt.io import Dataset, write_calibration, write_dataset
    from openemt.simulate import truth_calibration

    cal = truth_calibration("dipole-approx")
    P = np.tile(np.eye(4), (4, 1, 1))
    P[:, 0, 3] = 0.3
    ds = Dataset(couplings=cal.model.coupling(P), stage=np.zeros((4, 6)),
                 source_fixture="YoutZup", sensor_fixture="YoutZup", pattern="sim",
                 file_index=np.zeros(4, int), files=("sim",), poses=P)
    write_dataset(ds, tmp_path / "d.h5")
    write_calibration(cal, tmp_path / "c.json")
    server = _Server(b"\xff" * 64)
    try:
        code = main(["solve", str(tmp_path / "d.h5"), "-c", str(tmp_path / "c.json"), "-o",
                     str(tmp_path / "p.h5"), "--scheduler", f"tcp://127.0.0.1:{server.port}",
                     "--quiet"])
    finally:
        server.close()
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err[-1].startswith("error: expected a Dask scheduler"), err
    assert not (tmp_path / "p.h5").exists()
