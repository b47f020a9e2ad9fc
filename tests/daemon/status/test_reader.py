"""The status socket's clients (daemon/status/reader.py) against a listening socket the test
holds: a full listen backlog is waited out within the timeout, one that stays full is a
TimeoutError naming the socket. (Against the daemon's server: test_server.py,
test_server_subscribe.py.)"""

from __future__ import annotations

import socket
import threading
from pathlib import Path
from typing import Any

import pytest

from motorctl.daemon.status.reader import read_status

READ_DEADLINE_S = 10.0  # a loaded 2-core machine


def _full_backlog(path: Path) -> tuple[socket.socket, socket.socket]:
    """A listening socket that accepts nothing yet, its one backlog place taken."""
    srv = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    srv.bind(str(path))
    srv.listen(0)
    filler = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    filler.setblocking(False)
    filler.connect(str(path))
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    probe.setblocking(False)
    with pytest.raises(BlockingIOError), probe:  # the backlog is full indeed
        probe.connect(str(path))
    return srv, filler


def test_read_status_waits_for_room_in_a_full_backlog(tmp_path: Path) -> None:
    """A full backlog makes a connect with a timeout fail at once (EAGAIN on AF_UNIX):
    the reader waits for room instead, within its timeout."""
    path = tmp_path / "status.sock"
    srv, filler = _full_backlog(path)
    got: dict[str, Any] = {}

    def reader() -> None:
        try:
            got["doc"] = read_status(path, timeout=READ_DEADLINE_S)
        except Exception as exc:  # reported by the assertion below
            got["error"] = exc

    t = threading.Thread(target=reader)
    with srv, filler:
        t.start()
        srv.settimeout(READ_DEADLINE_S)
        first, _ = srv.accept()  # the filler's place: room for the reader
        first.close()
        conn, _ = srv.accept()
        with conn:
            conn.settimeout(READ_DEADLINE_S)
            assert conn.recv(64) == b"\n"
            conn.sendall(b'{"ok": true}')
        t.join(READ_DEADLINE_S)
    assert got == {"doc": {"ok": True}}


def test_read_status_gives_up_on_a_backlog_that_stays_full(tmp_path: Path) -> None:
    path = tmp_path / "status.sock"
    srv, filler = _full_backlog(path)
    with srv, filler, pytest.raises(TimeoutError, match="status slot stayed busy"):
        read_status(path, timeout=0.2)
