"""``[link] timeout_ms``: the host's silence stops the motors (docs/protocol.md, "When the host
falls silent"), on a virtual clock.

The daemon's parts are the real ones (dispatcher, engine, the thread step executor on a
virtual clock, the link session, the watch as the daemon builds it); a
``SessionRig`` (tests/support/sessions.py) plays the link loop's part: bytes in at a
time, and the time passing in small steps.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from motorctl.daemon.link.silence import SilenceWatch, check_timeout, min_timeout_ms
from motorctl.hal.interfaces import BridgeState, DcBridge
from motorctl.motion.motor import Motor
from motorctl.motion.types import MotorState
from motorctl.protocol.codec import (
    DcMove,
    ErrorCode,
    GetAbsPos,
    IsReady,
    Move,
    MoveTo,
    Response,
    StopMove,
    WaitMoved,
)
from motorctl.protocol.crc import SMBUS
from tests.support.frames import frame
from tests.support.inprocess import IN_PROCESS_CONFIG
from tests.support.sessions import SessionRig

E = ErrorCode


def line_rig(tmp: Path, link: str = "") -> SessionRig:
    """Two motors, a DC motor and the ``[link]`` table ``link``."""
    return SessionRig(tmp, IN_PROCESS_CONFIG + "[dc]\n" + link)


def state(m: Motor) -> MotorState:
    """A motor's state, read afresh (a plain attribute read would be narrowed by mypy)."""
    return m.state


def bridge_state(bridge: DcBridge) -> BridgeState:
    return bridge.state


def e4(resp: Response) -> bool:
    return resp.error_code is E.MOTOR_ERROR


@pytest.fixture
def line(tmp_path: Path) -> SessionRig:
    return line_rig(tmp_path, "[link]\ntimeout_ms = 200\n")


def test_off_by_default(tmp_path: Path) -> None:
    line = line_rig(tmp_path)
    link = line.daemon.config.link
    assert (link.timeout_ms, link.timeout_action) == (0.0, "decelerate")
    assert not line.watch.enabled
    assert line.call(Move(0, True, 0, 0, 0)).ack
    line.quiet(3.0)
    assert state(line.motors[0]) is MotorState.RUNNING and line.motors[0].fault is None
    assert line.watch.deadline() is None and line.timeouts() == 0


def test_silence_decelerates_the_moving_motors_and_latches_e4(line: SessionRig) -> None:
    assert line.call(Move(0, True, 0, 0, 0)).ack
    line.poll_host(1.0)  # the host polls, then falls silent
    assert line.call(IsReady(0)) == Response.boolean(False)
    line.quiet(0.195)
    m, idle = line.motors
    assert state(m) is MotorState.RUNNING and m.fault is None
    line.quiet(0.010)
    assert m.fault == "link timeout: no byte from the host for 200 ms"
    assert m.faults == {"link_timeout": 1} and m.fault_cause == "link_timeout"
    assert state(m) is MotorState.STOPPING  # along its ramp: decelerate is the default
    at_fault = m.position
    for cmd in (
        IsReady(0),
        WaitMoved(0, 1000),
        Move(0, True, 0, 0, 0),
        MoveTo(0, True, 0, 0, 0, 0),
    ):
        assert e4(line.call(cmd)), cmd
    line.quiet(1.0)
    assert state(m) is MotorState.FAULT and m.fault is not None
    assert m.position > at_fault + 50  # it ramped down (2000 step/s at 8000 step/s^2)
    assert not m.position_lost
    assert line.call(GetAbsPos(0)) == Response.position(m.position)
    # the motor at rest was not touched; the silence acted once
    assert state(idle) is MotorState.IDLE and idle.fault is None
    assert line.call(IsReady(1)) == Response.boolean(True)
    line.quiet(2.0)
    assert line.timeouts() == 1 and line.watch.counters["link_timeout_stops"] == 1


