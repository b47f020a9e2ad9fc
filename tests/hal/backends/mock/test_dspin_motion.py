"""The mock dSPIN's motion profile (dspin_motion.py, run by dspin_chip.py) against the
datasheet's: the trapezoid of a GoTo from its registers, Run's BUSY, SoftStop and HardStop,
GoUntil stopping at the switch and resetting ABS_POS, ReleaseSW leaving it at the low speed.

Full steps, ACC = DEC = 0x08A (2008.2 step/s^2), MAX_SPEED = 0x041 (991.8 step/s), MIN_SPEED
0 (the reset values): a GoTo of 3000 steps accelerates for 0.4939 s over 244.9 steps,
cruises 2510.1 steps for 2.5308 s and decelerates like it accelerated: 3.5186 s in all."""

from __future__ import annotations

import math

import pytest

from motorctl.hal.backends.mock.dspin_chip import DspinChip
from motorctl.hal.dspin import commands as c
from motorctl.hal.dspin import scales
from motorctl.hal.dspin.chips import L6470, L6480, Chip
from motorctl.hal.dspin.commands import Op
from motorctl.hal.dspin.status import MotorState, Status
from tests.hal.backends.mock.test_dspin_chip import ask, configure, get_status, reg, send

ACC = float(scales.ACC.value(0x08A))
VMAX = float(scales.MAX_SPEED.value(0x041))
T_ACC = VMAX / ACC
D_ACC = VMAX**2 / (2 * ACC)


def ready(model: Chip = L6470, sw_user: bool = False) -> DspinChip:
    chip = DspinChip(model, switch=lambda shaft: shaft <= -500)
    configure(chip)
    if sw_user:
        config = model.config
        send(chip, c.set_param(config, config.field("SW_MODE").put(config.reset or 0, 1)).encode())
    return chip


def state(chip: DspinChip) -> Status:
    return chip.chip.status.decode(ask(chip, c.get_param(chip.chip.status_register)))


def speed(chip: DspinChip) -> float:
    return float(scales.SPEED.value(reg(chip, "SPEED")))


def test_a_goto_runs_the_datasheet_s_trapezoid() -> None:
    assert pytest.approx(0.4939, abs=1e-4) == T_ACC and pytest.approx(244.9, abs=0.1) == D_ACC
    total = 2 * T_ACC + (3000 - 2 * D_ACC) / VMAX
    chip = ready()
    send(chip, c.go_to(3000).encode())
    chip.advance(0.25)
    s = state(chip)
    assert s.busy and s.motor is MotorState.ACCELERATION and s.forward
    assert speed(chip) == pytest.approx(ACC * 0.25, rel=0.01)
    assert reg(chip, "ABS_POS") == pytest.approx(ACC * 0.25**2 / 2, abs=2)
    chip.advance(1.25)  # t = 1.5: cruising at MAX_SPEED
    assert state(chip).motor is MotorState.CONSTANT_SPEED
    assert reg(chip, "SPEED") == 0x041 << 10  # MAX_SPEED's 0.18 in SPEED's 0.28
    assert reg(chip, "ABS_POS") == pytest.approx(D_ACC + (1.5 - T_ACC) * VMAX, abs=3)
    chip.advance(total - 0.25 - 1.5)  # t = total - 0.25: decelerating
    assert state(chip).motor is MotorState.DECELERATION
    assert speed(chip) == pytest.approx(ACC * 0.25, rel=0.05)
    chip.advance(0.2)
    assert chip.busy and reg(chip, "ABS_POS") < 3000
    chip.advance(0.1)
    s = state(chip)
    assert not s.busy and s.motor is MotorState.STOPPED and not s.hiz
    assert reg(chip, "ABS_POS") == 3000 and reg(chip, "SPEED") == 0


def test_a_short_goto_is_a_triangle() -> None:
    chip = ready()
    send(chip, c.go_to(-100).encode())
    peak = 0.0
    for _ in range(100):
        chip.advance(0.005)
        peak = max(peak, speed(chip))
    assert not chip.busy and reg(chip, "ABS_POS") == (-100) & 0x3FFFFF
    assert peak == pytest.approx(math.sqrt(ACC * 100), rel=0.05) and peak < VMAX


def test_run_holds_busy_until_its_speed_and_reverses_through_a_stop() -> None:
    chip = ready()
    spd = scales.SPEED.floor(scales.SPEED.lsb * 13421)  # 200 step/s
    send(chip, c.run(c.FORWARD, spd).encode())
    chip.advance(0.05)
    assert chip.busy and state(chip).motor is MotorState.ACCELERATION
    chip.advance(0.1)  # 200 / 2008 = 0.0996 s to the speed
    assert not chip.busy and state(chip).motor is MotorState.CONSTANT_SPEED
    assert reg(chip, "SPEED") == spd
    send(chip, c.run(c.REVERSE, spd).encode())
    chip.advance(0.05)
    assert state(chip).forward and state(chip).motor is MotorState.DECELERATION
    chip.advance(0.2)
    assert not state(chip).forward and not chip.busy
    too_fast = scales.SPEED.hi
    send(chip, c.run(c.FORWARD, too_fast).encode())  # capped at MAX_SPEED
    chip.advance(1)
    assert speed(chip) == pytest.approx(VMAX)


