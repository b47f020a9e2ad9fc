"""The link's shell on a real PTY (and a socket where a PTY cannot make the error), in-process.

Every wait has a deadline and fails with a message. The dispatcher behind it runs on a
virtual clock: these tests are about the bytes, not the motors.
"""

from __future__ import annotations

import os
import select
import signal
import socket
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from motorctl.daemon.dispatcher import Dispatcher, Wait
from motorctl.daemon.link import loop, session_end
from motorctl.daemon.link.silence import SilenceWatch
from motorctl.daemon.start.signals import StopSignals
from motorctl.protocol.codec import (
    Command,
    ErrorCode,
    GetAbsPos,
    GetPin,
    IsReady,
    Move,
    MoveTo,
    Response,
    SetPin,
    StopMove,
    WaitMoved,
)
from tests.support.frames import frame
from tests.support.inprocess import LIVE_CONFIG, Host, LiveDaemon

E = ErrorCode
DEADLINE_S = 20.0  # generous: these tests must pass on a loaded 2-core machine


class SlowPort:
    """The dispatcher, made slow: the daemon is busy while bytes keep arriving."""

    def __init__(self, inner: Dispatcher, delay_s: float) -> None:
        self.inner = inner
        self.delay_s = delay_s

    def handle(self, cmd: Command) -> Response:
        time.sleep(self.delay_s)
        return self.inner.handle(cmd)

    def wait_begin(self, cmd: WaitMoved, now: float) -> Response | Wait:
        return self.inner.wait_begin(cmd, now)

    def wait_poll(self, wait: Wait, now: float) -> Response | None:
        return self.inner.wait_poll(wait, now)

    def refused(
        self,
        code: ErrorCode,
        reason: str,
        command: Command | None = None,
        frame: bytes | None = None,
    ) -> None:
        self.inner.refused(code, reason, command, frame)


class GatedPort(SlowPort):
    """The dispatcher, whose held WaitMoved's next look waits for the test: the link is
    kept busy (not in poll()) for as long as the test needs."""

    def __init__(self, inner: Dispatcher) -> None:
        super().__init__(inner, 0.0)
        self.gate = threading.Event()
        self.gate.set()
        self.entered = threading.Event()

    def wait_poll(self, wait: Wait, now: float) -> Response | None:
        if not self.gate.is_set():
            self.entered.set()
            self.gate.wait(DEADLINE_S)
        return self.inner.wait_poll(wait, now)


@pytest.fixture
def served(tmp_path: Path) -> Iterator[LiveDaemon]:
    s = LiveDaemon(tmp_path)
    yield s
    s.close()


@pytest.fixture
def flooded(tmp_path: Path) -> Iterator[LiveDaemon]:
    """For a host that writes thousands of frames in one write: a gap of a second, not the
    10 ms of ``served``. The kernel takes such a write a PTY buffer at a time, each ending
    mid-frame as often as not, and a loaded machine (a `make test` beside other work) can
    leave the writing thread unscheduled for 10 ms while the daemon waits for the rest of
    that frame: a real gap by the protocol, and its frame rightly discarded (one answer
    missing of 10,000, seen once). What these tests check is back pressure and counting,
    and that no gap is seen (``gap_discards`` stays 0)."""
    s = LiveDaemon(tmp_path, gap_s=1.0)
    yield s
    s.close()


def test_serves_and_stops(served: LiveDaemon) -> None:
    host = served.host()
    host.write(frame(IsReady(0)))
    assert [r.as_bool for r in host.responses(1)] == [True]
    assert served.stop() < 2.0
    host.close()


def test_a_stop_before_serve_is_not_forgotten(tmp_path: Path) -> None:
    """A SIGTERM during start-up calls stop() before serve(): serve() must return at once
    (it used to start by setting "running" again, and served on for ever)."""
    s = LiveDaemon(tmp_path, start=False)
    try:
        s.link.stop()
        s.thread.start()
        s.thread.join(DEADLINE_S)
        assert not s.thread.is_alive(), "serve() after stop() did not return"
    finally:
        s.close()


def _asleep(tid: int) -> bool:
    with open(f"/proc/self/task/{tid}/stat") as f:
        return f.read().rsplit(")", 1)[1].split()[0] == "S"


