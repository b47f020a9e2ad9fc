"""Faults injected at the HAL of a live daemon (thread executor, link on a real PTY, in-process):
each must end in a latched fault or a clear error code, never a dead thread or a wrong ACK."""

from __future__ import annotations

import errno
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from motorctl.daemon.config import parse_config
from motorctl.daemon.link import Link, flush_pty_input
from motorctl.daemon.main import Daemon, open_pty
from motorctl.hal.interfaces import MonotonicClock
from motorctl.hal.mock import MockWorld, world_of
from motorctl.protocol.codec import (
    CodecOptions,
    Command,
    ErrorCode,
    GetAbsPos,
    IsReady,
    Move,
    MoveTo,
    Response,
    SetPin,
    StopMove,
    WaitMoved,
    encode_command,
)
from tests.daemon.test_link import Host
from tests.support.daemon_proc import IN_PROCESS_CONFIG, until

E = ErrorCode
OPTS = CodecOptions()

CONFIG = IN_PROCESS_CONFIG + """
[[pins]]
number = 0
mode = "output"
"""


class Live:
    def __init__(self, tmp: Path) -> None:
        clock = MonotonicClock()
        config = parse_config(CONFIG, "t.toml")  # best-effort step timing
        self.daemon = Daemon.build(config, tmp / "state", clock)
        self.world: MockWorld = world_of(self.daemon.hw)
        self.fd, name = open_pty(tmp / "pty")
        self.link = Link(self.fd, self.daemon.dispatcher, OPTS, 0.010, 16,
                         on_hangup=lambda: flush_pty_input(name))
        self.daemon.link = self.link
        self.link_thread = threading.Thread(target=self.link.serve, daemon=True)
        self.daemon.engine.executor.start()
        self.daemon.engine.start()
        self.link_thread.start()
        self.host = Host(name)

    def ask(self, *cmds: Command) -> list[Response]:
        self.host.write(b"".join(encode_command(c, OPTS) for c in cmds))
        return self.host.responses(len(cmds))

    def code(self, cmd: Command) -> ErrorCode | None:
        return self.ask(cmd)[0].error_code

    def alive(self) -> bool:
        engine = self.daemon.engine
        alive = engine.threads_alive and engine.executor.health().alive
        return alive and self.link_thread.is_alive()

    def close(self) -> None:
        self.host.close()
        self.link.stop()
        self.link_thread.join(20)
        self.daemon.engine.stop_threads()
        self.daemon.engine.executor.close()
        self.link.close()
        import os

        os.close(self.fd)


@pytest.fixture
def live(tmp_path: Path) -> Iterator[Live]:
    lv = Live(tmp_path)
    yield lv
    assert lv.alive(), "a daemon thread died"
    lv.close()


def moving(live: Live, motor: int) -> None:
    assert live.code(Move(motor, True, 1, 0, 0)) is None
    until(f"motor {motor} moving", lambda: live.ask(GetAbsPos(motor))[0].as_position > 0)


def test_step_line_that_raises_latches_a_fault(live: Live) -> None:
    moving(live, 0)
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
    # it failed at 4096 step/s, above the start speed: the position is lost, homing is due
    assert live.daemon.status()["motors"][0]["position_lost"]
    assert live.code(MoveTo(0, True, 10, 0, 0, 0)) is E.MOTOR_ERROR
    assert live.daemon.engine.hardware_errors >= 1


def test_dir_line_that_raises_on_a_new_move(live: Live) -> None:
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


def test_driver_fault_mid_move(live: Live) -> None:
    moving(live, 0)
    live.world.inject_fault(0, "overtemperature")
    assert live.code(WaitMoved(0, 20_000)) is E.MOTOR_ERROR
    stopped = live.ask(GetAbsPos(0))[0].as_position
    time.sleep(0.05)
    assert live.ask(GetAbsPos(0))[0].as_position == stopped  # stopped at once, stays
    assert live.code(StopMove(0, True)) is E.MOTOR_ERROR  # the driver still reports it
    live.world.inject_fault(0, None)
    assert live.code(StopMove(0, True)) is None
    assert live.code(IsReady(0)) is None


def test_pin_write_that_raises_is_e4_not_ack(live: Live) -> None:
    live.world.inject_line_error("pin", 0, OSError(errno.EIO, "gpio chip gone"))
    rs = live.ask(SetPin(0, True), IsReady(0))
    assert rs[0].error_code is E.MOTOR_ERROR
    assert rs[1].ack
    live.world.inject_line_error("pin", 0, None)
    assert live.code(SetPin(0, True)) is None
    assert live.daemon.dispatcher.hardware_errors == 1