def test_stop_move_clears_it_and_the_next_silence_acts_again(line: SessionRig) -> None:
    assert line.call(Move(0, True, 0, 0, 0)).ack
    line.quiet(2.0)
    m = line.motors[0]
    assert state(m) is MotorState.FAULT
    assert line.call(StopMove(0, False)).ack
    assert m.fault is None and line.call(IsReady(0)) == Response.boolean(True)
    assert line.call(Move(0, False, 0, 0, 0)).ack  # moves again
    line.quiet(0.15)
    assert state(m) is MotorState.RUNNING
    line.quiet(1.0)
    assert state(m) is MotorState.FAULT and line.timeouts() == 2


def test_any_bytes_keep_the_link_alive(line: SessionRig) -> None:
    """Good frames, frames that fail their checks, partial frames: all are signs of life."""
    assert line.call(Move(0, True, 0, 0, 0)).ack
    good = frame(GetAbsPos(0))
    bad_crc = good[:9] + bytes([good[9] ^ 0xFF])
    unknown = bytes([0x7F]) + bytes(8)
    unknown += bytes([SMBUS.compute(unknown)])
    for data in [bad_crc, unknown, good[:3], bad_crc, good[:7], unknown] * 3:
        line.quiet(0.15)
        line.ask(data)
    assert state(line.motors[0]) is MotorState.RUNNING and line.timeouts() == 0
    c = line.session.counters
    assert (c["checksum_errors"], c["unknown_errors"], c["gap_discards"]) == (6, 6, 6)
    line.quiet(0.21)
    assert line.motors[0].fault is not None and line.timeouts() == 1


def test_a_stop_move_while_it_ramps_down_clears_it_and_takes_the_stop_over(
    line: SessionRig,
) -> None:
    assert line.call(Move(0, True, 0, 0, 0)).ack
    line.poll_host(1.0)
    line.quiet(0.21)
    m = line.motors[0]
    assert state(m) is MotorState.STOPPING and m.fault is not None
    assert line.call(StopMove(0, True)).ack  # hard: answered once it has stopped
    assert m.fault is None and state(m) is MotorState.IDLE
    assert line.call(IsReady(0)) == Response.boolean(True)


def test_hard_stops_at_once(tmp_path: Path) -> None:
    line = line_rig(tmp_path, '[link]\ntimeout_ms = 200\ntimeout_action = "hard"\n')
    assert line.call(Move(0, True, 0, 0, 0)).ack
    line.poll_host(1.0)
    line.quiet(0.21)
    m = line.motors[0]
    assert state(m) is MotorState.FAULT and m.fault is not None
    assert m.faults == {"link_timeout": 1}
    line.quiet(0.005)
    stopped_at = m.position
    line.quiet(1.0)
    assert m.position == stopped_at
    assert e4(line.call(IsReady(0)))
    assert line.call(StopMove(0, False)).ack and line.call(IsReady(0)).as_bool


def test_a_held_wait_moved_is_not_silence_and_its_answer_restarts_it(line: SessionRig) -> None:
    """The host waits for the answer; from the answer on, its silence counts again, and
    a frame kept behind the WaitMoved that starts a motor is stopped after it."""
    data = (
        frame(MoveTo(0, True, 2000, 0, 0, 0))
        + frame(WaitMoved(0, 10000))
        + frame(Move(1, True, 0, 0, 0))
    )
    assert [r.ack for r in line.ask(data)] == [True]  # MoveTo; the rest is held
    answers = line.quiet(0.6)
    assert answers == [] and state(line.motors[0]) is MotorState.MOVING  # > 200 ms: held
    answers = line.quiet_until_answered()  # 2000 steps at 2000 step/s: ~1.25 s in all
    assert [r.ack for r in answers] == [True, True]  # WaitMoved, then the kept Move
    assert state(line.motors[0]) is MotorState.IDLE and line.motors[0].fault is None
    assert state(line.motors[1]) is MotorState.RUNNING
    line.quiet(0.25)
    assert line.motors[1].fault is not None  # the silence since the answer
    assert line.motors[0].fault is None  # at rest: untouched
    assert line.timeouts() == 1


