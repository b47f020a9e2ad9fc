"""The dispatcher in-process on a virtual clock: precedence of PROTOCOL.md §5, unit conversion."""

from __future__ import annotations

from pathlib import Path

import pytest

from motorctl.daemon.dispatcher import Dispatcher, Wait
from motorctl.daemon.start.assemble import Daemon
from motorctl.hal.backends.mock.world import world_of
from motorctl.hal.interfaces import BridgeState
from motorctl.protocol.codec import (
    COMMANDS,
    ConfigPin,
    DcMove,
    ErrorCode,
    GetPin,
    GoHome,
    InitMove,
    IsReady,
    Move,
    MoveTo,
    MoveToWayPoint,
    Response,
    SaveHome,
    SaveWayPoint,
    SetPin,
    StopMove,
    WaitMoved,
)
from tests.support.inprocess import build_daemon

E = ErrorCode

CONFIG = """
[units]
run_speed_factor = 1000.0
[dc]
[[motors]]
name = "a"
max_speed = 3000.0
max_accel = 50000.0
max_waypoints = 1
soft_limit_min = -100
soft_limit_max = 100
queue_depth = 1
[[motors]]
name = "b"
max_speed = 3000.0
[[pins]]
number = 0
[[pins]]
number = 1
mode = "input"
"""


@pytest.fixture
def d(tmp_path: Path) -> Daemon:
    return build_daemon(CONFIG, tmp_path)


def code(r: Response | Wait) -> ErrorCode | None:
    assert isinstance(r, Response)
    return r.error_code


def test_e2_before_everything(d: Daemon) -> None:
    for cmd in (
        MoveTo(2, True, 999, 0, 0, 0),
        IsReady(9),
        SaveWayPoint(2),
        MoveToWayPoint(2, 7, 0, 0, 0),
        SetPin(5, True),
        GetPin(2),
        ConfigPin(9, True),
    ):
        assert code(d.dispatcher.handle(cmd)) is E.INVALID_ADDRESS
    assert code(d.dispatcher.wait_begin(WaitMoved(3, 10), 0.0)) is E.INVALID_ADDRESS


def test_parameter_e1_before_fault_e4(d: Daemon) -> None:
    m = d.engine.motors[0]
    with d.engine.lock:
        m.latch_fault("test", 0.0)
    assert code(d.dispatcher.handle(MoveTo(0, True, 101, 0, 0, 0))) is E.INVALID_COMMAND
    assert code(d.dispatcher.handle(MoveTo(0, True, 100, 0, 0, 0))) is E.MOTOR_ERROR


def test_e6_before_e4_and_e1_for_waypoints(d: Daemon) -> None:
    m = d.engine.motors[0]
    with d.engine.lock:
        m.latch_fault("test", 0.0)
    assert code(d.dispatcher.handle(MoveToWayPoint(0, 0, 0, 0, 0))) is E.INVALID_WAYPOINT
    with d.engine.lock:
        m.waypoints.append(500)  # a waypoint beyond today's soft limits
    assert code(d.dispatcher.handle(MoveToWayPoint(0, 0, 0, 0, 0))) is E.INVALID_COMMAND


def test_e4_before_e3_before_e5(d: Daemon) -> None:
    assert d.dispatcher.handle(SaveWayPoint(0)).payload[0] == 0  # table (1) now full
    assert d.dispatcher.handle(Move(0, True, 1, 0, 0)).ack
    assert code(d.dispatcher.handle(SaveWayPoint(0))) is E.MOTOR_NOT_READY  # E3 before E5
    with d.engine.lock:
        d.engine.motors[0].latch_fault("test", 0.0)
    assert code(d.dispatcher.handle(SaveWayPoint(0))) is E.MOTOR_ERROR  # E4 before E3
    assert code(d.dispatcher.handle(SaveHome(0))) is E.MOTOR_ERROR
    assert code(d.dispatcher.handle(IsReady(0))) is E.MOTOR_ERROR


def test_e4_before_e0(d: Daemon) -> None:
    assert d.dispatcher.handle(Move(0, True, 1, 0, 0)).ack
    assert d.dispatcher.handle(MoveTo(0, True, 0, 0, 0, 0)).ack  # queue depth 1: full now
    assert code(d.dispatcher.handle(MoveTo(0, True, 0, 0, 0, 0))) is E.FULL_BUFFER
    d.engine.motors[0].position_lost = True
    assert code(d.dispatcher.handle(MoveTo(0, True, 0, 0, 0, 0))) is E.MOTOR_ERROR
    assert code(d.dispatcher.handle(GoHome(0))) is E.MOTOR_ERROR
    assert code(d.dispatcher.handle(InitMove(0, True, 0, 0, 0))) is E.FULL_BUFFER  # allowed