def test_a_signal_that_another_thread_takes_still_wakes_an_idle_link(tmp_path: Path) -> None:
    """The daemon's stop signals, wired as main() wires them, with the link loop asleep in
    poll() (no timeout: the host's port is open and idle) and the signal's C handler run on
    another thread, as when the signal arrives just before poll() or the kernel hands it to
    another thread: the Python handler cannot run until poll() returns, so only the signal
    wake-up descriptor ends it. Without it, serve() ran on until the host's next byte."""
    if threading.current_thread() is not threading.main_thread():
        pytest.skip("signal handlers run in the main thread only")
    before = signal.set_wakeup_fd(-1)  # whatever this process had: given back at the end
    signal.set_wakeup_fd(before)
    s = LiveDaemon(tmp_path, start=False)
    host = s.host()
    stop = StopSignals()
    sent: list[float] = []
    finished = threading.Event()
    try:
        stop.attach(s.link.stop, s.link.signal_fd)
        main_tid = threading.get_native_id()

        def signal_from_here() -> None:
            host.write(frame(IsReady(0)))
            host.responses(1)
            end, last = time.monotonic() + DEADLINE_S, -1
            while not (s.link.turns == last and _asleep(main_tid)):  # in poll(), idle
                if time.monotonic() > end:
                    s.link.stop()  # no signal sent: the assertion below says why
                    return
                last = s.link.turns
                time.sleep(0.02)
            sent.append(time.monotonic())
            signal.pthread_kill(threading.get_ident(), signal.SIGTERM)  # handled HERE
            if not finished.wait(DEADLINE_S):
                host.write(frame(IsReady(0)))  # the old code's only way out of poll()

        threading.Thread(target=signal_from_here, name="signaller", daemon=True).start()
        s.link.serve()  # here, in the main thread, as in motorctld
        assert sent, f"the link loop never went to sleep in {DEADLINE_S} s"
        took = time.monotonic() - sent[0]
        assert stop.requested == "SIGTERM"
        assert took < DEADLINE_S / 2, f"the link noticed the SIGTERM only after {took:.1f} s"
    finally:
        finished.set()
        stop.restore()
        host.close()
        s.close()
    assert signal.set_wakeup_fd(before) == before  # detached: no byte for a closed pipe


def test_burst_of_20000_frames_read_concurrently(flooded: LiveDaemon) -> None:
    served = flooded
    host = served.host()
    cmds = [GetAbsPos(i % 2) if i % 2 else IsReady(i % 2) for i in range(20_000)]
    writer = threading.Thread(target=host.write, args=(frame(*cmds),))
    writer.start()
    rs = host.responses(20_000, timeout=60.0)
    writer.join(DEADLINE_S)
    assert all(r.ack for r in rs)
    assert all(r.as_bool for r in rs[::2])
    c = served.counters()
    assert c["frames_good"] == 20_000 and c["gap_discards"] == 0 and c["sent_E1"] == 0
    host.close()


def test_slow_reader_loses_nothing(flooded: LiveDaemon) -> None:
    """The host writes 10,000 frames and reads nothing until the daemon's answers have
    filled the PTY: the daemon stops reading (back pressure) instead of blocking in a write
    or growing without bound, and once the host reads, every answer comes."""
    served = flooded
    host = served.host()
    data = b"".join(frame(GetAbsPos(i % 2)) for i in range(10_000))
    writer = threading.Thread(target=host.write, args=(data,))
    writer.start()

    def held_back() -> bool:
        c = served.counters()
        return bool(c["write_eagain"] > 0 or c["backpressure"] > 0)

    served.until("the daemon held back by the unread answers", held_back)
    assert served.thread.is_alive()
    assert writer.is_alive() or served.counters()["frames_good"] < 10_000  # not all taken
    rs = host.responses(10_000, timeout=60.0)
    writer.join(DEADLINE_S)
    assert not writer.is_alive(), "the host's write never completed"
    assert all(r.ack and r.as_position == 0 for r in rs)
    c = served.counters()
    assert c["frames_good"] == 10_000 and c["responses_dropped"] == 0
    assert c["gap_discards"] == 0
    host.close()


