"""The status socket's subscribe mode (docs/status.md), against a StatusServer with a scripted
source: the first update at once, updates only on a change (the clock and the executor's
turns are no change), a heartbeat, a poke, the subscriber limit (a new subscriber in place
of the oldest one that does not read its updates), a subscriber that stops reading. Against
a real daemon: tests/daemon/status/test_document_e2e.py."""

from __future__ import annotations

import fcntl
import json
import socket
import struct
import termios
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from motorctl.daemon.status import server as status_module
from motorctl.daemon.status.reader import StatusError, read_status, subscribe
from motorctl.daemon.status.requests import parse_request, stable_view
from motorctl.daemon.status.server import StatusServer
from tests.support.wait import until

DEADLINE_S = 30.0


class Source:
    """A status whose content the test sets; counts how often the server built it."""

    def __init__(self) -> None:
        self.doc: dict[str, Any] = {"motors": [], "steps": {"progress": 0}}
        self.asked = 0
        self.lock = threading.Lock()

    def __call__(self, histogram: bool = False) -> dict[str, Any]:
        with self.lock:
            self.asked += 1
            doc: dict[str, Any] = json.loads(json.dumps(self.doc))
        # what changes at every look in a real daemon, and must not count as a change
        doc.update(monotonic_s=float(self.asked), uptime_s=float(self.asked), unix_s=1.0)
        doc["steps"]["progress"] = self.asked
        return doc

    def set(self, **changes: Any) -> None:
        with self.lock:
            self.doc.update(changes)


@pytest.fixture
def served(tmp_path: Path) -> Iterator[tuple[StatusServer, Source]]:
    src = Source()
    server = StatusServer(tmp_path / "status.sock", src)
    server.start()
    try:
        yield server, src
    finally:
        server.close()


def raw_subscriber(path: Path, request: bytes) -> socket.socket:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.settimeout(DEADLINE_S)
    sock.connect(str(path))
    sock.sendall(request)
    return sock


def read_line(sock: socket.socket, buffered: bytearray) -> dict[str, Any]:
    while b"\n" not in buffered:
        chunk = sock.recv(65536)
        assert chunk, "the stream ended"
        buffered += chunk
    line, _, rest = bytes(buffered).partition(b"\n")
    buffered[:] = rest
    doc = json.loads(line)
    assert isinstance(doc, dict)
    return doc


def nothing_waiting(sock: socket.socket) -> bool:
    sock.setblocking(False)
    try:
        sock.recv(65536)
    except BlockingIOError:
        return True
    finally:
        sock.settimeout(DEADLINE_S)
    return False


def test_updates_come_on_a_change_only(served: tuple[StatusServer, Source]) -> None:
    server, src = served
    with raw_subscriber(server.path, b"subscribe 20\n") as sock:
        buf = bytearray()
        first = read_line(sock, buf)
        assert first["motors"] == [] and server.subscribers == 1
        # Looked at five more times without a change (only the clock and the executor's
        # turns moved): nothing sent. Each look's update, had there been one, is in the
        # socket before the server builds the next document.
        seen = src.asked
        until("five more looks", lambda: src.asked >= seen + 6)
        assert nothing_waiting(sock)
        src.set(motors=[{"index": 0, "state": "moving"}])
        update = read_line(sock, buf)
        assert update["motors"] == [{"index": 0, "state": "moving"}]
        assert update["steps"]["progress"] > first["steps"]["progress"]
    until("the subscriber dropped once it closed", lambda: server.subscribers == 0)


def test_a_heartbeat_without_changes(
    served: tuple[StatusServer, Source], monkeypatch: pytest.MonkeyPatch
) -> None:
    server, _ = served
    monkeypatch.setattr(status_module, "HEARTBEAT_S", 0.05)
    with raw_subscriber(server.path, b"subscribe 20\n") as sock:
        buf = bytearray()
        first, second = read_line(sock, buf), read_line(sock, buf)
        assert stable_view(first) == stable_view(second)
        assert second["monotonic_s"] > first["monotonic_s"]


def test_a_poke_looks_at_once(served: tuple[StatusServer, Source]) -> None:
    """A period of a minute, yet a motor event (poke) brings the change now."""
    server, src = served
    with raw_subscriber(server.path, b"subscribe 60000\n") as sock:
        buf = bytearray()
        read_line(sock, buf)
        src.set(motors=[{"index": 0, "state": "idle"}])
        server.poke()
        assert read_line(sock, buf)["motors"] == [{"index": 0, "state": "idle"}]


