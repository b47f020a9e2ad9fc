"""Why the device said no, on the client's side (client/reasons.py): where it looks for the
daemon's status socket, how it reads it (a real Unix socket here: answered, silent, missing,
not a socket, nonsense), which record is this error's, and the code's meaning for each
command when there is none. The whole path against a real daemon: test_cli_e2e.py."""

from __future__ import annotations

import json
import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

from motorctl.client.reasons import (
    DEFAULT_STATE_DIR,
    STATE_DIR_ENV,
    explain,
    find_record,
    meaning,
    read_document,
    socket_paths,
)
from motorctl.protocol.codec import (
    Command,
    DcMove,
    ErrorCode,
    GetPin,
    InitMove,
    IsReady,
    MoveTo,
    MoveToWayPoint,
    SaveHome,
    SetPin,
    StopMove,
    WaitMoved,
)

E = ErrorCode
HANG_S = 10.0  # a read that hangs is a failure, not a stuck test


@contextmanager
def status_socket(path: Path, answer: bytes | None) -> Iterator[list[bytes]]:
    """A status socket at ``path`` that answers each request with ``answer`` and closes
    (None: accepts, reads, and says nothing until the test ends); the requests it got."""
    requests: list[bytes] = []
    server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    server.bind(str(path))
    server.listen(4)
    done = threading.Event()

    def serve() -> None:
        server.settimeout(0.05)
        while not done.is_set():
            try:
                conn, _ = server.accept()
            except TimeoutError:
                continue
            with conn:
                conn.settimeout(HANG_S)
                requests.append(conn.recv(100))
                if answer is None:
                    done.wait(HANG_S)
                else:
                    conn.sendall(answer)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield requests
    finally:
        done.set()
        thread.join(HANG_S)
        server.close()


def record(**kw: Any) -> dict[str, Any]:
    out: dict[str, Any] = {
        "code": "E4",
        "command": "IsReady(motor=0)",
        "frame": None,
        "motor": 0,
        "reason": "end stop hit at -10000 outside homing",
        "fix": ["StopMove"],
        "at_s": 50.0,
    }
    out.update(kw)
    return out


def doc_with(*records: dict[str, Any]) -> dict[str, Any]:
    return {
        "motors": [{"index": 0, "last_error": records[0] if records else None}],
        "errors": {"last": records[-1] if records else None, "link": None},
    }


