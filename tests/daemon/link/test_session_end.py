"""The ends of hosts' sessions in the counters and the log (daemon/link/session_end.py), on a
clock the test sets: every dropped answer counted by its cause, a session that left
something said at INFO only once the line was quiet ``SAY_AFTER_S``, the poll's timeout
shortened to that moment, one that left nothing at DEBUG at once. (The loop ending real
hosts' sessions on a PTY: test_loop.py.)"""

from __future__ import annotations

import logging
from collections import Counter

import pytest

from motorctl.daemon.link.session import Ended
from motorctl.daemon.link.session_end import SAY_AFTER_S, SessionEnds, describe_ended


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_what_a_session_left_is_counted_by_cause_and_said_a_moment_later(
    caplog: pytest.LogCaptureFixture,
) -> None:
    counters: Counter[str] = Counter()
    clock = Clock()
    ends = SessionEnds(counters, clock)
    caplog.set_level(logging.DEBUG, "motorctl.link")
    ends.ended("the host closed the port", Ended(3, 2, 1, 4, 2), unsent=5)
    assert counters == Counter(
        hangup_partial_bytes=3,
        responses_dropped=10,
        responses_dropped_unsent=5,
        responses_dropped_wait=1,
        responses_dropped_held=4,
    )
    assert caplog.records == []  # not yet: a new host's first command comes first
    assert ends.bound(clock.t, None) == pytest.approx(SAY_AFTER_S * 1000)
    assert ends.bound(clock.t, 5.0) == 5.0  # a sooner timeout stands
    clock.t += SAY_AFTER_S / 2
    assert ends.bound(clock.t, 500.0) == pytest.approx(SAY_AFTER_S * 500)
    clock.t += SAY_AFTER_S / 2
    assert ends.bound(clock.t, 500.0) == 500.0  # due: said now
    (said,) = caplog.records
    assert said.levelno == logging.INFO and said.__dict__["EVENT"] == "session_ended"
    assert said.getMessage() == (
        "the host closed the port: dropped what its host did not read (5 answers written "
        "or due, a held WaitMoved's answer, 4 frames kept behind it (2 commands not "
        "executed), 3 bytes of an incomplete frame); serving the next host"
    )
    assert ends.bound(clock.t, None) is None  # nothing left to say


def test_a_session_that_left_nothing_is_said_at_once_at_debug(
    caplog: pytest.LogCaptureFixture,
) -> None:
    counters: Counter[str] = Counter()
    ends = SessionEnds(counters, Clock())
    caplog.set_level(logging.DEBUG, "motorctl.link")
    ends.ended("its serial device went away", Ended(0, 0, 0, 0, 0), unsent=0)
    (said,) = caplog.records
    assert said.levelno == logging.DEBUG
    assert said.getMessage() == "its serial device went away; serving the next host"
    assert counters == Counter(hangup_partial_bytes=0)
    ends.drop("shutdown", 0)  # nothing dropped: nothing counted
    ends.drop("shutdown", 2)
    assert counters["responses_dropped"] == counters["responses_dropped_shutdown"] == 2


def test_say_logs_every_end_not_said_yet() -> None:
    ends = SessionEnds(Counter(), Clock())
    ends.ended("a", Ended(1, 0, 0, 0, 0), unsent=0)
    ends.ended("b", Ended(0, 0, 1, 0, 0), unsent=0)
    ends.say()
    assert ends.bound(0.0, None) is None
    assert describe_ended(Ended(0, 0, 0, 2, 0), 1) == (
        "1 answers written or due, 2 frames kept behind it"
    )