def test_bytes_buffered_while_busy_are_not_a_gap(tmp_path: Path) -> None:
    """Byte by byte, 20 ms apart (well below a 100 ms gap, so that a loaded machine does
    not stretch it into a real one), to a daemon that takes 300 ms per command: each read
    finds bytes, often part of a frame, that waited while it was busy. None is a gap."""
    base = LiveDaemon(tmp_path / "a")
    base.close()
    s = LiveDaemon(tmp_path, port=SlowPort(base.daemon.dispatcher, 0.300), gap_s=0.100)
    try:
        host = s.host()
        data = b"".join(frame(IsReady(0)) for _ in range(3))
        for b in data:
            host.write(bytes([b]))
            time.sleep(0.020)
        rs = host.responses(3)
        assert all(r.as_bool for r in rs)
        c = s.counters()
        assert c["gap_discards"] == 0
        assert c["reads"] < len(data)  # bytes did pile up while the daemon was busy
        host.close()
    finally:
        s.close()


def test_a_real_gap_is_watched_and_discards(served: LiveDaemon) -> None:
    host = served.host()
    host.write(frame(Move(0, True, 1, 0, 0))[:6])
    served.until("the gap discard", lambda: served.counters()["gap_discards"] == 1)
    host.write(frame(IsReady(0)))
    assert [r.as_bool for r in host.responses(1)] == [True]
    host.close()


def test_host_closes_and_reopens(served: LiveDaemon) -> None:
    host = served.host()
    host.write(frame(IsReady(0)))
    assert len(host.responses(1)) == 1
    # Half a frame and a whole one, then close without reading the answer.
    host.write(frame(GetAbsPos(0)) + frame(IsReady(0))[:4])
    served.until("the frame", lambda: served.counters()["frames_good"] == 2)
    closed = served.counters()["peer_closed"]
    host.close()
    served.until("the hang-up", lambda: served.counters()["peer_closed"] > closed)
    assert served.link.status()["peer"] == "closed"
    host = served.host()
    host.write(frame(IsReady(1)))
    rs = host.responses(1)
    assert rs[0].as_bool is True  # the answer to this frame: nothing stale, nothing misaligned
    assert host.nothing_within(0.1)
    c = served.counters()
    assert c["peer_reopened"] >= 1
    # The 4 bytes went with the hang-up, or before it by the gap rule (a slow test machine).
    assert (c["hangup_partial_bytes"], c["gap_discards"]) in ((4, 0), (0, 1))
    host.close()


def test_no_host_yet_then_host(served: LiveDaemon) -> None:
    served.until("the link to notice no host", lambda: served.link.peer_gone)
    time.sleep(0.1)
    host = served.host()
    host.write(frame(IsReady(0)))
    assert len(host.responses(1)) == 1
    host.close()


def test_wait_moved_woken_by_motor_event(served: LiveDaemon) -> None:
    host = served.host()
    host.write(frame(Move(0, True, 1, 0, 0)) + frame(WaitMoved(0, 60_000)) + frame(IsReady(1)))
    assert len(host.responses(1)) == 1
    served.until("the WaitMoved to be held", lambda: served.link.status()["waiting"])
    engine = served.daemon.engine
    with engine.lock:
        engine.motors[0].stop(hard=True, now=engine.clock.now())  # notifies: link.wake()
    t = time.monotonic()
    rs = host.responses(2)
    assert time.monotonic() - t < 5.0
    assert [r.ack for r in rs] == [True, True]
    host.close()


def test_wait_moved_times_out_on_the_link_clock(served: LiveDaemon) -> None:
    host = served.host()
    host.write(frame(Move(0, True, 1, 0, 0)) + frame(WaitMoved(0, 200)))
    rs = host.responses(2)
    assert rs[1].error_code is E.MOTOR_NOT_READY
    host.write(frame(StopMove(0, True)))
    assert host.responses(1)[0].ack
    host.close()


def test_stop_bounded_while_host_does_not_read(tmp_path: Path) -> None:
    s = LiveDaemon(tmp_path, drain_s=0.3)
    try:
        host = s.host()
        data = b"".join(frame(IsReady(0)) for _ in range(30_000))
        stop = threading.Event()
        writer = threading.Thread(target=host.write, args=(data, stop), daemon=True)
        writer.start()
        s.until("back pressure", lambda: s.counters()["backpressure"] > 0)
        assert s.stop() < 5.0
        assert s.counters()["responses_dropped"] > 0
        stop.set()
        writer.join(DEADLINE_S)
        host.close()
    finally:
        s.close()


