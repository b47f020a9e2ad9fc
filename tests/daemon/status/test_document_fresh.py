"""A frequent reader's documents (daemon/status/document.py, ``StatusDocument``) are never
older than a change: on a clock that never moves, a document would be the answer forever
but for the counts that move on when something happens. So each read below shows what its
reader caused (a command answered, a move ended and its WaitMoved released, a pin set) or
what the daemon did on its own (a move's end, seen by polling the status only), and the
link's recent frames name the command just answered. A live daemon (in-process, thread
executor, link on a real PTY), read through its socket."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from motorctl.daemon.status.document import StatusDocument
from motorctl.daemon.status.reader import read_status
from motorctl.daemon.status.server import StatusServer
from motorctl.protocol.codec import GetAbsPos, MoveTo, SetPin, WaitMoved
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