def test_the_dc_motor_brakes_and_idle_silence_does_nothing(line: SessionRig) -> None:
    line.quiet(5.0)  # nothing moves: silence does nothing
    assert line.timeouts() == 0
    assert line.call(DcMove(True, 5000, True)).ack
    bridge = line.daemon.hw.dc
    assert bridge is not None and bridge_state(bridge) is BridgeState.FORWARD
    line.quiet(0.25)
    assert bridge_state(bridge) is BridgeState.BRAKE and line.timeouts() == 1
    assert line.call(DcMove(True, 100, True)).ack  # no fault to clear for the DC motor


# -- the gap's rule: only silence the daemon listened to --------------------------------------
def test_time_the_daemon_does_not_read_is_not_silence() -> None:
    """Back pressure: while the daemon does not read, no byte can reach it; that time does
    not count, the silence before it does."""
    acted: list[float] = []

    def act(t: float) -> list[str]:
        acted.append(t)
        return ["motor 0 (a)"]

    watch = SilenceWatch(1.0, act, 0.0)
    watch.listening(True, 0.0)
    watch.listening(False, 0.4)  # 0.4 s of silence, then it stops reading
    assert watch.deadline() is None
    assert not watch.check(100.0)  # however long it holds back
    watch.listening(True, 100.0)
    assert watch.deadline() == pytest.approx(100.6)  # the 0.4 s before still count
    assert not watch.check(100.55)
    assert watch.check(100.6) and acted == [100.6]


def test_a_timeout_shorter_than_a_frame_is_refused_naming_the_minimum() -> None:
    assert min_timeout_ms(115200) == pytest.approx(0.868, abs=1e-3)
    why = check_timeout(0.5, 115200)
    assert why is not None and "[link] timeout_ms = 0.5" in why and "0.868 ms" in why
    assert check_timeout(0.9, 115200) is None and check_timeout(0, 9600) is None
    why = check_timeout(5, 9600)  # 10.4 ms a frame at 9600 baud
    assert why is not None and "at least 10.4 ms" in why


def test_the_timeout_is_logged_as_configured(caplog: pytest.LogCaptureFixture) -> None:
    watch = SilenceWatch(0.0015, lambda t: ["motor 0 (a)"], 0.0)
    with caplog.at_level("WARNING", "motorctl.link"):
        assert watch.check(0.002)
    assert "[link] timeout_ms = 1.5," in caplog.text  # not rounded to 2 (or 0.5 to 0)


def test_check_config_refuses_a_timeout_below_a_frame(tmp_path: Path) -> None:
    config = tmp_path / "short.toml"
    config.write_text('[link]\ntimeout_ms = 0.5\n[[motors]]\nname = "a"\n')
    out = subprocess.run(
        [sys.executable, "-m", "motorctl.daemon.start.main", "--check-config", str(config)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 1 and "0.868 ms" in out.stderr and "Traceback" not in out.stderr
    slow = subprocess.run(
        [
            sys.executable,
            "-m",
            "motorctl.daemon.start.main",
            "--check-config",
            str(config),
            "--baud",
            "9600",
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert slow.returncode == 1 and "at 9600 baud" in slow.stderr
    config.write_text('[link]\ntimeout_ms = 0.5\n[[motors]]\nname = "a"\n')
    state = tmp_path / "state"
    start = subprocess.run(
        [
            sys.executable,
            "-m",
            "motorctl.daemon.start.main",
            "--config",
            str(config),
            "--pty",
            str(tmp_path / "pty"),
            "--state-dir",
            str(state),
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert start.returncode == 1 and "0.868 ms" in start.stderr, start.stderr
    assert not (state / "state.json").exists()  # refused before anything was written
