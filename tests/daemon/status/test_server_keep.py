"""The status socket's kept connections (the ``keep`` request, docs/status.md), against a
StatusServer with a scripted source: many requests on one connection, requests sent ahead
in one write, a bad request among them, a client that asks and stops reading, one that
closes in the middle of an answer, one that asks nothing, the limit of kept connections
(a new one in place of the one that asked longest ago, one-shot reads still served).
(The client side, StatusReader: test_reader.py.)"""

from __future__ import annotations

import socket
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from motorctl.daemon.status import server as status_module
from motorctl.daemon.status.reader import read_status
from motorctl.daemon.status.requests import MAX_REQUEST
from motorctl.daemon.status.server import StatusServer
from tests.daemon.status.test_server_subscribe import read_line
from tests.support.wait import until

DEADLINE_S = 30.0


class Source:
    """A status whose content the test sets; numbers each document it builds and records
    whether the histogram was asked."""

    def __init__(self) -> None:
        self.doc: dict[str, Any] = {"motors": []}
        self.asked: list[bool] = []
        self.lock = threading.Lock()

    def __call__(self, histogram: bool = False) -> dict[str, Any]:
        with self.lock:
            self.asked.append(histogram)
            doc = {**self.doc, "n": len(self.asked)}
        if histogram:
            doc["histogram_us"] = {"0": 1}
        return doc


@pytest.fixture
def served(tmp_path: Path) -> Iterator[tuple[StatusServer, Source]]:
    src = Source()
    server = StatusServer(tmp_path / "status.sock", src)
    server.start()
    try:
        yield server, src
    finally:
        server.close()


def kept(path: Path, first: bytes = b"keep\n") -> socket.socket:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.settimeout(DEADLINE_S)
    sock.connect(str(path))
    sock.sendall(first)
    return sock


def nothing_waiting(sock: socket.socket) -> bool:
    sock.setblocking(False)
    try:
        return not sock.recv(65536)  # b"": closed, not "nothing waiting"
    except BlockingIOError:
        return True
    finally:
        sock.settimeout(DEADLINE_S)


def closed(sock: socket.socket) -> bool:
    """The server closed ``sock`` (after whatever it had sent)."""
    while chunk := sock.recv(1 << 20):
        del chunk
    return True


def test_many_requests_on_one_connection(served: tuple[StatusServer, Source]) -> None:
    """``keep`` itself is not answered; then each request line is, one document a line,
    each built for it, on the one connection."""
    server, src = served
    with kept(server.path) as sock:
        buf = bytearray()
        until("kept", lambda: server.kept == 1)
        assert nothing_waiting(sock) and src.asked == []
        for i in range(1, 51):
            sock.sendall(b"\n")
            assert read_line(sock, buf) == {"motors": [], "n": i}
        sock.sendall(b"histogram\n")
        assert read_line(sock, buf) == {"motors": [], "n": 51, "histogram_us": {"0": 1}}
        assert src.asked == [False] * 50 + [True]
        assert server.kept == 1 and len(server._clients) == 1
    until("dropped once it closed", lambda: server.kept == 0 and not server._clients)
    assert server.served == 51  # (counted once each answer is sent: now, all of them)


def test_requests_sent_ahead_in_one_write(served: tuple[StatusServer, Source]) -> None:
    """``keep`` and three requests in one write (whole at accept): three answers in order;
    then requests sent ahead again, and a half-close after them: answered, then closed."""
    server, src = served
    with kept(server.path, b"keep\n\nhistogram\n\n") as sock:
        buf = bytearray()
        answers = [read_line(sock, buf) for _ in range(3)]
        assert [a["n"] for a in answers] == [1, 2, 3]
        assert ["histogram_us" in a for a in answers] == [False, True, False]
        sock.sendall(b"\n\n")
        sock.shutdown(socket.SHUT_WR)
        assert [read_line(sock, buf)["n"] for _ in range(2)] == [4, 5]
        assert closed(sock) and buf == b""
    until("dropped", lambda: server.kept == 0)
    assert src.asked == [False, True, False, False, False]