def test_read_error_is_counted_and_survived(tmp_path: Path) -> None:
    # A directory polls readable and fails every read (EISDIR): the stand-in for a device
    # that errors. The thread must neither die nor spin, and stop() must still end it.
    fd = os.open(tmp_path, os.O_RDONLY)
    s = LiveDaemon(tmp_path, fd=fd, retry_s=0.01)
    try:
        s.until("the link error", lambda: s.counters()["link_errors"] == 1)
        time.sleep(0.1)
        assert s.thread.is_alive() and s.counters()["link_errors"] == 1
    finally:
        s.close()


def test_write_error_is_counted_and_survived(tmp_path: Path) -> None:
    ours, theirs = socket.socketpair()
    ours.setblocking(False)
    ours.shutdown(socket.SHUT_WR)  # every write now fails with EPIPE
    s = LiveDaemon(tmp_path, fd=ours.fileno())
    try:
        theirs.sendall(frame(IsReady(0)))
        s.until("the write error", lambda: s.counters()["link_errors"] == 1)
        assert s.thread.is_alive()
        # It looks again after retry_s, serves the next frame, and counts the next failure.
        s.until("the retry", lambda: s.counters()["peer_reopened"] >= 1)
        theirs.sendall(frame(IsReady(0)))
        s.until("the second write error", lambda: s.counters()["link_errors"] == 2)
        assert s.counters()["frames_good"] == 2 and s.thread.is_alive()
    finally:
        s.stop()
        s.link.close()
        ours.close()
        theirs.close()


def test_with_no_host_the_link_sleeps_holding_the_slave(served: LiveDaemon) -> None:
    """No host on the PTY: the link holds its slave side, so the master does not report a
    hang-up at every poll (the loop used to look every 20 ms, and a new host's first
    command waited for that look); it sleeps until a host writes. Nothing is an error."""
    served.until("no host", lambda: served.link.peer_gone)
    assert served.link.pty is not None and served.link.pty.held
    probe = select.poll()
    probe.register(served.fd, select.POLLIN)
    assert probe.poll(0) == []  # neither POLLHUP nor input
    turns = served.link.turns
    host = served.host()  # a host that opens the port and says nothing: no session yet
    try:
        assert host.nothing_within(0.2)
    finally:
        host.close()
    # asleep in poll() but for the host's open and close, not looking every 20 ms
    assert served.link.turns - turns <= 3
    c = served.counters()
    assert c["link_errors"] == 0 and c["peer_closed"] == 0  # no host yet: none closed


# -- a host's session ends: the next one reads only its own answers ---------------------------
def _three_motor_daemon(tmp_path: Path) -> LiveDaemon:
    """Motors on the real clock (a move takes its time), three of them and output pin 0."""
    return LiveDaemon(tmp_path, LIVE_CONFIG + '[[motors]]\nname = "c"\n', motion=True)


def test_a_host_that_closes_during_a_wait_leaves_nothing_to_the_next(tmp_path: Path) -> None:
    """Issue 22's scenario on a PTY: MoveTo 0 -> 6000 at 1000 step/s, WaitMoved(0, 30 s) and
    GetAbsPos(2), the port closed without reading the last two answers; the next host's
    IsReady(1) is answered at once (the motor still moving), with its own answer and
    nothing else. The two answers owed to the old session are dropped and counted; the
    motor goes on (the host left; it did not ask for a stop)."""
    s = _three_motor_daemon(tmp_path)
    try:
        old = s.host()
        old.write(frame(MoveTo(0, True, 6000, 250, 0, 0)))  # SPEED 250 x 4 = 1000 step/s
        assert old.responses(1)[0].ack
        old.write(frame(WaitMoved(0, 30_000), GetAbsPos(2)))
        s.until("the WaitMoved held, GetAbsPos kept", lambda: s.link.status()["held"] == 1)
        old.close()
        s.until("the session's end", lambda: s.counters()["peer_closed"] == 1)
        new = s.host()
        try:
            new.write(frame(IsReady(1)))
            assert new.responses(1) == [Response.boolean(True)]
            assert not s.daemon.engine.motors[0].idle  # answered long before the move ends
            new.write(frame(GetAbsPos(1)))  # in step: its own answer again
            assert new.responses(1) == [Response.position(0)]
            assert new.nothing_within(0.2)
        finally:
            new.close()
        c = s.counters()
        assert c["responses_dropped_wait"] == 1 and c["responses_dropped_held"] == 1
        assert c["responses_dropped_unsent"] == 0 and c["responses_dropped"] == 2
        assert c["held_discarded"] == 1  # GetAbsPos(2): never executed
        status = s.link.status()
        assert not status["waiting"] and status["held"] == 0
        results = {r["command"]: r["result"] for r in status["recent"]}  # type: ignore[attr-defined]
        assert results["WaitMoved(motor=0, timeout_ms=30000)"] == (
            "not sent: its host's session ended"
        )
    finally:
        s.close()