def test_units_defaults_and_clamping(d: Daemon) -> None:
    assert d.dispatcher.handle(Move(1, True, 2, 250, 0)).ack  # 2 x 1000 step/s, 250 x 16
    m = d.engine.motors[1]
    assert m.traj is not None
    d.engine.run_until(d.clock.now() + 0.6)  # 2000 / 4000 = 0.5 s of ramp
    assert m.traj.velocity(d.clock.now()) == pytest.approx(2000.0)
    assert d.dispatcher.handle(Move(1, True, 9, 0, 0)).ack  # 9000 > max_speed 3000
    assert d.dispatcher.clamped["speed"] == 1
    d.engine.run_until(d.clock.now() + 1.0)  # default accel 8000: 1000 more in 0.125 s
    assert m.traj.velocity(d.clock.now()) == pytest.approx(3000.0)


def test_a_handler_for_each_command_of_the_table(d: Daemon) -> None:
    """The command table's commands, each to the method it names (WaitMoved: the link's),
    with the unit factors the table names for its SPEED, ACC and DEC ([units])."""
    table = d.dispatcher.table
    assert (
        set(table) == {c for c in COMMANDS if c.spec.answer.held == ""} and WaitMoved not in table
    )
    assert {cls: getattr(h, "__name__", "") for cls, h in table.items()} == {
        cls: cls.spec.handler for cls in table
    }
    factors = d.dispatcher.factors
    assert set(factors) == {InitMove, MoveTo, Move, MoveToWayPoint}
    assert factors[Move] == factors[InitMove] == (1000.0, 16.0, 16.0)  # run_speed_factor here
    assert factors[MoveTo] == factors[MoveToWayPoint] == (4.0, 16.0, 16.0)


def test_a_command_without_its_handler_stops_the_start(d: Daemon) -> None:
    class Missing(Dispatcher):
        dc_move = None  # type: ignore[assignment]

    with pytest.raises(TypeError, match=r"no handler for DcMove: Dispatcher\.dc_move"):
        Missing(d.config, d.engine, d.dispatcher.pins)


def test_stop_clears_fault_only_when_driver_is_healthy(d: Daemon) -> None:
    world = world_of(d.hw)
    world.inject_fault(0, "over-temperature")
    d.engine.run_until(d.clock.now() + 0.05)  # a driver poll latches it
    assert code(d.dispatcher.handle(IsReady(0))) is E.MOTOR_ERROR
    assert code(d.dispatcher.handle(StopMove(0, False))) is E.MOTOR_ERROR
    world.inject_fault(0, None)
    assert d.dispatcher.handle(StopMove(0, False)).ack
    assert d.dispatcher.handle(IsReady(0)).as_bool


def test_pins_and_dc(d: Daemon) -> None:
    assert code(d.dispatcher.handle(SetPin(1, True))) is E.INVALID_COMMAND
    assert d.dispatcher.handle(ConfigPin(1, True)).ack
    assert d.dispatcher.handle(SetPin(1, True)).ack
    assert d.dispatcher.handle(GetPin(1)).as_bool
    assert d.dispatcher.handle(DcMove(True, 250, False)).ack
    bridge = d.hw.dc
    assert bridge is not None
    states = [bridge.state]
    d.engine.run_until(d.clock.now() + 0.3)
    states.append(bridge.state)
    assert states == [BridgeState.FORWARD, BridgeState.BRAKE]
    assert d.dispatcher.handle(DcMove(False, 0, True)).ack
    assert bridge.state.value == "coast"


def test_wait_moved_answers(d: Daemon) -> None:
    assert d.dispatcher.wait_begin(WaitMoved(0, 100), d.clock.now()) == Response.ok()
    assert d.dispatcher.handle(MoveTo(0, True, 50, 0, 0, 0)).ack
    assert code(d.dispatcher.wait_begin(WaitMoved(0, 0), d.clock.now())) is E.MOTOR_NOT_READY
    w = d.dispatcher.wait_begin(WaitMoved(0, 10_000), d.clock.now())
    assert isinstance(w, Wait)
    assert d.dispatcher.wait_poll(w, d.clock.now()) is None
    d.engine.run_until_idle()
    assert d.dispatcher.wait_poll(w, d.clock.now()) == Response.ok()
