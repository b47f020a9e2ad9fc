"""motorctld as a real process on a PTY with a chain of three dSPIN chips (an L6470, an L6480,
a powerSTEP01) on the mock backend, driven by the client over pyserial: MoveTo, Move and
StopMove, InitMove (zero where the switch releases), GetAbsPos while moving, an end stop
outside homing (E4), and the chips in the status document."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from motorctl.client.client import Client, DeviceError
from motorctl.protocol.codec import ErrorCode
from tests.support import REPO
from tests.support.daemon_proc import DaemonProcess, StartDaemon, positions_until_ready

CONFIG = """\
[drivers]
poll_ms = 5.0

[[motors]]
name = "x"
  [motors.mock]
  endstop_min = -2000
  [motors.dspin]
  driver = "l6470"
  spi = "/dev/spidev0.0"
  microsteps = 16

[[motors]]
name = "y"
  [motors.dspin]
  driver = "l6480"
  spi = "/dev/spidev0.0"
  position = 1

[[motors]]
name = "z"
  [motors.homing]
  max_travel = 20000
  [motors.mock]
  endstop_min = -3000
  [motors.dspin]
  driver = "powerstep01"
  spi = "/dev/spidev0.0"
  position = 2
  microsteps = 8
"""


@pytest.fixture
def daemon(motorctld: StartDaemon) -> DaemonProcess:
    return motorctld(CONFIG)


def until_past(c: Client, motor: int, position: int, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while c.position(motor) < position:
        assert time.monotonic() < deadline, f"motor {motor} not past {position} in {timeout_s} s"
        time.sleep(0.02)


def test_moves_stops_and_homing_on_a_dspin_chain(daemon: DaemonProcess) -> None:
    with daemon.client() as c:
        with pytest.raises(DeviceError) as e:
            c.move_to(0, 2**21, speed=250)  # beyond ABS_POS's 22 bits: refused, nothing moves
        assert e.value.code is ErrorCode.INVALID_COMMAND
        c.move_to(0, 1000, speed=250)  # 1 s at 1000 step/s (SPEED's byte allows 1020 at most)
        seen = positions_until_ready(c, 0)
        assert c.position(0) == 1000
        assert any(0 < p < 1000 for p in seen)  # GetAbsPos while the chip moves it
        c.move(1, True, speed=1)  # Run at 4096 step/s
        until_past(c, 1, 500)
        assert not c.is_ready(1)
        c.stop(1)  # soft: along DEC
        c.wait_moved(1, timeout_ms=10_000)
        stopped = c.position(1)
        assert stopped > 500 and c.is_ready(1)
        c.move(1, False, speed=1)
        assert not c.is_ready(1)
        c.stop(1, hard=True)
        c.wait_moved(1, timeout_ms=10_000)
        assert c.is_ready(1)
        c.init_move(2, False, speed=2)  # GoUntil down, then ReleaseSW: zero at the release
        c.wait_moved(2, timeout_ms=20_000)
        assert c.position(2) == 0
        c.move_to(2, 400, speed=250)
        c.wait_moved(2, timeout_ms=10_000)
        assert c.position(2) == 400
        c.init_move(2, False, speed=2)  # again from 400: the same zero
        c.wait_moved(2, timeout_ms=20_000)
        assert c.position(2) == 0
        c.move(0, False, speed=1)  # down into motor x's end stop at -2000, not homing: E4
        deadline = time.monotonic() + 10.0
        while True:
            try:
                c.wait_moved(0, timeout_ms=500)
            except DeviceError as exc:
                if exc.code is ErrorCode.MOTOR_ERROR:
                    break
                assert exc.code is ErrorCode.MOTOR_NOT_READY  # still on its way
            assert time.monotonic() < deadline, "no E4 within 10 s"
        assert -2100 < c.position(0) < -1900
    drivers = daemon.status()["drivers"]
    assert [(d["chip"], d["device"], d["chain_position"]) for d in drivers] == [
        ("L6470", "/dev/spidev0.0", 0),
        ("L6480", "/dev/spidev0.0", 1),
        ("powerSTEP01 (voltage mode)", "/dev/spidev0.0", 2),
    ]
    assert all(d["polls"] > 0 for d in drivers)


def test_the_client_names_abs_pos_s_range_when_a_target_is_beyond_it(
    motorctld: StartDaemon, tmp_path: Path
) -> None:
    # the daemon's reason, read by `motorctl` from the status socket beside the port (as
    # `make run` lays it out), says what refused the target: not the soft limits
    d = motorctld(CONFIG, state_dir=tmp_path / ".run" / "state")
    out = subprocess.run(
        [sys.executable, "-m", "motorctl.client.cli", "-p", str(d.pty), "moveto", "0", "2097152"],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=REPO,
        env={**os.environ, "MOTORCTL_STATE_DIR": ""},
    )
    assert (out.returncode, out.stdout) == (1, "")
    assert out.stderr.strip() == (
        "error: E1 invalid command: target 2097152 is outside what the motor's driver chip "
        "counts from its zero: -2097152..2097151 (motor 0)"
    )