def test_kept_commands_of_a_host_that_left_are_not_executed_but_its_stop_is(
    tmp_path: Path,
) -> None:
    """Behind a held WaitMoved: SetPin (kept) and StopMove of motor 1 (executed on arrival).
    The host closes: the StopMove has stopped motor 1, the SetPin never runs (pin 0 stays
    low), the waited-for motor goes on; their answers are never sent."""
    s = _three_motor_daemon(tmp_path)
    try:
        old = s.host()
        old.write(frame(MoveTo(0, True, 6000, 250, 0, 0), Move(1, True, 1, 0, 0)))
        assert [r.ack for r in old.responses(2)] == [True, True]
        old.write(frame(WaitMoved(0, 30_000), SetPin(0, True), StopMove(1, True)))
        s.until("the StopMove kept", lambda: s.link.status()["held"] == 2)
        old.close()
        s.until("the session's end", lambda: s.counters()["peer_closed"] == 1)
        new = s.host()
        try:
            new.write(frame(GetPin(0), IsReady(1), IsReady(0)))
            assert [r.as_bool for r in new.responses(3)] == [False, True, False]
            assert new.nothing_within(0.2)
        finally:
            new.close()
        c = s.counters()
        assert c["held_discarded"] == 1  # the SetPin; the StopMove was executed
        assert c["responses_dropped_wait"] == 1 and c["responses_dropped_held"] == 2
        assert c["stops_while_held"] == 1
    finally:
        s.close()


def test_answers_the_old_host_did_not_read_are_flushed_and_counted(served: LiveDaemon) -> None:
    """Answers already written to the PTY and left unread: the kernel keeps them for the
    next host unless the daemon takes them; counted as unsent."""
    old = served.host()
    old.write(frame(IsReady(0), GetAbsPos(0), IsReady(1)))
    served.until("the answers written", lambda: served.counters()["responses"] == 3)
    old.close()
    served.until("the session's end", lambda: served.counters()["peer_closed"] == 1)
    new = served.host()
    try:
        new.write(frame(GetAbsPos(1)))
        assert new.responses(1) == [Response.position(0)]
        assert new.nothing_within(0.1)
    finally:
        new.close()
    c = served.counters()
    assert c["responses_dropped_unsent"] == 3 and c["responses_dropped"] == 3


def test_a_host_per_command_counts_in_the_processing_time(served: LiveDaemon) -> None:
    """Issue 27 item 7: a host that opens the port for each command (the motorctl CLI):
    each first read of a session is a read like any other; every one counts, the one-frame
    path's (a frame seen before) and the framer's alike."""
    for n in range(1, 6):
        host = served.host()
        try:
            host.write(frame(IsReady(n % 2)))
            assert len(host.responses(1)) == 1
        finally:
            host.close()
        served.until("the session's end", lambda n=n: served.counters()["peer_closed"] == n)
    processing = served.link.status()["processing"]
    assert isinstance(processing, dict) and processing["steps"] == 5
    assert served.counters()["peer_reopened"] == 5


