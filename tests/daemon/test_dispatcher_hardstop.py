"""A hard StopMove is answered once the executor confirmed the stop (docs/protocol.md,
StopMove): the deadline, the skip after a timeout, executor death, and that the thread
executor on a virtual clock (which confirms at once) is unchanged.

The executor here is the real thread step executor behind ``SlowToConfirm``
(tests/support/stalls.py), which
holds back its STOPPED confirmations (a stalled executor) or dies on cue: the motor really
stops, only the confirmation is late or never comes.
"""

from __future__ import annotations

import logging
import os
import select
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from motorctl.daemon.link.loop import Link
from motorctl.daemon.link.ports import open_pty
from motorctl.hal.backends.mock.world import world_of
from motorctl.hal.interfaces import MonotonicClock, VirtualClock
from motorctl.motion.executors.base import (
    STOP_CONFIRM_S,
    ExecEventKind,
    from_ticks,
    to_ticks,
)
from motorctl.motion.types import MotorState
from motorctl.protocol.codec import (
    ErrorCode,
    InitMove,
    IsReady,
    Move,
    StopMove,
)
from tests.support.frames import OPTS, answers, frame
from tests.support.inprocess import IN_PROCESS_CONFIG, build_daemon
from tests.support.stalls import StallRig, stall_rig
from tests.support.wait import until

E = ErrorCode
K = ExecEventKind
DEADLINE_S = 20.0  # for conditions that take milliseconds, on a loaded 2-core machine


def moving(rig: StallRig, motor: int = 0) -> None:
    assert rig.send(Move(motor, True, 1, 0, 0)).ack
    rig.run(0.2)
    assert rig.position(motor) > 0 and not rig.ready(motor)


# ------------------------------------------------------------------ a virtual clock
def test_never_confirmed_answers_at_the_deadline_not_never(
    caplog: pytest.LogCaptureFixture,
) -> None:
    rig = stall_rig(VirtualClock(), delay_s=None)
    moving(rig)
    t0 = rig.clock.now()
    with caplog.at_level(logging.WARNING, "motorctl.dispatcher"):
        assert rig.send(StopMove(0, True)).ack
    assert rig.clock.now() - t0 == pytest.approx(STOP_CONFIRM_S, abs=1e-9)
    assert "did not confirm the hard stop within 50 ms" in caplog.text
    assert rig.engine.stop_waits["timed_out"] == 1
    # the stop is on its way: IsReady tells the truth (0) until it is confirmed
    assert not rig.ready()
    stopped_at = rig.position()
    rig.run(0.1)
    assert rig.position() == stopped_at  # the motor really stopped; only the answer waited
    # A burst of hard stops to the stalled executor waits once, not once each.
    t1 = rig.clock.now()
    assert rig.send(StopMove(0, True)).ack and rig.send(StopMove(0, True)).ack
    assert rig.clock.now() == t1
    assert rig.engine.stop_waits["skipped"] == 2
    # It runs again: the confirmation comes, the motor is ready, and waits resume.
    rig.ex.release()
    assert rig.ready() and rig.position() == stopped_at
    moving(rig)
    t2 = rig.clock.now()
    assert rig.send(StopMove(0, True)).ack
    assert rig.clock.now() - t2 == pytest.approx(STOP_CONFIRM_S, abs=1e-9)
    assert rig.engine.stop_waits["timed_out"] == 2


def test_confirmed_late_answers_at_the_confirmation_and_ready_at_once() -> None:
    rig = stall_rig(VirtualClock(), delay_s=0.003)
    moving(rig)
    t0 = rig.clock.now()
    assert rig.send(StopMove(0, True)).ack
    assert rig.clock.now() - t0 == pytest.approx(0.003, abs=1e-6)
    assert rig.ready()  # the confirmation was processed before the answer
    stopped_at = rig.position()
    rig.run(0.1)
    assert rig.position() == stopped_at
    assert rig.engine.stop_waits["confirmed"] == 1


def test_the_other_motor_goes_on_while_the_answer_waits() -> None:
    rig = stall_rig(VirtualClock(), delay_s=0.02)
    moving(rig, 1)
    moving(rig, 0)
    before = rig.position(1)
    assert rig.send(StopMove(0, True)).ack
    assert rig.position(1) > before + 20  # ~20 ms at >= 2,000 step/s
    assert not rig.ready(1) and rig.ready(0)