def test_softstop_decelerates_and_hardstop_stops_at_once() -> None:
    chip = ready()
    send(chip, c.run(c.FORWARD, scales.SPEED.hi).encode())
    chip.advance(1)
    start = reg(chip, "ABS_POS")
    send(chip, c.simple(Op.SOFT_STOP).encode())
    chip.advance(T_ACC - 0.05)
    assert chip.busy and state(chip).motor is MotorState.DECELERATION
    chip.advance(0.1)
    assert not chip.busy and reg(chip, "SPEED") == 0
    assert reg(chip, "ABS_POS") - start == pytest.approx(D_ACC, abs=3)
    send(chip, c.run(c.FORWARD, scales.SPEED.hi).encode())
    chip.advance(1)
    send(chip, c.simple(Op.HARD_STOP).encode())
    stopped_at = reg(chip, "ABS_POS")
    assert not chip.busy and reg(chip, "SPEED") == 0
    chip.advance(1)
    assert reg(chip, "ABS_POS") == stopped_at and not state(chip).hiz


def test_softhiz_ends_in_hiz_and_hardhiz_at_once() -> None:
    chip = ready()
    send(chip, c.run(c.FORWARD, scales.SPEED.hi).encode())
    chip.advance(1)
    send(chip, c.simple(Op.SOFT_HIZ).encode())
    chip.advance(0.1)
    assert not state(chip).hiz and chip.busy
    chip.advance(1)
    assert state(chip).hiz and not chip.busy
    send(chip, c.simple(Op.SOFT_STOP).encode())  # out of HiZ, no motion
    assert not state(chip).hiz and chip.motion.stopped
    send(chip, c.run(c.FORWARD, 100).encode())
    send(chip, c.simple(Op.HARD_HIZ).encode())
    assert state(chip).hiz and chip.motion.stopped


@pytest.mark.parametrize("model", [L6470, L6480])
def test_gountil_stops_at_the_switch_and_releasesw_zeroes_where_it_opens(model: Chip) -> None:
    chip = ready(model, sw_user=True)  # SW_MODE = 1: GoUntil ends in a SoftStop
    send(chip, c.set_param(model.registers["ABS_POS"], 1234).encode())
    spd = 13421  # 200 step/s
    send(chip, c.go_until(c.RESET_ABS_POS, c.REVERSE, spd).encode())
    chip.advance(1)
    assert chip.busy
    chip.advance(2)  # 500 steps at 200 step/s: 2.5 s, then 10 steps of SoftStop
    s = state(chip)
    assert not s.busy and s.switch_closed and s.switch_event
    overshoot = 200**2 / (2 * ACC)  # 9.96 steps past the switch, counted from 0
    assert model.registers["ABS_POS"].value(reg(chip, "ABS_POS")) == pytest.approx(
        -overshoot, abs=1.5
    )
    get_status(chip)
    send(chip, c.release_sw(c.RESET_ABS_POS, c.FORWARD).encode())
    chip.advance(0.5)
    assert chip.busy and state(chip).switch_closed
    assert speed(chip) == pytest.approx(5, abs=0.02)  # MIN_SPEED 0: 5 step/s
    chip.advance(2.5)
    s = state(chip)
    assert not s.busy and not s.switch_closed and not s.switch_event
    assert reg(chip, "ABS_POS") == 0 and chip.shaft == -499  # zero where it opened


def test_with_sw_mode_0_the_switch_hard_stops() -> None:
    chip = ready()  # SW_MODE = 0 at reset
    send(chip, c.go_until(c.COPY_TO_MARK, c.REVERSE, 13421).encode())
    chip.advance(3)
    assert chip.shaft == -500 and not chip.busy  # stopped on the switch
    assert L6470.registers["MARK"].value(reg(chip, "MARK")) == -500  # ACT 1: copied
    assert L6470.registers["ABS_POS"].value(reg(chip, "ABS_POS")) == -500
    # a Run into the switch stops there too, latching SW_EVN: the hard stop interrupt
    chip2 = ready()
    send(chip2, c.run(c.REVERSE, 13421).encode())
    chip2.advance(3)
    assert chip2.shaft == -500 and chip2.motion.stopped
    assert state(chip2).switch_event


def test_releasesw_runs_at_min_speed_when_that_is_faster() -> None:
    chip = DspinChip(L6470)  # the switch is what set_switch says
    configure(chip)
    chip.set_switch(True)
    send(chip, c.set_param(L6470.registers["MIN_SPEED"], 84).encode())  # 20.0 step/s
    send(chip, c.release_sw(c.RESET_ABS_POS, c.FORWARD).encode())
    chip.advance(0.5)
    assert speed(chip) == pytest.approx(float(scales.MIN_SPEED.value(84)), abs=0.02)
    chip.set_switch(False)
    assert not chip.busy and reg(chip, "ABS_POS") == 0


@pytest.mark.parametrize("direction", [c.REVERSE, c.FORWARD])
def test_a_fast_motion_stops_at_the_microstep_where_the_switch_closes(direction: int) -> None:
    # 1/16 microsteps at 500 full step/s: 4 microsteps per 0.5 ms of the model's time; the
    # chip samples SW all the time, so its hard stop is at the switch's first microstep
    sign = -1 if direction == c.REVERSE else 1
    chip = DspinChip(L6470, switch=lambda shaft: sign * shaft >= 1001)
    configure(chip, 16)
    send(chip, c.set_param(L6470.registers["MAX_SPEED"], 0x3FF).encode())
    send(chip, c.set_param(L6470.registers["ACC"], 0xFFE).encode())
    send(chip, c.run(direction, 500 * 2**28 // 4_000_000).encode())
    chip.advance(1)
    assert chip.shaft == sign * 1001 and chip.motion.stopped
    assert state(chip).switch_event