def test_a_host_held_back_by_its_unread_answers_is_not_silent(tmp_path: Path) -> None:
    """[link] timeout_ms: the host writes on and does not read, the daemon holds back (it
    does not read while the answers are not taken): the host is not silent, however long
    (its bytes wait in the kernel). Once it reads, the daemon reads on; silence counts
    again only from when it listens, and is then acted on."""
    now = [0.0]
    acted: list[float] = []

    def act(t: float) -> list[str]:
        acted.append(t)
        return ["motor 0 (a)"]

    s = LiveDaemon(
        tmp_path, clock=lambda: now[0], watch=SilenceWatch(0.5, act, 0.0), backlog_limit=64
    )
    stop = threading.Event()
    host = s.host()
    writer = threading.Thread(
        target=host.write, args=(frame(*[IsReady(0)] * 20_000), stop), daemon=True
    )

    def at(t: float) -> None:
        """The link's clock at ``t``, seen by a whole turn of its loop."""
        now[0] = t
        for _ in range(2):
            turns = s.link.turns
            s.link.poke()
            s.until("a turn", lambda turns=turns: s.link.turns > turns)

    try:
        writer.start()
        s.until("back pressure", lambda: s.counters()["backpressure"] > 0)
        at(0.4)
        at(30.0)  # held back all along: not silence
        assert acted == []
        assert writer.is_alive()  # the host's bytes wait in the kernel
        assert all(r.as_bool for r in host.responses(20_000, timeout=60.0))
        writer.join(DEADLINE_S)
        assert not writer.is_alive()
        assert s.counters()["frames_good"] == 20_000
        at(30.4)
        assert acted == []
        at(31.0)  # now silent for 0.5 s while the daemon listened
        assert acted == [31.0]
    finally:
        stop.set()
        host.close()
        s.close()


def test_a_host_that_closes_and_opens_again_before_the_link_looks(tmp_path: Path) -> None:
    """The old host closes the port and a new one opens it while the link is busy (here:
    in the held WaitMoved's look, kept there by the test): the master never reports the
    hang-up (a host has the slave open again when the link polls). The slave's opens and
    closes tell it all the same: the new host's IsReady is answered at once, alone."""
    base = LiveDaemon(tmp_path / "a")
    base.close()
    gated = GatedPort(base.daemon.dispatcher)
    s = LiveDaemon(tmp_path, port=gated)
    try:
        old = s.host()
        old.write(frame(Move(0, True, 1, 0, 0), WaitMoved(0, 60_000), GetAbsPos(1)))
        assert old.responses(1)[0].ack
        s.until("the WaitMoved held, GetAbsPos kept", lambda: s.link.status()["held"] == 1)
        gated.gate.clear()
        s.link.wake()
        assert gated.entered.wait(DEADLINE_S), "the link never looked at its WaitMoved"
        old.close()  # and at once a new host: the link is busy meanwhile
        c = _new_host_while_busy(s, gated.gate)
        assert c["peer_closed"] == 1
        assert c["responses_dropped_wait"] == 1 and c["responses_dropped_held"] == 1
    finally:
        gated.gate.set()
        s.close()


@pytest.mark.parametrize("watched", [True, False], ids=["watched", "unwatched"])
def test_a_session_ends_with_its_host_whether_the_slave_is_watched_or_not(
    tmp_path: Path, watched: bool
) -> None:
    """The link holds the slave while no host has the port and lets go of it when a
    session begins; the master's hang-up says that the host closed it (the slave's watch
    also tells a reconnect that the master never reports). Either way the host's close
    ends its session, the answers it owed are dropped, and the next host reads only its
    own."""
    s = LiveDaemon(tmp_path, LIVE_CONFIG, motion=True, slave_watch=watched)
    try:
        assert s.link.pty is not None and (s.link.pty.events_fd is not None) is watched
        old = s.host()
        old.write(frame(MoveTo(0, True, 6000, 250, 0, 0)))
        assert old.responses(1)[0].ack
        assert not s.link.pty.held  # while the host has it
        old.write(frame(WaitMoved(0, 30_000), GetAbsPos(1)))
        s.until("the WaitMoved held, GetAbsPos kept", lambda: s.link.status()["held"] == 1)
        old.close()
        s.until("the session's end", lambda: s.counters()["peer_closed"] == 1)
        assert s.link.pty.held  # no host: held either way
        new = s.host()
        try:
            new.write(frame(IsReady(1)))
            assert new.responses(1) == [Response.boolean(True)]
            assert new.nothing_within(0.1)
            c = s.counters()  # while the new host is there (its close may be counted next)
        finally:
            new.close()
        assert c["peer_closed"] == 1 and c["responses_dropped"] == 2
        assert c["responses_dropped_wait"] == 1 and c["responses_dropped_held"] == 1
        s.until("the new host's close", lambda: s.counters()["peer_closed"] == 2)
    finally:
        s.close()