def test_where_it_looks(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    assert socket_paths("/run/motorctl/motorctl.pty", None) == [
        Path("/run/motorctl/status.sock"),  # the service: beside its PTY
        Path("/run/motorctl/.run/state/status.sock"),
    ]
    monkeypatch.chdir(tmp_path)
    assert socket_paths("motorctl.pty", None) == [  # make run: in .run/state beside it
        tmp_path / "status.sock",
        tmp_path / ".run" / "state" / "status.sock",
        DEFAULT_STATE_DIR / "status.sock",
    ]
    assert socket_paths("/dev/ttyAMA0", "/run/motorctl-left") == [
        Path("/run/motorctl-left/status.sock")
    ]


def test_it_reads_the_document_with_the_sockets_protocol(tmp_path: Path) -> None:
    doc = doc_with(record())
    path = tmp_path / "status.sock"
    with status_socket(path, json.dumps(doc).encode()) as requests:
        assert read_document(path, time.monotonic() + HANG_S) == doc
    assert requests == [b"\n"]  # the plain status: one line, then the document


def test_a_silent_daemon_costs_at_most_the_deadline(tmp_path: Path) -> None:
    path = tmp_path / "status.sock"
    got: list[object] = ["not returned"]
    with status_socket(path, None):
        reader = threading.Thread(
            target=lambda: got.__setitem__(0, read_document(path, time.monotonic() + 0.2))
        )
        reader.start()
        reader.join(HANG_S)
        assert not reader.is_alive()
    assert got == [None]


@pytest.mark.parametrize("what", ["missing", "a regular file", "nonsense", "a list"])
def test_anything_but_a_document_is_none(tmp_path: Path, what: str) -> None:
    path = tmp_path / "status.sock"
    deadline = time.monotonic() + HANG_S
    if what == "missing":
        assert read_document(path, deadline) is None
    elif what == "a regular file":
        path.write_text(json.dumps(doc_with(record())))
        assert read_document(path, deadline) is None
    else:
        answer = b"{not json" if what == "nonsense" else b"[1, 2]"
        with status_socket(path, answer):
            assert read_document(path, deadline) is None


def test_the_record_of_this_error_and_no_other() -> None:
    doc = doc_with(record())
    assert find_record(doc, E.MOTOR_ERROR, IsReady(0), 49.0) == record()
    assert find_record(doc, E.MOTOR_ERROR, IsReady(0), 51.0) is None  # an older one
    assert find_record(doc, E.MOTOR_NOT_READY, IsReady(0), 49.0) is None  # another code
    assert find_record(doc, E.MOTOR_ERROR, IsReady(1), 49.0) is None  # another command
    bad = bytes.fromhex("03 00 00 00 00 00 00 00 00 00")
    link = record(code="E1", command=None, frame=bad.hex(" "), motor=None, fix=[])
    assert find_record(doc_with(link), E.INVALID_COMMAND, None, 49.0, bad) == link
    assert find_record(doc_with(link), E.INVALID_COMMAND, None, 49.0, b"\x03" * 10) is None
    assert find_record({"errors": "?", "motors": [None]}, E.MOTOR_ERROR, None, 0.0) is None


def test_the_daemons_reason_when_its_socket_has_it(tmp_path: Path) -> None:
    path = tmp_path / "status.sock"
    doc = doc_with(record(at_s=time.monotonic() + 1.0, fix=["StopMove", "InitMove"]))
    beside = str(tmp_path / "motorctl.pty")
    with status_socket(path, json.dumps(doc).encode()):
        text = explain(E.MOTOR_ERROR, IsReady(0), beside, time.monotonic(), env={})
        named = {STATE_DIR_ENV: str(tmp_path)}
        assert explain(E.MOTOR_ERROR, IsReady(0), "/dev/ttyUSB0", 0.0, env=named) == text
        # another motor's error is not this one's: the code's meaning
        assert explain(E.MOTOR_ERROR, IsReady(1), beside, 0.0, env={}).startswith(
            "E4 motor error: motor 1 has a latched fault"
        )
    assert text == (
        "E4 motor error: end stop hit at -10000 outside homing (motor 0) — clear it with "
        "'motorctl stop 0', then home it with 'motorctl init 0 up|down'"
    )


def test_without_the_socket_the_codes_meaning_for_the_command(tmp_path: Path) -> None:
    env = {STATE_DIR_ENV: str(tmp_path)}  # no socket there
    assert explain(E.INVALID_ADDRESS, DcMove(True, 100, False), "p", 0.0, env=env) == (
        "E2 invalid address: no DC motor configured"
    )
    assert explain(E.INVALID_ADDRESS, MoveTo(5, True, 0, 0, 0, 0), "p", 0.0, env=env) == (
        "E2 invalid address: no motor 5"
    )
    assert explain(E.INVALID_COMMAND, MoveTo(0, True, 9, 0, 0, 0), "p", 0.0, env=env) == (
        "E1 invalid command: target 9 is outside motor 0's soft limits or its driver chip's range"
    )
    assert explain(0x42, None, "p", 0.0, env=env) == "unknown error code 0x42"


@pytest.mark.parametrize(
    ("code", "cmd", "text"),
    [
        (E.INVALID_ADDRESS, GetPin(9), "no pin 9"),
        (E.INVALID_ADDRESS, IsReady(7), "no motor 7"),
        (E.INVALID_COMMAND, SetPin(5, True), "pin 5 is an input — make it an output with "
         "'motorctl pin config 5 out'"),
        (E.INVALID_COMMAND, None, "the frame was refused: a wrong checksum, an unknown "
         "command or non-zero padding"),
        (E.MOTOR_NOT_READY, WaitMoved(1, 100), "motor 1 still moving when TIMEOUT_MS ran out"),
        (E.MOTOR_NOT_READY, SaveHome(1), "motor 1 is moving or has commands queued; it must "
         "be at rest"),
        (E.MOTOR_ERROR, StopMove(2, False), "motor 2's fault remains (its driver still "
         "reports it)"),
        (E.MOTOR_ERROR, InitMove(2, True, 0, 0, 0), "motor 2 has a latched fault — clear it "
         "with 'motorctl stop 2'"),
        (E.MOTOR_ERROR, MoveTo(2, True, 0, 0, 0, 0), "motor 2 has a latched fault or has lost "
         "its position — clear it with 'motorctl stop 2', or home it with 'motorctl init 2 "
         "up|down'"),
        (E.MOTOR_ERROR, IsReady(1), "motor 1 has a latched fault — clear it with "
         "'motorctl stop 1'"),
        (E.MOTOR_ERROR, GetPin(3), "pin 3's line failed (hardware error)"),
        (E.INVALID_COMMAND, InitMove(0, True, 0, 0, 0), "the frame was refused: a wrong "
         "checksum, an unknown command or non-zero padding"),
        (E.INVALID_WAYPOINT, IsReady(0), "no such waypoint"),
        (E.FULL_BUFFER, MoveTo(0, True, 0, 0, 0, 0), "motor 0's motion queue is full"),
        (E.FULL_WAYPOINT_BUFFER, IsReady(0), "motor 0's waypoint table is full"),
        (E.INVALID_WAYPOINT, MoveToWayPoint(0, 4, 0, 0, 0), "no waypoint 4 saved on motor 0"),
    ],
)  # fmt: skip
def test_each_codes_meaning(code: ErrorCode, cmd: Command | None, text: str) -> None:
    assert meaning(code, cmd) == text
