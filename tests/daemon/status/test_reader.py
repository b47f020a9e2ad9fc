"""The status socket's clients (daemon/status/reader.py) against a listening socket the test
holds: a full listen backlog is waited out within the timeout, one that stays full is a
TimeoutError naming the socket. StatusReader (one kept connection) against a StatusServer:
reads on one connection, connects again when the daemon closed it, names the path and the
fix without a daemon; against a socket the test holds: a timeout, an older daemon's
refusal. (Against the daemon's server: test_server.py, test_server_subscribe.py,
test_server_keep.py.)"""

from __future__ import annotations

import errno
import grp
import os
import socket
import threading
from pathlib import Path
from typing import Any

import pytest

from motorctl.daemon.status import server as status_module
from motorctl.daemon.status.reader import StatusError, StatusReader, read_status, unreachable
from motorctl.daemon.status.server import StatusServer
from tests.support.wait import until

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


# -- StatusReader: one kept connection ----------------------------------------------------


class Counting:
    """A status source numbering the documents it builds."""

    def __init__(self) -> None:
        self.n = 0

    def __call__(self, histogram: bool = False) -> dict[str, Any]:
        self.n += 1
        return {"n": self.n, **({"histogram_us": {"0": 1}} if histogram else {})}


def test_status_reader_reads_over_one_connection(tmp_path: Path) -> None:
    path = tmp_path / "status.sock"
    server = StatusServer(path, Counting())
    server.start()
    try:
        with StatusReader(path, timeout=READ_DEADLINE_S) as reader:
            assert [reader.read()["n"] for _ in range(20)] == list(range(1, 21))
            assert reader.read(histogram=True) == {"n": 21, "histogram_us": {"0": 1}}
            assert reader.read() == {"n": 22}
            assert reader.connects == 1 and server.kept == 1
        until("closed with the reader", lambda: server.kept == 0 and not server._clients)
    finally:
        server.close()


def test_status_reader_connects_again_when_the_daemon_closed_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The daemon restarted, closed an idle connection, or gave its place to another
    reader: the next read connects again on its own."""
    path = tmp_path / "status.sock"
    server = StatusServer(path, Counting())
    server.start()
    reader = StatusReader(path, timeout=READ_DEADLINE_S)
    others: list[StatusReader] = []
    try:
        assert reader.read() == {"n": 1}
        server.close()  # a restart: a new daemon, a new server on the same path
        server = StatusServer(path, Counting())
        server.start()
        assert reader.read() == {"n": 1} and reader.connects == 2
        for _ in range(status_module.MAX_KEPT):  # each new one takes the oldest's place
            others.append(StatusReader(path, timeout=READ_DEADLINE_S))
            others[-1].read()
        assert server.kept_evicted == 1
        assert reader.read() == {"n": 2 + status_module.MAX_KEPT} and reader.connects == 3
        for other in others:
            other.close()
        until("the others gone", lambda: server.kept == 1)
        monkeypatch.setattr(status_module, "KEEP_IDLE_S", 0.05)
        reader.read()  # idle for 0.05 s after this one: closed
        until("closed when idle", lambda: server.kept == 0)
        assert reader.read()["n"] > 0 and reader.connects == 4
    finally:
        reader.close()
        for other in others:
            other.close()
        server.close()


def test_status_reader_without_a_daemon_names_the_path_and_the_fix(tmp_path: Path) -> None:
    path = tmp_path / "status.sock"
    reader = StatusReader(path, timeout=READ_DEADLINE_S)
    with pytest.raises(FileNotFoundError, match=r"no motorctld serves its status there") as info:
        reader.read()
    assert str(path) in str(info.value) and "--state-dir" in str(info.value)
    server = StatusServer(path, Counting())
    server.start()
    try:
        assert reader.read() == {"n": 1}
    finally:
        server.close()
    with pytest.raises(FileNotFoundError, match="no motorctld serves its status there"):
        reader.read()  # gone for good: the reconnect finds nothing, and says so
    reader.close()


def test_status_reader_times_out_naming_the_path(tmp_path: Path) -> None:
    """A listener that accepts and reads but never answers: TimeoutError within the
    reader's timeout, naming the socket."""
    path = tmp_path / "status.sock"
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as srv:
        srv.bind(str(path))
        srv.listen(1)
        reader = StatusReader(path, timeout=0.2)
        with pytest.raises(TimeoutError, match=f"{path}: the status did not come within 0.2 s"):
            reader.read()
        srv.settimeout(READ_DEADLINE_S)
        conn, _ = srv.accept()
        with conn:
            conn.settimeout(READ_DEADLINE_S)
            assert conn.recv(64) == b"keep\n\n"
        reader.close()


def test_status_reader_refused_by_an_older_daemon(tmp_path: Path) -> None:
    """A daemon that does not know ``keep`` answers an error document and closes: a
    StatusError with its text, not a reconnect loop."""
    path = tmp_path / "status.sock"
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as srv:
        srv.bind(str(path))
        srv.listen(1)

        def older() -> None:
            conn, _ = srv.accept()
            with conn:
                conn.recv(64)
                conn.sendall(b'{"error": "unknown status request: keep; known: histogram"}')

        t = threading.Thread(target=older)
        t.start()
        with pytest.raises(StatusError, match="refused a kept connection: unknown status request"):
            StatusReader(path, timeout=READ_DEADLINE_S).read()
        t.join(READ_DEADLINE_S)


def test_a_status_socket_that_may_not_be_opened_names_the_group_to_join(tmp_path: Path) -> None:
    """``motorctld --status`` as a user outside the socket's group (0660): whose group, and
    how to join it; where its group cannot be looked at, what to look at."""
    path = tmp_path / "status.sock"
    path.write_text("")
    group = grp.getgrgid(os.stat(path).st_gid).gr_name
    denied = PermissionError(errno.EACCES, os.strerror(errno.EACCES))
    assert unreachable(path, denied) == (
        f"Permission denied: the status socket is open to its owner and group {group} only; "
        f"join the group with 'sudo adduser $USER {group}' and log in again"
    )
    assert unreachable(tmp_path / "none", denied) == (
        "Permission denied: the status socket is open to its owner and group only (ls -l it)"
    )
    long = OSError("AF_UNIX path too long")  # no errno: the limit, and the fix
    assert unreachable(path, long) == (
        "AF_UNIX path too long: a Unix socket's path holds at most 107 bytes, so no "
        "motorctld serves one there; give --state-dir the shorter path it runs with"
    )