@pytest.mark.parametrize("watched", [True, False], ids=["watched", "unwatched"])
def test_a_frame_sent_just_before_the_close_is_its_hosts(tmp_path: Path, watched: bool) -> None:
    """A host that writes a command and closes the port at once, not waiting for its answer:
    the command is its session's, executed, and its answer dropped with the session and
    counted, however soon after it was written the session ended (the kernel moves it to
    the slave's input a moment after the write: the daemon reads it out, and a read waits
    for it); the next host reads only its own."""
    served = LiveDaemon(tmp_path, LIVE_CONFIG, slave_watch=watched)  # output pin 0
    try:
        _write_and_close(served)
    finally:
        served.close()


def _write_and_close(served: LiveDaemon) -> None:
    for n in range(1, 21):
        old = served.host()
        old.write(frame(SetPin(0, n % 2 == 1)))
        old.close()
        served.until("the session's end", lambda k=2 * n - 1: served.counters()["peer_closed"] == k)
        new = served.host()
        try:
            new.write(frame(GetPin(0)))  # the level the old host's SetPin left
            assert new.responses(1) == [Response.boolean(n % 2 == 1)]
            assert new.nothing_within(0.02)
        finally:
            new.close()
        served.until("the new host's close", lambda k=2 * n: served.counters()["peer_closed"] == k)
    c = served.counters()
    # the SetPin answers never reached anybody: dropped as unsent (left in the kernel, or
    # still owed when the close was seen)
    assert c["responses_dropped_unsent"] == 20 and c["responses_dropped"] == 20


def _new_host_while_busy(
    s: LiveDaemon, gate: threading.Event, answers: int | None = None
) -> dict[str, int]:
    """A new host opens the port and sends IsReady(1) while the link is kept busy (the old
    host has closed it); ``gate`` set, it must read its own answer and nothing else. The
    link's counters, read while the new host is still there (its own close, once made, may
    be counted at any moment). ``answers``: it reads only once the link has made that many
    (its own the last): what the old session left went before its answer was written (a
    host that reads before the link saw the close may find it: the race docs/protocol.md
    names, "When a host goes away")."""
    new = s.host()
    try:
        new.write(frame(IsReady(1)))
        gate.set()
        if answers is not None:
            s.until("the new host's answer", lambda: s.counters()["responses"] == answers)
        assert new.responses(1) == [Response.boolean(True)]
        assert new.nothing_within(0.1)
        return s.counters()
    finally:
        new.close()


