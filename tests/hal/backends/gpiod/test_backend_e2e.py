"""motorctld with the gpiod backend and a TMC5160 that runs its own ramp, wired without any
STEP/DIR line: it starts, moves end to end on the chip model and stops, opening no GPIO line.

The daemon imports ``gpiod`` and ``spidev`` as on a Raspberry Pi: tests/fakegpiod/ stands in
for libgpiod's binding and refuses every line request (so any line opened for the ramp
motor would stop the daemon), tests/fakespi/ for py-spidev with the register-level TMC5160
model of tests/support/tmc_model.py behind it.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.support.daemon_proc import DaemonProcess, StartDaemon, positions_until_ready, run_probe
from tests.support.stand_ins import stand_in_env

RAMP_ONLY = """\
[hal]
backend = "gpiod"

[[motors]]
name = "r"
  [motors.homing]
  max_travel = 20000
  [motors.tmc]
  driver = "tmc5160"
  spi = "/dev/spidev0.0"
  mode = "ramp"
  run_current = 2.0
  hold_current = 1.0
"""

STEP_DIR_WITHOUT_STEP = (
    RAMP_ONLY
    + """
[[motors]]
name = "s"
  [motors.gpiod]
  dir = "gpiochip0:6"
  [motors.tmc]
  driver = "tmc2130"
  spi = "/dev/spidev0.1"
"""
)


@pytest.fixture
def env() -> dict[str, str]:
    return stand_in_env("gpiod", "spidev", chips={"0.0": "tmc5160"})


@pytest.fixture
def daemon(motorctld: StartDaemon, env: dict[str, str]) -> DaemonProcess:
    return motorctld(RAMP_ONLY, env=env, kill_at_end=True)


def test_a_ramp_motor_without_step_dir_lines_moves_end_to_end(daemon: DaemonProcess) -> None:
    with daemon.client() as c:
        c.move_to(0, 800, speed=255)  # XTARGET on the chip; its ramp makes the steps
        seen = positions_until_ready(c, 0)  # 1,020 step/s: 0.8 s, a look every 50 ms
        assert c.position(0) == 800
        assert any(0 < p < 800 for p in seen)  # GetAbsPos follows XACTUAL while moving
        c.move_to(0, -200, speed=255)
        c.wait_moved(0, timeout_ms=10_000)
        assert c.position(0) == -200
    status = daemon.status()
    executor = status["executor"]
    assert executor["alive"] and (executor["kind"], executor["pid"]) == ("none", None)
    assert status["motors"][0]["position"] == -200
    assert daemon.terminate() == 0
    assert "fakegpiod" not in daemon.stderr()  # no line was ever asked for


def test_probe_of_a_ramp_motor_without_lines_opens_none(
    tmp_path: Path, env: dict[str, str]
) -> None:
    config = tmp_path / "ramp.toml"
    config.write_text(RAMP_ONLY)
    out = run_probe(config, env=env)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "r: /dev/spidev0.0: TMC5160" in out.stdout
    assert "all 0 lines requested" in out.stdout and "PROBLEM" not in out.stdout


def test_a_step_dir_motor_without_step_stops_the_daemon_naming_motor_and_key(
    tmp_path: Path, env: dict[str, str]
) -> None:
    with pytest.raises(RuntimeError) as e:
        DaemonProcess(tmp_path, STEP_DIR_WITHOUT_STEP, env=env).start()
    msg = str(e.value)
    assert "motors[1].gpiod.step" in msg and "motor 1 ('s')" in msg
    assert "STEP line" in msg and "Traceback" not in msg
