"""The ends of hosts' sessions in the counters and the log (daemon/link/session_end.py), on a
clock the test sets: every dropped answer counted by its cause, a session that left
something said at INFO only once the line was quiet ``SAY_AFTER_S``, the poll's timeout
shortened to that moment, one that left nothing at DEBUG at once; what a host that closed
the PTY wrote and was not read, read out of a real PTY's master. (The loop ending real
hosts' sessions on a PTY: test_loop.py; motorctld's, after back pressure:
test_session_end_e2e.py.)"""

from __future__ import annotations

import dataclasses
import logging
import os
import tty
from collections import Counter
from collections.abc import Iterator

import pytest

from motorctl.daemon.link.session import Ended
from motorctl.daemon.link.session_end import (
    NOTHING,
    SAY_AFTER_S,
    SAY_WITHIN_S,
    UNREAD_MAX,
    SessionEnds,
    added,
    describe_ended,
    read_out,
)


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


def test_sessions_that_ended_moments_apart_are_said_in_one_line(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A host that reconnects over and over: the sessions that ended less than SAY_AFTER_S
    apart are said in one line, however many they are, with what they left in all (one
    line each made the link thread write 600 lines at once, inside a new host's first round
    trip: 35-41 ms, docs/timing.md); the counters have every one."""
    counters: Counter[str] = Counter()
    clock = Clock()
    ends = SessionEnds(counters, clock)
    caplog.set_level(logging.INFO, "motorctl.link")
    for _ in range(300):
        ends.ended("the host closed the port", Ended(4, 0, 0, 0, 0), unsent=0)
        ends.ended("the host closed the port", Ended(0, 0, 1, 2, 1), unsent=3)
        clock.t += SAY_AFTER_S / 4
    ends.ended("the port failed", Ended(0, 0, 0, 0, 0, unread_frames=2), unsent=0)
    assert caplog.records == []  # the line was never quiet for SAY_AFTER_S
    clock.t += SAY_AFTER_S
    assert ends.bound(clock.t, None) is None  # said now, all of it
    (said,) = caplog.records
    assert said.levelno == logging.INFO and said.__dict__["EVENT"] == "session_ended"
    assert said.__dict__["SESSIONS"] == 601
    assert said.getMessage() == (
        "601 sessions ended less than 20 ms apart (the host closed the port: 600, the port "
        "failed: 1): dropped what their hosts did not read (in all: 900 answers written or "
        "due, 300 held WaitMoveds' answers, 600 frames kept behind them (300 commands not "
        "executed), 2 frames it wrote that were not read yet, 1200 bytes of an incomplete "
        "frame); serving the next host"
    )
    assert counters["responses_dropped"] == 900 + 300 + 600
    assert counters["hangup_partial_bytes"] == 1200
    ends.say()  # nothing left to say
    assert len(caplog.records) == 1
    ends.ended("a", Ended(1, 0, 0, 0, 0), unsent=0)  # a later one on its own, as ever
    ends.say()
    assert caplog.records[-1].getMessage() == (
        "a: dropped what its host did not read (1 bytes of an incomplete frame); serving "
        "the next host"
    )


def test_a_line_that_is_never_quiet_still_has_its_ends_said_within_a_second(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A host that reconnects every 10 ms for minutes: the line is never quiet for
    SAY_AFTER_S, yet what the ended sessions left is said at the latest SAY_WITHIN_S after
    the first of them (the poll's timeout shortened to that moment), one line each time."""
    counters: Counter[str] = Counter()
    clock = Clock()
    ends = SessionEnds(counters, clock)
    caplog.set_level(logging.INFO, "motorctl.link")
    gap = SAY_AFTER_S / 2
    per_line = round(SAY_WITHIN_S / gap)
    timeouts = []
    for _ in range(3 * per_line):
        ends.ended("the host closed the port", Ended(0, 1, 0, 0, 0), unsent=1)
        clock.t += gap
        timeouts.append(ends.bound(clock.t, 500.0))
    said = [r for r in caplog.records if r.__dict__.get("EVENT") == "session_ended"]
    assert [r.__dict__["SESSIONS"] for r in said] == [per_line] * 3
    # never a wait longer than to the next saying: within SAY_WITHIN_S of the first end
    assert all(t is not None and t <= SAY_WITHIN_S * 1000 for t in timeouts)
    assert counters["responses_dropped_unsent"] == 3 * per_line


def test_what_sessions_left_is_added_field_by_field() -> None:
    fields = [f.name for f in dataclasses.fields(Ended)]
    a = Ended(*range(1, len(fields) + 1))
    b = Ended(*(10 * n for n in range(1, len(fields) + 1)))
    assert [getattr(added(a, b), f) for f in fields] == [11 * n for n in range(1, len(fields) + 1)]
    assert added(NOTHING, a) == a
    assert describe_ended(Ended(0, 0, 0, 2, 0), 1) == (
        "1 answers written or due, 2 frames kept behind it"
    )


def test_frames_the_host_wrote_and_were_not_read_are_counted_and_said() -> None:
    counters: Counter[str] = Counter()
    ends = SessionEnds(counters, Clock())
    ended = Ended(2, 0, 0, 0, 0, unread_frames=1129, unread_stops=1)
    ends.ended("the host closed the port", ended, unsent=7372)
    assert counters == Counter(
        hangup_partial_bytes=2,
        unread_frames_dropped=1129,
        unread_stops_executed=1,
        responses_dropped=7372,
        responses_dropped_unsent=7372,
    )
    assert describe_ended(ended, 7372) == (
        "7372 answers written or due, 1129 frames it wrote that were not read yet (1 StopMoves "
        "among them carried out), 2 bytes of an incomplete frame"
    )


@pytest.fixture
def pty() -> Iterator[tuple[int, str]]:
    """A PTY's master (non-blocking, as the daemon's) and its slave's name; nobody has the
    slave open."""
    master, slave = os.openpty()
    tty.setraw(slave)
    name = os.ttyname(slave)
    os.close(slave)
    os.set_blocking(master, False)
    yield master, name
    os.close(master)


def host_wrote(name: str, data: bytes) -> bytes:
    """A host that opens the slave, writes ``data`` (as much of it as the kernel takes while
    nobody reads: some 4 KiB in the line discipline, more in its flip buffers) and closes
    it (never reading); what it wrote."""
    fd = os.open(name, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    view = memoryview(data)
    try:
        while view:
            view = view[os.write(fd, view[:1024]) :]
    except BlockingIOError:
        pass
    finally:
        os.close(fd)
    return data[: len(data) - len(view)]


def test_what_a_host_that_closed_wrote_is_read_out_to_the_last_byte(
    pty: tuple[int, str],
) -> None:
    """More than the line discipline's 4 KiB: the rest waits in the kernel's flip buffers,
    moved on as the master reads; all of it is read out, and then the master says that
    nobody has the slave (no new host)."""
    master, name = pty
    wrote = host_wrote(name, bytes(range(256)) * 256)
    assert len(wrote) > 8192
    asked = []

    def no_new_host() -> bool:
        asked.append(True)
        return False

    assert read_out(master, no_new_host) == (wrote, b"", False)
    assert len(asked) > 1  # before the first read and after each


def test_a_new_host_that_has_the_port_stops_the_read_out(pty: tuple[int, str]) -> None:
    """Told by the slave's watch before anything is read: nothing is read (what is there
    may be the new host's, and is its session's); told after a read: that read's bytes are
    the new session's (a host's open is reported before it can write, so the reads before
    hold only the old host's); without a watch, by the master itself once nothing is left:
    the slave is open again."""
    master, name = pty
    host_wrote(name, b"old")
    assert read_out(master, lambda: True) == (b"", b"", True)
    asked = iter([False, True])
    assert read_out(master, lambda: next(asked)) == (b"", b"old", True)
    host_wrote(name, b"old")
    new = os.open(name, os.O_RDWR | os.O_NOCTTY)
    try:
        assert read_out(master, lambda: False) == (b"old", b"", True)
    finally:
        os.close(new)


def test_the_read_out_is_bounded(pty: tuple[int, str]) -> None:
    """A writer that never stops (a new host the watch did not see) cannot keep the link
    reading: at most UNREAD_MAX bytes."""
    master, name = pty
    new = os.open(name, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    chunk = bytes(4096)
    total = 0

    def keep_writing() -> bool:
        nonlocal total
        while True:  # fill what the kernel takes, every time the link asks
            try:
                total += os.write(new, chunk)
            except BlockingIOError:
                return False

    try:
        got, rest, reopened = read_out(master, keep_writing)
    finally:
        os.close(new)
    assert len(got) >= UNREAD_MAX and rest == b"" and not reopened and total > UNREAD_MAX
