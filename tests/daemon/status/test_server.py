"""The status socket's server (daemon/status/server.py) with a scripted status source: it
serves and cleans up, builds the histogram only when asked, a silent client holds up
nobody, accept errors do not end it, a broken source is an error document, close leaves a
socket that is not its own. (Subscriptions: test_server_subscribe.py.)"""

from __future__ import annotations

import errno
import json
import socket
import time
from pathlib import Path
from typing import Any

import pytest

from motorctl.daemon.status import server as status_module
from motorctl.daemon.status.reader import read_status
from motorctl.daemon.status.server import StatusServer, StatusSource
from tests.support.fsutil import read_only
from tests.support.wait import until

DEADLINE_S = 5.0


def source(doc: dict[str, Any], asked: list[bool] | None = None) -> StatusSource:
    """A status source answering ``doc`` (plus the histogram when asked); records asks."""

    def status(histogram: bool = False) -> dict[str, Any]:
        if asked is not None:
            asked.append(histogram)
        return {**doc, "histogram_us": {"0": 1}} if histogram else dict(doc)

    return status


def raw_request(path: Path, request: bytes | None) -> bytes:
    """Send ``request`` (None: nothing, then half-close) and read the answer to EOF."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(DEADLINE_S)
        sock.connect(str(path))
        if request is None:
            sock.shutdown(socket.SHUT_WR)
        else:
            sock.sendall(request)
        chunks = []
        while chunk := sock.recv(65536):
            chunks.append(chunk)
    return b"".join(chunks)


def connect_when_there_is_room(path: Path) -> socket.socket:
    """A connected client; a full listen backlog refuses at once (EAGAIN): retry until the
    server has taken some, with a deadline."""
    deadline = time.monotonic() + DEADLINE_S
    while True:
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.settimeout(DEADLINE_S)
        try:
            sock.connect(str(path))
            return sock
        except BlockingIOError:
            sock.close()
            if time.monotonic() > deadline:
                raise AssertionError(f"no room in {path}'s backlog for {DEADLINE_S} s") from None
            time.sleep(0.005)


def test_status_server_serves_and_cleans_up(tmp_path: Path) -> None:
    path = tmp_path / "status.sock"
    server = StatusServer(path, source({"motors": []}))
    assert oct(path.stat().st_mode & 0o777) == "0o660"
    server.start()
    assert read_status(path) == {"motors": []}
    server.close()
    assert not path.exists()


def test_status_server_builds_the_histogram_only_when_asked(tmp_path: Path) -> None:
    path = tmp_path / "status.sock"
    asked: list[bool] = []
    server = StatusServer(path, source({"motors": []}, asked))
    server.start()
    try:
        assert read_status(path) == {"motors": []}
        assert read_status(path, histogram=True) == {"motors": [], "histogram_us": {"0": 1}}
        assert json.loads(raw_request(path, None)) == {"motors": []}  # asked nothing: EOF
        assert asked == [False, True, False]
        bad = json.loads(raw_request(path, b"everything please\n"))
        assert "unknown status request: everything please; known: histogram" in bad["error"]
        assert "error" in json.loads(raw_request(path, b"x" * 300))  # no line end in sight
        assert asked == [False, True, False] and server.served == 5
    finally:
        server.close()


@pytest.mark.parametrize("size", [10, 4_000_000])
def test_status_server_answers_requests_waiting_whole_at_accept(tmp_path: Path, size: int) -> None:
    """Requests already whole when the server accepts (a plain one is answered straight
    from accept()): the plain status, small (sent at once) or larger than the socket's
    buffer (the rest sent as the client reads), the histogram and a bad request, each
    whole; nothing is left registered."""
    path = tmp_path / "status.sock"
    blob = "x" * size
    asked: list[bool] = []
    server = StatusServer(path, source({"blob": blob}, asked))
    requests = [b"\n", b"\n", b"histogram\n", b"what\n"]
    socks = []
    try:
        for request in requests:  # connected and asked before the server's thread runs
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            sock.settimeout(DEADLINE_S)
            sock.connect(str(path))
            sock.sendall(request)
            socks.append(sock)
        server.start()
        answers = []
        for sock in socks:
            chunks = []
            while chunk := sock.recv(1 << 20):
                chunks.append(chunk)
            answers.append(json.loads(b"".join(chunks)))
        assert answers[:2] == [{"blob": blob}, {"blob": blob}]
        assert answers[2] == {"blob": blob, "histogram_us": {"0": 1}}
        assert "unknown status request: what" in answers[3]["error"]
        assert asked == [False, False, True] and server.served == 4
        until("no client left registered", lambda: not server._clients)
    finally:
        for sock in socks:
            sock.close()
        server.close()


def test_status_server_a_silent_client_holds_up_nobody(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A client that connects and says nothing (or never reads) does not delay the others;
    it gets the plain status after REQUEST_WAIT_S, as ``socat - UNIX-CONNECT:`` users do.
    More silent clients than MAX_CLIENTS at once wait in the backlog and are all served."""
    path = tmp_path / "status.sock"
    server = StatusServer(path, source({"ok": True}))
    server.start()
    try:
        monkeypatch.setattr(status_module, "REQUEST_WAIT_S", 2.0)  # ample on a loaded machine
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as silent:
            silent.connect(str(path))
            t0 = time.monotonic()
            assert read_status(path) == {"ok": True}
            silent.setblocking(False)
            with pytest.raises(BlockingIOError):  # served after the other one, not before
                silent.recv(65536)
            silent.settimeout(DEADLINE_S)
            assert json.loads(silent.recv(65536)) == {"ok": True}
            assert time.monotonic() - t0 >= 2.0 * 0.9
        monkeypatch.undo()
        crowd: list[socket.socket] = []
        try:
            for _ in range(status_module.MAX_CLIENTS + 4):  # silent: each holds a slot
                crowd.append(connect_when_there_is_room(path))
            assert read_status(path) == {"ok": True}  # waits for a slot, no longer
            for sock in crowd:
                assert json.loads(sock.recv(65536)) == {"ok": True}
        finally:
            for sock in crowd:
                sock.close()
    finally:
        server.close()


def test_status_server_survives_accept_errors(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "status.sock"
    server = StatusServer(path, source({"ok": True}))
    real = server._sock
    failures = [OSError(errno.EMFILE, "Too many open files")]

    class Flaky:
        def accept(self) -> tuple[socket.socket, Any]:
            if failures:
                raise failures.pop()
            return real.accept()

        def __getattr__(self, name: str) -> Any:
            return getattr(real, name)

    server._sock = Flaky()  # type: ignore[assignment]
    server.start()
    assert read_status(path) == {"ok": True}
    assert server.errors == 1 and "accept failed" in caplog.text
    server.close()


def test_status_server_broken_status(tmp_path: Path) -> None:
    def broken(histogram: bool = False) -> dict[str, Any]:
        raise RuntimeError("boom")

    server = StatusServer(tmp_path / "s.sock", broken)
    server.start()
    assert "error" in read_status(tmp_path / "s.sock")
    server.close()


def test_status_close_leaves_a_replaced_socket_and_survives_read_only(tmp_path: Path) -> None:
    path = tmp_path / "status.sock"
    server = StatusServer(path, source({}))
    path.unlink()
    path.write_text("someone else's")
    server.close()
    assert path.read_text() == "someone else's"
    path.unlink()
    server = StatusServer(path, source({}))
    with read_only(tmp_path):
        server.close()  # cannot unlink: logged, no traceback
    assert path.exists()