def test_a_bad_request_in_the_middle(served: tuple[StatusServer, Source]) -> None:
    """A bad line gets an error document on its line and the connection stays kept;
    ``subscribe`` and ``keep`` are not for a kept connection; a line too long for a
    request gets its error document, then the close."""
    server, _ = served
    with kept(server.path, b"keep\n\nwhat\n\nsubscribe 20\nkeep\nhistogram please\n\n") as sock:
        buf = bytearray()
        answers = [read_line(sock, buf) for _ in range(7)]
        assert [a.get("n") for a in answers] == [1, None, 2, None, None, None, 3]
        assert "unknown status request: what; known: histogram" in answers[1]["error"]
        assert "on a kept connection ask for an empty line or histogram" in answers[3]["error"]
        assert "on a kept connection" in answers[4]["error"]
        assert "unknown status request: please" in answers[5]["error"]
        assert server.kept == 1
        sock.sendall(b"x" * (MAX_REQUEST + 10))
        assert "a request line too long" in read_line(sock, buf)["error"]
        assert closed(sock)
    until("dropped", lambda: server.kept == 0 and not server._clients)
    assert read_status(server.path)["n"] == 4  # the server serves on


def test_a_kept_client_that_stops_reading_is_dropped(
    served: tuple[StatusServer, Source], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Answers far larger than the socket's buffers, asked for and never read: dropped
    once an answer stays unread for SEND_TIMEOUT_S; its requests meanwhile wait unread
    (not answered behind it), and nobody else waits for it."""
    server, src = served
    monkeypatch.setattr(status_module, "SEND_TIMEOUT_S", 0.2)
    src.doc["blob"] = "x" * 8_000_000
    with kept(server.path, b"keep\n" + b"\n" * 100):
        until("the first answer begun", lambda: src.asked)
        until("dropped", lambda: server.kept == 0 and not server._clients)
        assert src.asked == [False]  # one answer begun; the 99 behind it never built
        assert read_status(server.path)["blob"] == "x" * 8_000_000
    assert server.served == 1


def test_a_kept_client_that_closes_in_the_middle_of_an_answer(
    served: tuple[StatusServer, Source],
) -> None:
    server, src = served
    src.doc["blob"] = "x" * 8_000_000
    with kept(server.path, b"keep\n\n") as sock:
        assert sock.recv(4096)  # the answer begun
        until("sending", lambda: any(c.out is not None for c in server._clients.values()))
    until("dropped", lambda: server.kept == 0 and not server._clients)
    assert server.served == 0
    assert read_status(server.path)["n"] == 2


def test_a_kept_client_that_asks_nothing_is_closed(
    served: tuple[StatusServer, Source], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Silent for KEEP_IDLE_S after its last answer (or after ``keep``): closed."""
    server, _ = served
    monkeypatch.setattr(status_module, "KEEP_IDLE_S", 0.1)
    with kept(server.path, b"keep\n\n") as sock:
        buf = bytearray()
        assert read_line(sock, buf)["n"] == 1
        assert closed(sock) and buf == b""
    until("dropped", lambda: server.kept == 0 and not server._clients)


def test_kept_connections_are_limited_and_one_shot_reads_still_served(
    served: tuple[StatusServer, Source],
) -> None:
    """MAX_KEPT kept connections: a new one takes the place of the one that asked longest
    ago (closed), the others stay; with the kept and the subscribers' places all taken, a
    one-shot read still finds a slot."""
    server, _ = served
    socks = []
    try:
        for _ in range(status_module.MAX_KEPT):
            socks.append(kept(server.path, b"keep\n\n"))
            read_line(socks[-1], bytearray())
        socks[0].sendall(b"\n")  # the first asks again: the second asked longest ago
        read_line(socks[0], bytearray())
        subscribers = [
            kept(server.path, b"subscribe\n") for _ in range(status_module.MAX_SUBSCRIBERS)
        ]
        socks.extend(subscribers)
        until(
            "all in",
            lambda: server.kept == 4 and server.subscribers == status_module.MAX_SUBSCRIBERS,
        )
        assert read_status(server.path)["motors"] == []
        newcomer = kept(server.path, b"keep\n\n")
        socks.append(newcomer)
        assert "n" in read_line(newcomer, bytearray())
        assert server.kept == status_module.MAX_KEPT and server.kept_evicted == 1
        assert closed(socks[1])
        for sock in (socks[0], socks[2], socks[3]):
            buf = bytearray()
            sock.sendall(b"\n")
            assert "n" in read_line(sock, buf)
    finally:
        for sock in socks:
            sock.close()
    until("all dropped", lambda: server.kept == 0 and not server._clients)
