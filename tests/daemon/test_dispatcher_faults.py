"""What the dispatcher answers when the HAL fails (daemon/dispatcher.py): faults injected at
the HAL of a live daemon (thread executor, link on a real PTY, in-process) each end in a
latched fault or a clear error code, never a dead thread or a wrong ACK."""

from __future__ import annotations

import errno
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from motorctl.protocol.codec import (
    ErrorCode,
    GetAbsPos,
    IsReady,
    MoveTo,
    SetPin,
    StopMove,
    WaitMoved,
)
from tests.support.inprocess import LIVE_CONFIG, LiveDaemon
from tests.support.wait import until

E = ErrorCode


@pytest.fixture
def live(tmp_path: Path) -> Iterator[LiveDaemon]:
    lv = LiveDaemon(tmp_path, LIVE_CONFIG, motion=True)
    yield lv
    assert lv.alive(), "a daemon thread died"
    lv.close()


def test_step_line_that_raises_latches_a_fault(live: LiveDaemon) -> None:
    live.moving(0)
    start_speed = live.daemon.engine.motors[0].params.start_speed
    # past its start speed before the line fails (its first steps may be below it)
    until(
        "motor 0 above its start speed",
        lambda: live.daemon.status()["motors"][0]["speed"] > start_speed,
    )
    live.world.inject_line_error("step", 0, OSError(errno.EIO, "gpio chip gone"))
    assert live.code(WaitMoved(0, 20_000)) is E.MOTOR_ERROR
    assert live.alive()
    fault = live.daemon.status()["motors"][0]["fault"]
    assert fault is not None and "hardware error" in fault
    assert live.code(IsReady(0)) is E.MOTOR_ERROR
    assert live.code(MoveTo(0, True, 0, 0, 0, 0)) is E.MOTOR_ERROR
    assert live.code(IsReady(1)) is None  # the other motor is unaffected
    live.world.inject_line_error("step", 0, None)
    assert live.code(StopMove(0, True)) is None  # the driver reports nothing: cleared
    # it failed above the start speed: the position is lost, homing is due
    assert live.daemon.status()["motors"][0]["position_lost"]
    assert live.code(MoveTo(0, True, 10, 0, 0, 0)) is E.MOTOR_ERROR
    assert live.daemon.engine.hardware_errors >= 1


def test_dir_line_that_raises_on_a_new_move(live: LiveDaemon) -> None:
    live.world.inject_line_error("dir", 1, OSError(errno.EIO, "gpio chip gone"))
    # The executor writes DIR ahead of the first step: the failure is latched there and
    # the next answer about the motor says so.
    assert live.code(MoveTo(1, True, 100, 0, 0, 0)) in (None, E.MOTOR_ERROR)
    assert live.code(WaitMoved(1, 20_000)) is E.MOTOR_ERROR
    assert live.code(StopMove(1, False)) is None  # the driver reports nothing: cleared
    assert not live.daemon.status()["motors"][1]["position_lost"]  # it never stepped
    assert live.code(MoveTo(1, True, 100, 0, 0, 0)) in (None, E.MOTOR_ERROR)  # still fails
    assert live.code(WaitMoved(1, 20_000)) is E.MOTOR_ERROR
    live.world.inject_line_error("dir", 1, None)
    assert live.code(StopMove(1, False)) is None
    assert live.code(MoveTo(1, True, 100, 0, 0, 0)) is None
    assert live.code(WaitMoved(1, 20_000)) is None
    assert live.ask(GetAbsPos(1))[0].as_position == 100


def test_driver_fault_mid_move(live: LiveDaemon) -> None:
    live.moving(0)
    live.world.inject_fault(0, "overtemperature")
    assert live.code(WaitMoved(0, 20_000)) is E.MOTOR_ERROR
    stopped = live.ask(GetAbsPos(0))[0].as_position
    time.sleep(0.05)
    assert live.ask(GetAbsPos(0))[0].as_position == stopped  # stopped at once, stays
    assert live.code(StopMove(0, True)) is E.MOTOR_ERROR  # the driver still reports it
    live.world.inject_fault(0, None)
    assert live.code(StopMove(0, True)) is None
    assert live.code(IsReady(0)) is None


def test_pin_write_that_raises_is_e4_not_ack(live: LiveDaemon) -> None:
    live.world.inject_line_error("pin", 0, OSError(errno.EIO, "gpio chip gone"))
    rs = live.ask(SetPin(0, True), IsReady(0))
    assert rs[0].error_code is E.MOTOR_ERROR
    assert rs[1].ack
    live.world.inject_line_error("pin", 0, None)
    assert live.code(SetPin(0, True)) is None
    assert live.daemon.dispatcher.hardware_errors == 1