def test_executor_dying_while_the_answer_waits_gives_e4() -> None:
    rig = stall_rig(VirtualClock(), delay_s=None)
    moving(rig)
    rig.ex.dies_at = from_ticks(to_ticks(rig.clock.now() + 0.01))
    t0 = rig.clock.now()
    assert rig.send(StopMove(0, True)).error_code is E.MOTOR_ERROR
    assert rig.clock.now() - t0 == pytest.approx(0.01, abs=1e-6)
    assert rig.engine.stop_waits["died"] == 1
    # every motor faulted; a StopMove cannot clear it while the executor is dead
    for m in (0, 1):
        assert rig.send(IsReady(m)).error_code is E.MOTOR_ERROR
        assert rig.send(StopMove(m, True)).error_code is E.MOTOR_ERROR
        assert rig.send(StopMove(m, False)).error_code is E.MOTOR_ERROR


def test_hard_stop_of_a_homing_motor_waits_too() -> None:
    rig = stall_rig(VirtualClock(), delay_s=0.004)
    assert rig.send(InitMove(0, False, 1, 0, 0)).ack  # towards the end stop far below
    rig.run(0.1)
    assert rig.engine.motors[0].state is MotorState.HOMING
    t0 = rig.clock.now()
    assert rig.send(StopMove(0, True)).ack
    assert rig.clock.now() - t0 == pytest.approx(0.004, abs=1e-6)
    assert rig.ready()  # idle, not homed: the position stays where it stopped
    stopped_at = rig.position()
    rig.run(0.1)
    assert rig.position() == stopped_at


def test_stop_move_clearing_a_fault_whose_stop_is_unconfirmed_waits_for_it() -> None:
    """A driver fault stops the motor hard; a StopMove that clears the fault before that
    stop was confirmed answers once it is, so IsReady right after answers 1."""
    rig = stall_rig(VirtualClock(), delay_s=0.04)
    moving(rig)
    world = world_of(rig.hw)
    world.inject_fault(0, "over-temperature")
    rig.run(0.03)  # a driver poll (every 10 ms) latches it; its stop is confirmed 40 ms later
    m = rig.engine.motors[0]
    assert m.fault is not None and m.stopping
    assert rig.send(StopMove(0, False)).error_code is E.MOTOR_ERROR  # still hot: no wait
    world.inject_fault(0, None)
    t0 = rig.clock.now()
    assert rig.send(StopMove(0, False)).ack  # cleared; answered at the confirmation
    assert 0 < rig.clock.now() - t0 < STOP_CONFIRM_S
    assert rig.engine.stop_waits["confirmed"] == 1
    assert rig.ready()


def test_a_fault_latched_while_the_stop_is_confirmed_answers_e4() -> None:
    rig = stall_rig(VirtualClock(), delay_s=0.03)
    moving(rig)
    world_of(rig.hw).inject_fault(0, "over-temperature")  # the next poll (10 ms) latches it
    assert rig.send(StopMove(0, True)).error_code is E.MOTOR_ERROR
    assert rig.engine.motors[0].fault == "driver fault: over-temperature"
    assert rig.send(IsReady(0)).error_code is E.MOTOR_ERROR


def test_soft_stop_and_idle_stop_do_not_wait() -> None:
    rig = stall_rig(VirtualClock(), delay_s=None)
    t0 = rig.clock.now()
    assert rig.send(StopMove(0, True)).ack and rig.clock.now() == t0  # idle: just ACK
    moving(rig)
    t1 = rig.clock.now()
    assert rig.send(StopMove(0, False)).ack and rig.clock.now() == t1
    assert not rig.ready()  # decelerating along its ramp, as before
    rig.engine.run_until_idle()
    assert rig.ready()
    assert sum(rig.engine.stop_waits.values()) == 0


