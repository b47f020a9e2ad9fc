"""Each error answer's reason, decided where the decision is made: the dispatcher's checks in
their precedence, the motor's fault latch, the link session's frame checks and held-frame
buffer. Through the link session in front of a daemon on a virtual clock (SessionRig), so
that what the host gets and what the status keeps are seen together."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from motorctl.protocol.codec import (
    Command,
    DcMove,
    ErrorCode,
    GetPin,
    InitMove,
    IsReady,
    Move,
    MoveTo,
    MoveToWayPoint,
    SaveHome,
    SaveWayPoint,
    SetPin,
    StopMove,
    WaitMoved,
)
from tests.support.frames import frame
from tests.support.sessions import SessionRig

E = ErrorCode

CONFIG = """
[[motors]]
name = "a"
max_waypoints = 1
soft_limit_min = -100
soft_limit_max = 100
queue_depth = 1
[[motors]]
name = "b"
[[pins]]
number = 0
[[pins]]
number = 1
mode = "input"
[[pins]]
number = 4
"""


@pytest.fixture
def w(tmp_path: Path) -> SessionRig:
    return SessionRig(tmp_path, CONFIG, held=2)


def refused(w: SessionRig, cmd: Command, code: ErrorCode) -> dict[str, Any]:
    """``cmd``'s answer is ``code``, one the command table says it can give; the record the
    status keeps of it."""
    assert w.call(cmd).error_code is code, cmd
    assert code in [g.code for g in cmd.spec.gives], f"{cmd}: {code.short} is not in the table"
    last = w.daemon.dispatcher.refusals.status()["last"]
    assert last is not None and last["code"] == code.short
    return dict(last)


NO_MOTOR = "no motor 2 (this machine has motors 0..1)"
OUTSIDE = "target 101 is outside the soft limits -100..100"


@pytest.mark.parametrize(
    ("cmd", "code", "reason", "motor", "fix"),
    [
        (MoveTo(2, True, 0, 0, 0, 0), E.INVALID_ADDRESS, NO_MOTOR, None, []),
        (GetPin(2), E.INVALID_ADDRESS, "no pin 2 (this machine has pins 0..1, 4)", None, []),
        (DcMove(True, 100, False), E.INVALID_ADDRESS, "no DC motor configured", None, []),
        (MoveTo(0, True, 101, 0, 0, 0), E.INVALID_COMMAND, OUTSIDE, 0, []),
        (SetPin(1, True), E.INVALID_COMMAND, "pin 1 is an input", None, ["ConfigPin"]),
        (MoveToWayPoint(0, 3, 0, 0, 0), E.INVALID_WAYPOINT, "no waypoint 3; none saved", 0, []),
    ],
)
def test_the_reason_of_each_check(
    w: SessionRig, cmd: Command, code: ErrorCode, reason: str, motor: int | None, fix: list[str]
) -> None:
    last = refused(w, cmd, code)
    assert (last["reason"], last["motor"], last["fix"]) == (reason, motor, fix)
    assert last["command"] is not None and last["command"].startswith(type(cmd).__name__ + "(")
    status = w.daemon.dispatcher.refusals.status()
    if motor is None:  # not tied to a motor: the link's
        assert status["link"] == last
    else:
        assert w.daemon.dispatcher.refusals.motor_status(motor) == last


def test_a_latched_fault_says_what_latched_it_and_that_stopmove_clears_it(w: SessionRig) -> None:
    """The end stop of the mock's axis, hit outside homing: the motor's own fault text."""
    assert w.call(Move(1, False, 1, 0, 0)).ack
    w.run(15.0)
    last = refused(w, IsReady(1), E.MOTOR_ERROR)
    assert last["reason"] == f"end stop hit at {w.motors[1].position} outside homing"
    assert (last["motor"], last["fix"]) == (1, ["StopMove"])
    assert w.call(InitMove(1, True, 0, 0, 0)).error_code is E.MOTOR_ERROR  # homing needs a stop
    assert w.call(StopMove(1, False)).ack


def test_a_lost_position_says_to_home_and_a_fault_then_both(w: SessionRig) -> None:
    w.motors[0].position_lost = True
    last = refused(w, MoveTo(0, True, 5, 0, 0, 0), E.MOTOR_ERROR)
    assert last["reason"].startswith("its position is lost")
    assert last["fix"] == ["InitMove"]
    with w.engine.lock:
        w.motors[0].latch_fault("step timing lost (test)", w.now, lost=True)
    last = refused(w, IsReady(0), E.MOTOR_ERROR)
    assert (last["reason"], last["fix"]) == ("step timing lost (test)", ["StopMove", "InitMove"])


def test_busy_full_and_timed_out(w: SessionRig) -> None:
    assert w.call(Move(0, True, 1, 0, 0)).ack
    reason = refused(w, SaveHome(0), E.MOTOR_NOT_READY)["reason"]
    assert reason == "not idle (running, 0 queued): it must be at rest"
    assert w.call(MoveTo(0, True, 0, 0, 0, 0)).ack  # queue depth 1: full now
    reason = refused(w, MoveTo(0, True, 0, 0, 0, 0), E.FULL_BUFFER)["reason"]
    assert reason == "motion queue full (1 commands behind the running one)"
    reason = refused(w, WaitMoved(0, 0), E.MOTOR_NOT_READY)["reason"]
    assert reason == "still moving; TIMEOUT 0 answers at once"
    w.send(WaitMoved(0, 20))
    assert [r.error_code for r in w.quiet_until_answered()] == [E.MOTOR_NOT_READY]
    last = w.daemon.dispatcher.refusals.status()["last"]
    assert last["reason"] == "still moving after 20 ms (WaitMoved's TIMEOUT)"
    assert last["command"] == "WaitMoved(motor=0, timeout_ms=20)"


def test_a_full_waypoint_table(w: SessionRig) -> None:
    assert w.call(SaveWayPoint(0)).ack
    reason = refused(w, SaveWayPoint(0), E.FULL_WAYPOINT_BUFFER)["reason"]
    assert reason == "waypoint table full (1 waypoints)"
    assert refused(w, MoveToWayPoint(0, 1, 0, 0, 0), E.INVALID_WAYPOINT)["reason"] == (
        "no waypoint 1; saved: 0"
    )


def test_the_link_sessions_own_errors_have_their_reasons(w: SessionRig) -> None:
    bad = bytearray(frame(IsReady(0)))
    bad[-1] ^= 0xFF
    assert [r.error_code for r in w.ask(bytes(bad))] == [E.INVALID_COMMAND]
    link = w.daemon.dispatcher.refusals.status()["link"]
    assert link["reason"] == f"bad frame: checksum 0x{bad[-1]:02X}, expected 0x{bad[-1] ^ 0xFF:02X}"
    assert (link["frame"], link["command"], link["motor"]) == (bad.hex(" "), None, None)
    # the held-frame buffer (2 here) full behind a WaitMoved: E0 for the third
    assert w.call(Move(0, True, 1, 0, 0)).ack
    w.send(WaitMoved(0, 10_000), IsReady(1), IsReady(1), IsReady(1))
    last = w.daemon.dispatcher.refusals.status()["last"]
    assert last["code"] == "E0" and last["command"] == "IsReady(motor=1)"
    assert last["reason"] == "held-frame buffer full (2 frames behind a WaitMoved)"
    assert last["motor"] == 1  # a motor of this machine: its record