def test_a_new_hosts_bytes_read_out_with_the_old_ones_are_its_own(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The link saw the old host's close and reads out what it left; a new host opens the
    port and writes between the slave's watch saying "no new host" and the read (made so
    here, in the watch's first answer): the read holds its frame, the watch says so after
    it, and the frame is the new session's, answered, not dropped with the old one's."""
    s = LiveDaemon(tmp_path)
    hosts: list[Host] = []
    real = session_end.read_out

    def read_out(master: int, reopened: Callable[[], bool]) -> tuple[bytes, bytes, bool]:
        def racing() -> bool:
            answer = reopened()
            if not hosts:  # the new host, just after the watch's first answer
                hosts.append(s.host())
                hosts[0].write(frame(IsReady(1)))
            return answer

        return real(master, racing)

    # what a status reader would see when the new host's bytes are taken (and answered)
    closes_seen: list[int] = []
    take = loop.Link._take

    def counted_take(link: loop.Link, data: bytes, now: float) -> None:
        if hosts and not closes_seen:
            closes_seen.append(link.counters["peer_closed"])
        take(link, data, now)

    try:
        old = s.host()
        old.write(frame(IsReady(0)))
        assert old.responses(1) == [Response.boolean(True)]
        monkeypatch.setattr(loop.Link, "_take", counted_take)
        monkeypatch.setattr(loop, "read_out", read_out)
        old.close()
        s.until("the new host", lambda: bool(hosts))
        assert hosts[0].responses(1) == [Response.boolean(True)]
        c = s.counters()
        assert c["peer_closed"] == 1 and c["unread_frames_dropped"] == 0
        assert closes_seen == [1], "the new host was answered before the close was counted"
    finally:
        for host in hosts:
            host.close()
        s.close()


class GatedRecorder:
    """A byte recorder (the link's trace hook, called on its thread) that keeps the link
    waiting on the first bytes it reads, once ``gate`` is cleared, for as long as the test
    needs."""

    def __init__(self) -> None:
        self.gate = threading.Event()
        self.gate.set()
        self.entered = threading.Event()

    def received(self, data: bytes, t: float) -> None:
        if not self.gate.is_set():
            self.entered.set()
            self.gate.wait(DEADLINE_S)

    def sent(self, data: bytes, t: float) -> None:
        pass


def _partial_frame_then_close(old: Host, gated: GatedRecorder) -> None:
    """Host ``old`` sends 4 bytes of a frame; the link reads them and is kept busy with
    them (``gated``) while ``old`` closes the port."""
    gated.gate.clear()
    old.write(frame(GetAbsPos(0))[:4])
    assert gated.entered.wait(DEADLINE_S), "the link never read the old host's bytes"
    old.close()  # and at once a new host, while the link is busy with the old bytes


def test_a_partial_frame_of_a_host_gone_before_the_link_looked_is_not_the_next_ones(
    tmp_path: Path,
) -> None:
    """A host's first bytes, 4 of a frame, are read; while the link is still busy with
    them, the host closes the port and a new host opens it and writes: the new host's bytes
    are a session of their own (the 4 bytes went with the old one), and its answer is its
    own. (The slave's watch tells it: without one, the master never says that the old host
    closed the port, docs/protocol.md.)"""
    gated = GatedRecorder()
    s = LiveDaemon(tmp_path, recorder=gated)
    try:
        _partial_frame_then_close(s.host(), gated)
        c = _new_host_while_busy(s, gated.gate)
        assert c["peer_closed"] == 1 and c["hangup_partial_bytes"] == 4
        assert c["frames"] == 1 and c["responses_dropped"] == 0
    finally:
        gated.gate.set()
        s.close()


def test_answers_left_unread_are_flushed_when_the_next_host_came_before_the_link_looked(
    tmp_path: Path,
) -> None:
    """A host's answers were written and it did not read them; then it sends 4 bytes of a
    frame and closes the port, and a new host opens it and writes while the link is still
    busy with those bytes (the master never reports the hang-up). The old answers are
    still read out of the slave's input, counted and flushed: the new host reads only its
    own. (A session that was written nothing has nothing there: the link does not look,
    test_a_partial_frame_of_a_host_gone_before_the_link_looked_is_not_the_next_ones.)"""
    gated = GatedRecorder()
    s = LiveDaemon(tmp_path, recorder=gated)
    try:
        old = s.host()
        old.write(frame(GetAbsPos(0), IsReady(0)))
        s.until("the answers written", lambda: s.counters()["responses"] == 2)
        _partial_frame_then_close(old, gated)
        c = _new_host_while_busy(s, gated.gate, answers=3)
        assert c["peer_closed"] == 1 and c["hangup_partial_bytes"] == 4
        assert c["responses_dropped_unsent"] == 2 and c["responses_dropped"] == 2
    finally:
        gated.gate.set()
        s.close()


def test_another_writer_that_closes_the_port_does_not_end_the_hosts_session(
    served: LiveDaemon,
) -> None:
    """The slave's watch says that a description opened for writing was closed, not whose:
    a second program that opens the port and closes it (``echo > PORT``) while the host
    has it does not end the host's session (the master reports no hang-up: the host still
    has the port). More such programs are opens after a close, as when a host reconnects
    (the session may end there: docs/protocol.md); the host's commands are answered
    throughout, and its own close ends its session."""
    host = served.host()
    assert served.link.pty is not None
    try:
        host.write(frame(IsReady(0)))
        assert host.responses(1) == [Response.boolean(True)]
        for n in range(3):
            other = os.open(served.name, os.O_WRONLY | os.O_NOCTTY)
            os.close(other)
            host.write(frame(GetAbsPos(0)))
            assert host.responses(1) == [Response.position(0)]
            assert host.nothing_within(0.02)
            if n == 0:  # the close alone (the watch's news taken with the bytes)
                assert served.counters()["peer_closed"] == 0
        closed = served.counters()["peer_closed"]
    finally:
        host.close()
    served.until("the host's close", lambda: served.counters()["peer_closed"] == closed + 1)
    assert served.link.status()["peer"] == "closed"
