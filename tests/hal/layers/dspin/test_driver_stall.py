"""Stall homing on a dSPIN chip (``homing.source = "stall"``, driver.py): InitMove runs
towards the mock axis's hard stop (``[motors.mock] endstop_min``, ``switches = false``),
where the chip model loses steps and latches STEP_LOSS_A (its stall detection); the driver
stops the chip and reports the stall, the motor zeroes where it stalled (docs/protocol.md's
homing rule, with its second approach when ``pull_off`` asks for one). Outside homing the
same stall is a fault (E4). A daemon on a virtual clock, the host's bytes through a session."""

from __future__ import annotations

from pathlib import Path

import pytest

from motorctl.hal.backends.mock.dspin_world import MockChain
from motorctl.hal.backends.mock.world import world_of
from motorctl.hal.layers.dspin.driver import DspinDriver
from motorctl.protocol.codec import ErrorCode, GetAbsPos, InitMove, IsReady, MoveTo
from tests.support.sessions import SessionRig

#: the hard stop (where the axis stalls), counted from where the axis starts
STOP = -1500

CONFIG = f"""\
[[motors]]
name = "x"
  [motors.homing]
  source = "stall"
  speed = 400
  pull_off = {{pull_off}}
  second_speed = 200
  max_travel = 40000
  [motors.mock]
  endstop_min = {STOP}
  switches = false
  [motors.dspin]
  driver = "{{driver}}"
  spi = "/dev/spidev0.0"
  microsteps = 16
  switch = "none"
"""


def rig_of(tmp: Path, pull_off: int = 0, driver: str = "l6470") -> SessionRig:
    rig = SessionRig(tmp, CONFIG.format(pull_off=pull_off, driver=driver))
    rig.run(0.1)
    return rig


def chain_of(rig: SessionRig) -> MockChain:
    nodes = world_of(rig.daemon.hw).spi_nodes
    assert nodes is not None
    return nodes.chains[(0, 0)]


def until_ready(rig: SessionRig, limit_s: float = 30.0) -> None:
    for _ in range(round(limit_s / 0.05)):
        answer = rig.call(IsReady(0))
        assert answer.error_code is None, rig.daemon.engine.motors[0].fault
        if answer.as_bool:
            return
        rig.run(0.05)
    raise AssertionError(f"not ready within {limit_s} s of the virtual clock")


@pytest.mark.parametrize("driver", ["l6470", "l6480"])
@pytest.mark.parametrize("pull_off", [0, 300])
def test_init_move_stops_where_the_chip_stalls_and_zeroes_there(
    tmp_path: Path, pull_off: int, driver: str
) -> None:
    rig = rig_of(tmp_path, pull_off, driver)
    chain = chain_of(rig)
    axis, chip = chain.members[0].axis, chain.members[0].chip
    assert rig.call(InitMove(0, False, 0, 0, 0)).error_code is None
    until_ready(rig)
    driver_ = rig.daemon.hw.steppers[0].driver
    assert isinstance(driver_, DspinDriver)
    assert axis.position == STOP  # against the hard stop: where it stalled
    assert rig.call(GetAbsPos(0)).as_position == 0  # zero there
    assert not driver_.fault_counts  # the stall was the homing's, not a fault
    assert driver_.stats()["chip"] == chip.chip.name
    # the homing is done: a move away is a move, and back to 0 ends at the stop again
    assert rig.call(MoveTo(0, True, 800, 100, 100, 100)).error_code is None
    until_ready(rig)
    assert axis.position == STOP + 800 and rig.call(GetAbsPos(0)).as_position == 800


def test_outside_homing_the_stall_is_a_fault(tmp_path: Path) -> None:
    rig = rig_of(tmp_path)
    assert rig.call(MoveTo(0, True, -4000, 100, 100, 100)).error_code is None
    answer = None
    for _ in range(400):
        rig.run(0.05)
        answer = rig.call(IsReady(0)).error_code
        if answer is not None:
            break
    assert answer is ErrorCode.MOTOR_ERROR
    fault = rig.daemon.engine.motors[0].fault or ""
    assert "STEP_LOSS_A" in fault, fault