def test_thread_executor_on_a_virtual_clock_confirms_at_once(tmp_path: Path) -> None:
    """The executor the virtual-clock tests use answers stop() with the position: nothing
    waits, virtual time does not move, IsReady is 1 at once (unchanged behaviour)."""
    clock = VirtualClock()
    d = build_daemon(IN_PROCESS_CONFIG, tmp_path, clock)
    assert d.dispatcher.handle(Move(0, True, 1, 0, 0)).ack
    d.engine.run_until(clock.now() + 0.2)
    t0 = clock.now()
    assert d.dispatcher.handle(StopMove(0, True)).ack
    assert clock.now() == t0
    assert d.dispatcher.handle(IsReady(0)).as_bool
    assert sum(d.engine.stop_waits.values()) == 0


# ------------------------------------------------------------------ a real clock
def start_real(stop_confirm_s: float = STOP_CONFIRM_S) -> StallRig:
    """A real clock, the thread executor's thread and the engine's threads running."""
    rig = stall_rig(MonotonicClock(), delay_s=None, stop_confirm_s=stop_confirm_s)
    rig.ex.start()
    rig.engine.start()
    return rig


def close_real(rig: StallRig) -> None:
    rig.engine.stop_threads()
    rig.ex.close()
    rig.hw.close()


@pytest.fixture
def real() -> Iterator[StallRig]:
    rig = start_real()
    yield rig
    close_real(rig)


@pytest.fixture
def patient() -> Iterator[StallRig]:
    """A deadline that a 20 ms confirmation meets however loaded the machine is."""
    rig = start_real(DEADLINE_S)
    yield rig
    close_real(rig)


def real_moving(rig: StallRig, motor: int = 0) -> None:
    assert rig.send(Move(motor, True, 1, 0, 0)).ack
    until(f"motor {motor} moving", lambda: rig.position(motor) > 20)


def test_real_clock_never_confirmed_answers_after_the_deadline(real: StallRig) -> None:
    real_moving(real)
    t0 = time.monotonic()
    assert real.send(StopMove(0, True)).ack
    took = time.monotonic() - t0
    assert STOP_CONFIRM_S <= took < STOP_CONFIRM_S + DEADLINE_S
    assert not real.ready()
    real.ex.release()  # from this thread: the planner processes it
    until("the late confirmation", real.ready)


def test_real_clock_woken_by_the_confirmation_from_another_thread(patient: StallRig) -> None:
    real = patient
    real_moving(real)
    timer = threading.Timer(0.02, real.ex.release)  # the executor's event thread, as it were
    t0 = time.monotonic()
    timer.start()
    try:
        assert real.send(StopMove(0, True)).ack
    finally:
        timer.join()
    took = time.monotonic() - t0
    assert real.ready()
    assert real.engine.stop_waits["confirmed"] == 1, dict(real.engine.stop_waits)
    assert 0.02 <= took < DEADLINE_S


def test_link_with_a_stalled_executor_answers_a_burst_and_notices_shutdown(tmp_path: Path) -> None:
    """100 hard StopMoves in one write to a stalled executor: the first waits the deadline,
    the rest are answered at once, and a stop of the link ends it promptly (without the skip
    it would take 100 x 0.2 s)."""
    rig = start_real(0.2)
    fd, name = open_pty(tmp_path / "pty")
    link = Link(fd, rig.dispatcher, OPTS, 0.010, 16)
    thread = threading.Thread(target=link.serve, name="link", daemon=True)
    host = os.open(name, os.O_RDWR | os.O_NOCTTY)
    try:
        thread.start()
        real_moving(rig)
        burst = frame(StopMove(0, True)) * 100
        os.write(host, burst)
        until("the burst read", lambda: link.session.counters["bytes_in"] == len(burst))
        t0 = time.monotonic()
        link.stop()
        thread.join(DEADLINE_S)
        took = time.monotonic() - t0
        assert not thread.is_alive(), "the link did not notice the stop"
        assert took < 10.0, took
        data = b""
        while len(data) < 500 and select.select([host], [], [], 5.0)[0]:
            data += os.read(host, 500 - len(data))
        got = answers(data)
        assert len(got) == 100 and all(a.ack for a in got)
        assert rig.engine.stop_waits["timed_out"] == 1
        assert rig.engine.stop_waits["skipped"] == 99
    finally:
        os.close(host)
        link.close()
        os.close(fd)
        close_real(rig)
