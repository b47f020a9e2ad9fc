"""What was reported before a command is acted on before it is answered: the dispatcher's
look before each command (``MotionEngine.catch_up``: the driver poller's queue and
``Executor.events_waiting``) finds every report published before it, whatever the
executor. The planner thread is not started here, so the dispatcher is the reports' only
consumer: a report it missed would leave the command's answer as if nothing happened."""

from __future__ import annotations

import signal
from collections.abc import Iterator
from pathlib import Path

import pytest

from motorctl.daemon.start.assemble import Daemon
from motorctl.hal.backends.mock.world import world_of
from motorctl.hal.interfaces import MonotonicClock
from motorctl.motion.executors.base import ExecEvent, ExecEventKind
from motorctl.motion.executors.process.parent import ProcessStepExecutor
from motorctl.motion.executors.process.rings import event_fields
from motorctl.motion.executors.thread import ThreadStepExecutor
from motorctl.protocol.codec import ErrorCode, IsReady, Response
from tests.support.executors import show_slot, slot_bytes
from tests.support.inprocess import IN_PROCESS_CONFIG, TWO_MOTORS, build_daemon
from tests.support.wait import until

E = ErrorCode
TRUE = Response.boolean(True)


def fault_of(motor: int, detail: str) -> ExecEvent:
    return ExecEvent(ExecEventKind.FAULT, motor, 0, 0, 0.0, detail=detail)


@pytest.fixture
def process_daemon(tmp_path: Path) -> Iterator[Daemon]:
    """The daemon's default executor (a step core in a process of its own), started; no
    planner thread."""
    daemon = build_daemon(TWO_MOTORS, tmp_path / "state", MonotonicClock())
    assert isinstance(daemon.engine.executor, ProcessStepExecutor)
    daemon.engine.executor.start()
    yield daemon
    daemon.engine.executor.close()
    daemon.hw.close()


def test_a_report_in_the_process_executors_ring_answers_the_next_command(
    process_daemon: Daemon,
) -> None:
    d, ex = process_daemon.dispatcher, process_daemon.engine.executor
    assert isinstance(ex, ProcessStepExecutor)
    assert d.handle(IsReady(0)) == TRUE and not ex.events_waiting()
    # as the child publishes a report (it is idle: this is the ring's only producer now)
    assert ex.shared.events.put(*event_fields(fault_of(0, "test: the line failed")))
    assert d.handle(IsReady(0)).error_code is E.MOTOR_ERROR
    motors = process_daemon.engine.motors
    assert motors[0].fault is not None and "test: the line failed" in motors[0].fault
    assert motors[1].fault is None and d.handle(IsReady(1)) == TRUE


def test_a_report_announced_before_it_is_whole_answers_the_command_after_it_is(
    process_daemon: Daemon,
) -> None:
    """A weakly ordered CPU may show the ring's head before the record's bytes: the command
    then answers as before the report (``get`` takes it later, as it always did), and the
    next command, once the record is whole, sees it: the look never settles for the head."""
    d, ex = process_daemon.dispatcher, process_daemon.engine.executor
    assert isinstance(ex, ProcessStepExecutor)
    ring = ex.shared.events
    index = ring.cells[0]
    whole = slot_bytes(ring, index, event_fields(fault_of(1, "test: torn, then whole")))
    at = ring.base + (index % ring.cap) * ring.slot
    old = bytes(ring.buf[at : at + ring.slot])
    show_slot(ring, index, whole[:8] + old[8:])  # the sequence number new, the rest old
    assert ex.events_waiting()
    assert d.handle(IsReady(1)) == TRUE  # not taken torn
    assert ex.events_waiting()  # still announced: looked at again by the next command
    show_slot(ring, index, whole)
    assert d.handle(IsReady(1)).error_code is E.MOTOR_ERROR


def test_the_executors_death_answers_the_next_command(process_daemon: Daemon) -> None:
    d, ex = process_daemon.dispatcher, process_daemon.engine.executor
    assert isinstance(ex, ProcessStepExecutor)
    assert d.handle(IsReady(0)) == TRUE
    ex.kill_for_test(signal.SIGKILL)
    until("the event thread's word of the death", lambda: ex.died is not None)
    assert ex.events_waiting()
    assert d.handle(IsReady(0)).error_code is E.MOTOR_ERROR
    assert process_daemon.engine.executor_died == ex.died
    assert all(m.position_lost for m in process_daemon.engine.motors)
    assert not ex.events_waiting()  # DIED is reported once


def test_a_report_of_the_thread_executor_and_a_drivers_answer_the_next_command(
    tmp_path: Path,
) -> None:
    """The thread executor's deque, and the driver poller's queue (a fault it read)."""
    daemon = build_daemon(IN_PROCESS_CONFIG, tmp_path / "state")  # a virtual clock
    d, engine = daemon.dispatcher, daemon.engine
    ex = engine.executor
    assert isinstance(ex, ThreadStepExecutor)
    assert d.handle(IsReady(0)) == TRUE and not ex.events_waiting()
    ex._emit(fault_of(0, "test: the thread's report"))  # as its step thread reports
    assert ex.events_waiting()
    assert d.handle(IsReady(0)).error_code is E.MOTOR_ERROR
    assert d.handle(IsReady(1)) == TRUE
    world_of(daemon.hw).inject_fault(1, "short")
    engine.poller.poll_due(engine.clock.now() + 1.0)  # the poller's pass: it reads, queues
    assert d.handle(IsReady(1)).error_code is E.MOTOR_ERROR
    assert engine.motors[1].fault is not None and "short" in engine.motors[1].fault
