"""The error answers' records and their journal lines (daemon/refusals.py), on a virtual clock:
the last one per motor and for the link, and the rate limit that a flood of bad frames cannot
get past, which says what it held back."""

from __future__ import annotations

import logging

import pytest

from motorctl.daemon.refusals import BURST, EVERY_S, Refusals
from motorctl.protocol.codec import ErrorCode, IsReady, MoveTo

E = ErrorCode
BAD = bytes.fromhex("03 00 00 00 00 00 00 00 00 00")


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


@pytest.fixture
def clock() -> Clock:
    return Clock()


@pytest.fixture
def r(clock: Clock) -> Refusals:
    return Refusals(["x", "y"], clock=clock, wall=lambda: 1.7e9 + clock.t)


def lines(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [rec.getMessage() for rec in caplog.records if rec.name == "motorctl.errors"]


def test_the_last_error_per_motor_and_for_the_link(r: Refusals, clock: Clock) -> None:
    r.add(E.INVALID_COMMAND, MoveTo(0, True, 30000, 0, 0, 0), 0, "target 30000 is outside")
    clock.t += 1
    r.add(E.MOTOR_ERROR, IsReady(1), 1, "end stop hit at 5 outside homing", ("StopMove",))
    clock.t += 1
    r.add(E.INVALID_ADDRESS, IsReady(7), None, "no motor 7 (this machine has motors 0..1)")
    assert r.motor_status(0) is not None and r.motor_status(0)["code"] == "E1"  # type: ignore[index]
    assert r.motor_status(1) == {
        "code": "E4",
        "name": "Motor Error",
        "command": "IsReady(motor=1)",
        "frame": None,
        "motor": 1,
        "reason": "end stop hit at 5 outside homing",
        "fix": ["StopMove"],
        "at_s": 101.0,
        "unix_s": 1.7e9 + 101.0,
    }
    status = r.status()
    assert status["answered"] == 3 and status["logged"] == 3 and status["suppressed"] == 0
    assert status["last"] == status["link"]
    assert status["link"]["reason"] == "no motor 7 (this machine has motors 0..1)"
    assert status["link"]["motor"] is None and status["link"]["at_s"] == 102.0
    r.add(E.INVALID_COMMAND, None, None, "bad frame: checksum 0x00, expected 0x8B", frame=BAD)
    assert r.status()["link"]["frame"] == BAD.hex(" ")
    assert r.status()["link"]["command"] is None
    assert r.motor_status(1)["reason"].startswith("end stop hit")  # type: ignore[index]


def test_one_journal_line_per_error_with_its_reason_and_fix(
    r: Refusals, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, "motorctl.errors")
    r.add(E.MOTOR_ERROR, IsReady(1), 1, "end stop hit at 5 outside homing", ("StopMove",))
    r.add(E.INVALID_COMMAND, None, None, "bad frame: checksum 0x00, expected 0x8B", frame=BAD)
    r.add(E.MOTOR_NOT_READY, IsReady(0), 0, "still moving")
    assert lines(caplog) == [
        "motor 1 (y): IsReady(motor=1) answered E4 Motor Error: end stop hit at 5 outside "
        "homing; StopMove clears it",
        "link: frame 03 00 00 00 00 00 00 00 00 00 answered E1 Invalid Command: bad frame: "
        "checksum 0x00, expected 0x8B",
        "motor 0 (x): IsReady(motor=0) answered E3 Motor not ready: still moving",
    ]
    levels = [rec.levelno for rec in caplog.records]
    assert levels == [logging.WARNING, logging.WARNING, logging.INFO]  # E3: an answer on time
    first = caplog.records[0]
    assert (first.MOTOR, first.COMMAND, first.ERROR_CODE) == (1, "IsReady", "E4")  # type: ignore[attr-defined]


def test_a_flood_of_bad_frames_writes_a_burst_then_says_how_many_it_held_back(
    r: Refusals, clock: Clock, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, "motorctl.errors")
    for i in range(1000):  # a thousand bad frames in one second
        clock.t = 100.0 + i / 1000
        r.add(E.INVALID_COMMAND, None, None, "bad frame: checksum", frame=BAD)
        if i == 500:  # a motor's error in the middle of it has its own budget
            r.add(E.MOTOR_ERROR, IsReady(0), 0, "end stop hit at 0 outside homing")
    got = lines(caplog)
    assert len([g for g in got if g.startswith("link: ")]) == BURST
    assert [g for g in got if g.startswith("motor 0 (x): ")] == [
        "motor 0 (x): IsReady(motor=0) answered E4 Motor Error: end stop hit at 0 outside homing"
    ]
    assert r.status()["suppressed"] == 1000 - BURST and r.status()["answered"] == 1001
    caplog.clear()
    r.flush()  # no token yet: nothing said, nothing lost
    assert lines(caplog) == []
    clock.t += EVERY_S  # the link may write one line again: the summary
    r.flush()
    (summary,) = lines(caplog)
    assert summary.startswith(f"link: {1000 - BURST} more error answers not logged in the last ")
    assert summary.endswith(
        "the last: frame 03 00 00 00 00 00 00 00 00 00 answered E1 Invalid "
        "Command: bad frame: checksum"
    )
    assert caplog.records[0].SUPPRESSED == 1000 - BURST  # type: ignore[attr-defined]
    r.flush()
    assert len(lines(caplog)) == 1  # said once
    assert r.status()["logged"] == BURST + 2


def test_the_next_line_of_a_source_says_what_was_held_back_since_its_last(
    r: Refusals, clock: Clock, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, "motorctl.errors")
    for _ in range(BURST + 3):
        r.add(E.INVALID_ADDRESS, IsReady(9), None, "no motor 9")
    clock.t += EVERY_S
    r.add(E.INVALID_ADDRESS, IsReady(8), None, "no motor 8")
    last = lines(caplog)[-1]
    assert last == (
        "link: IsReady(motor=8) answered E2 Invalid Address: no motor 8 "
        f"(and 3 more not logged in the last {EVERY_S:.1f} s)"
    )
    assert len(lines(caplog)) == BURST + 1


def test_the_budget_refills_one_line_per_period_up_to_the_burst(
    r: Refusals, clock: Clock, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, "motorctl.errors")
    for _ in range(BURST):
        r.add(E.INVALID_ADDRESS, IsReady(9), None, "no motor 9")
    clock.t += 1000 * EVERY_S  # a long quiet spell refills the burst, no more
    for _ in range(BURST + 1):
        r.add(E.INVALID_ADDRESS, IsReady(9), None, "no motor 9")
    assert len(lines(caplog)) == 2 * BURST
    assert r.status()["suppressed"] == 1
