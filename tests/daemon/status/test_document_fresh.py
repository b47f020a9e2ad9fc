"""A frequent reader's documents (daemon/status/document.py, ``StatusDocument``) are never
older than a change: on a clock that never moves, a document would be the answer forever
but for the counts that move on when something happens. So each read below shows what its
reader caused (a command answered, a move ended and its WaitMoved released, a pin set) or
what the daemon did on its own (a move's end, seen by polling the status only), and the
link's recent frames name the command just answered. A live daemon (in-process, thread
executor, link on a real PTY), read through its socket."""

from __future__ import annotations

import select
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from motorctl.daemon.status.document import StatusDocument
from motorctl.daemon.status.reader import read_status
from motorctl.daemon.status.server import StatusServer
from motorctl.protocol.codec import GetAbsPos, IsReady, MoveTo, SetPin, WaitMoved
from tests.support.frames import frame
from tests.support.inprocess import LIVE_CONFIG, LiveDaemon
from tests.support.wait import until

READ_DEADLINE_S = 10.0


@pytest.fixture
def served(tmp_path: Path) -> Iterator[tuple[LiveDaemon, Path]]:
    live = LiveDaemon(tmp_path, LIVE_CONFIG, motion=True)
    path = tmp_path / "status.sock"
    # the clock stands still: the last document is the answer until something happens
    server = StatusServer(path, StatusDocument(live.daemon, clock=lambda: 0.0))
    server.start()
    try:
        yield live, path
    finally:
        server.close()
        assert live.alive(), "a daemon thread died"
        live.close()


def read(path: Path) -> dict[str, Any]:
    return read_status(path, timeout=READ_DEADLINE_S)


def test_each_read_shows_what_its_reader_caused(served: tuple[LiveDaemon, Path]) -> None:
    live, path = served
    first = read(path)
    assert first["motors"][0]["state"] == "idle"
    assert live.code(MoveTo(0, True, 300, 0, 0, 0)) is None
    doc = read(path)
    assert doc["link"]["recent"][-1]["command"].startswith("MoveTo(motor=0")
    assert doc["motors"][0]["state"] != "idle" or doc["motors"][0]["position"] == 300
    assert live.code(WaitMoved(0, 20_000)) is None
    doc = read(path)
    assert doc["motors"][0]["state"] == "idle" and doc["motors"][0]["position"] == 300
    assert doc["link"]["recent"][-1]["command"] == "WaitMoved(motor=0, timeout_ms=20000)"
    assert live.code(SetPin(0, True)) is None
    assert read(path)["pins"][0]["level"] is True
    assert live.ask(GetAbsPos(0))[0].as_position == 300
    assert read(path)["link"]["recent"][-1]["command"] == "GetAbsPos(motor=0)"


def test_a_moves_end_is_seen_by_a_reader_of_the_status_alone(
    served: tuple[LiveDaemon, Path],
) -> None:
    live, path = served
    assert live.code(MoveTo(1, True, 200, 0, 0, 0)) is None
    until("motor 1 at rest at 200", lambda: read(path)["motors"][1]["state"] == "idle")
    assert read(path)["motors"][1]["position"] == 200


def test_back_pressure_is_seen_while_the_host_keeps_the_link_waiting(tmp_path: Path) -> None:
    """A reader's link part is kept until the link's moment moves on. A status read that
    comes between a turn's end and the next turn's count of back pressure (the race of the
    e2e test that hung, made certain here: the read is made right there, on the link's
    thread) must not be the answer while the link then waits in ``poll()`` for a host that
    never reads its answers: waiting moves the moment on."""
    live = LiveDaemon(tmp_path, backlog_limit=64, start=False)
    reader = StatusDocument(live.daemon)
    link = live.link
    listen = link._listen

    def read_then_listen(poller: select.poll) -> bool:
        reader.link(link)  # the status thread's read, just before back pressure is counted
        return listen(poller)

    link._listen = read_then_listen  # type: ignore[method-assign]
    live.thread.start()
    stop = threading.Event()
    host = live.host()
    writer = threading.Thread(
        target=host.write, args=(frame(*[IsReady(0)] * 20_000), stop), daemon=True
    )
    try:
        writer.start()
        live.until("back pressure", lambda: live.counters()["backpressure"] > 0)
        until(
            "the reader to see the back pressure",
            lambda: reader.link(link)["counters"]["backpressure"] > 0,
            READ_DEADLINE_S,
        )
    finally:
        stop.set()
        writer.join(READ_DEADLINE_S)
        host.close()
        live.close()