def test_the_client_iterator_and_its_errors(served: tuple[StatusServer, Source]) -> None:
    server, src = served
    stream = subscribe(server.path, period_s=0.02)
    assert next(stream)["motors"] == []
    src.set(motors=[{"index": 1}])
    assert next(stream)["motors"] == [{"index": 1}]
    stream.close()
    until("the subscriber dropped", lambda: server.subscribers == 0)
    with pytest.raises(
        StatusError,
        match="PERIOD_MS must be a whole number of milliseconds from 20 to 60000, got '5'",
    ):
        next(subscribe(server.path, period_s=0.005))
    assert parse_request(b"subscribe soon\n").error is not None
    assert parse_request(b"subscribe 20 40\n").error is not None
    assert "known: histogram, subscribe [PERIOD_MS]" in str(parse_request(b"what\n").error)


def test_subscribers_are_limited_and_one_shot_reads_still_served(
    served: tuple[StatusServer, Source],
) -> None:
    server, _ = served
    streams = [subscribe(server.path, period_s=0.02) for _ in range(status_module.MAX_SUBSCRIBERS)]
    try:
        for stream in streams:
            next(stream)
        assert server.subscribers == status_module.MAX_SUBSCRIBERS
        with pytest.raises(StatusError, match="too many subscribers"):
            next(subscribe(server.path))
        assert read_status(server.path)["motors"] == []
    finally:
        for stream in streams:
            stream.close()
    until("all dropped", lambda: server.subscribers == 0)


def test_the_stream_ends_when_the_server_closes(tmp_path: Path) -> None:
    server = StatusServer(tmp_path / "status.sock", Source())
    server.start()
    stream = subscribe(server.path, period_s=0.02)
    next(stream)
    server.close()
    assert list(stream) == []  # ended, no error


def test_a_subscriber_that_stops_reading_is_dropped(
    served: tuple[StatusServer, Source], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Updates far larger than the socket's buffers: one that stays unread for
    SEND_TIMEOUT_S ends the subscription; nothing queues up meanwhile."""
    server, src = served
    monkeypatch.setattr(status_module, "SEND_TIMEOUT_S", 0.2)
    src.set(blob="x" * 8_000_000)
    with raw_subscriber(server.path, b"subscribe 20\n"):
        until("the subscriber dropped", lambda: server.subscribers == 0)
        assert read_status(server.path)["blob"] == "x" * 8_000_000


def unread(sock: socket.socket) -> int:
    """Bytes waiting in ``sock`` to be read (FIONREAD)."""
    raw = fcntl.ioctl(sock.fileno(), termios.FIONREAD, b"\0\0\0\0")
    value: int = struct.unpack("i", raw)[0]
    return value


def test_a_new_subscriber_takes_the_place_of_the_oldest_that_does_not_read(
    served: tuple[StatusServer, Source],
) -> None:
    """Every slot held by clients that subscribe and never read (the status changing all
    the while): a monitor still gets in, in place of the oldest of them; when every one
    reads, the daemon is full and says so."""
    server, src = served
    stop = threading.Event()

    def changes() -> None:
        tick = 0
        while not stop.wait(0.005):
            tick += 1
            src.set(tick=tick)

    changer = threading.Thread(target=changes, daemon=True)
    idle = []
    changer.start()
    try:
        for _ in range(status_module.MAX_SUBSCRIBERS):
            idle.append(raw_subscriber(server.path, b"subscribe 20\n"))
            until("subscribed", lambda: server.subscribers == len(idle))
        line = len(json.dumps(src()).encode())
        until("each several updates behind", lambda: min(map(unread, idle)) > 4 * (line + 1024))
        stream = subscribe(server.path, period_s=0.02)
        assert "tick" in next(stream)  # in, not "too many subscribers"
        assert server.evicted == 1 and server.subscribers == status_module.MAX_SUBSCRIBERS
        idle[0].settimeout(DEADLINE_S)  # the oldest: closed (after what it had not read)
        while idle[0].recv(1 << 20):
            pass
        for sock in idle[1:]:
            assert nothing_waiting(sock) is False  # the others: still subscribed
        assert next(stream)["tick"] > 0
        stream.close()
    finally:
        stop.set()
        changer.join()
        for sock in idle:
            sock.close()
    until("all dropped", lambda: server.subscribers == 0)
