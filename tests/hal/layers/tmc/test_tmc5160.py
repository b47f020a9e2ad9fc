"""The TMC5160's own ramp generator (tmc5160.py): its units, the set-up it needs, moves,
stops and homing against the register-level model on a virtual clock."""

from __future__ import annotations

import math
from collections.abc import Callable

import pytest

from motorctl.hal.layers.tmc.link import TmcError
from motorctl.hal.layers.tmc.tmc5160 import F, RampState, RampUnits, Tmc5160
from tests.support import tmc_model as tm
from tests.support.spi_bench import S5160, SpiBench


def test_ramp_units_follow_the_datasheet() -> None:
    u = RampUnits(12e6)
    assert u.velocity(2000.0) == round(2000 * 2**24 / 12e6)
    assert u.steps_s(u.velocity(2000.0)) == pytest.approx(2000.0, abs=0.8)
    assert u.accel(8000.0) == round(8000 * 2**41 / 12e6**2)
    assert u.steps_s2(u.accel(8000.0)) == pytest.approx(8000.0, rel=0.01)
    assert u.decel(8000.0) == math.ceil(8000 * 2**41 / 12e6**2)  # brakes at least as planned
    assert u.steps_s2(u.decel(8000.0)) >= 8000.0
    assert u.velocity(1e9) == (1 << 23) - 512  # clamped to the register's range
    assert u.accel(1e12) == 65535 and u.accel(0.0) == 1


def run_until(
    spi_bench: SpiBench, drv: Tmc5160, cond: Callable[[RampState], bool], limit_s: float
) -> float:
    """Advance the virtual clock in 10 ms steps until ``cond(state)``; the time it took."""
    t0 = spi_bench.clock.now()
    while not cond(drv.state()):
        assert spi_bench.clock.now() - t0 < limit_s, f"not reached within {limit_s} s"
        spi_bench.clock.advance(0.01)
    return spi_bench.clock.now() - t0


def test_ramp_mode_needs_sd_mode_low(spi_bench: SpiBench) -> None:
    spi_bench.chip("tmc5160", sd_mode=1)
    drv = Tmc5160("x", spi_bench.device(), S5160)
    with pytest.raises(TmcError, match=r"SD_MODE pin is high.*tie SD_MODE to GND"):
        drv.start()


def test_ramp_start_holds_still_with_the_required_registers(spi_bench: SpiBench) -> None:
    drv, model = spi_bench.ramp_driver()
    assert model.regs[tm.A_RAMPMODE] == 0
    assert model.regs[tm.A_VSTOP] >= 10 and model.regs[tm.A_VSTART] == 0
    assert model.regs[tm.A_SW_MODE] & 0b1100 == 0b0100  # REFL active low
    spi_bench.clock.advance(1.0)
    assert drv.state().xactual == 0


def test_move_to_reaches_xtarget_along_a_trapezoid(spi_bench: SpiBench) -> None:
    drv, model = spi_bench.ramp_driver()
    drv.move_to(10_000, 5000.0, 20_000.0, 10_000.0)
    assert model.regs[tm.A_XTARGET] == 10_000
    assert model.regs[tm.A_D1] != 0  # the datasheet forbids D1 = 0 in positioning mode
    seen_v: list[int] = []

    def done(s: RampState) -> bool:
        seen_v.append(s.vactual)
        return bool(s.xactual == 10_000 and s.vactual == 0)

    took = run_until(spi_bench, drv, done, 10.0)
    # trapezoid: 5000/20000 s up, 5000/10000 s down, the rest at 5000 steps/s
    ideal = 0.25 + 0.5 + (10_000 - 5000**2 / 40_000 - 5000**2 / 20_000) / 5000
    assert took == pytest.approx(ideal, abs=0.05)
    assert max(seen_v) * 12e6 / 2**24 == pytest.approx(5000.0, rel=0.001)
    assert drv.state().flag(F.POSITION_REACHED)
    assert drv.position() == 10_000


def test_run_and_soft_stop_in_velocity_mode(spi_bench: SpiBench) -> None:
    drv, _ = spi_bench.ramp_driver()
    drv.run(-1, 3000.0, 30_000.0)
    run_until(spi_bench, drv, lambda s: s.vactual * 12e6 / 2**24 < -2999, 2.0)
    x0 = drv.position()
    drv.stop(6000.0)
    took = run_until(spi_bench, drv, lambda s: s.vactual == 0, 5.0)
    assert took == pytest.approx(0.5, abs=0.03)  # 3000 / 6000
    assert drv.position() - x0 == pytest.approx(-(3000**2) / 12_000, abs=20)
    spi_bench.clock.advance(0.5)
    assert drv.state().vactual == 0  # stays stopped


def test_hard_stop_uses_the_chips_largest_deceleration(spi_bench: SpiBench) -> None:
    drv, model = spi_bench.ramp_driver()
    drv.run(1, 20_000.0, 200_000.0)
    run_until(spi_bench, drv, lambda s: s.vactual > 0 and s.flag(F.VELOCITY_REACHED), 2.0)
    drv.stop(None)
    assert model.regs[tm.A_AMAX] == 65535
    took = run_until(spi_bench, drv, lambda s: s.vactual == 0, 1.0)
    assert took <= 0.02


@pytest.mark.parametrize("direction", [-1, 1])
def test_homing_on_the_reference_switch_zeroes_where_it_releases(
    spi_bench: SpiBench, direction: int
) -> None:
    drv, model = spi_bench.ramp_driver()
    if direction < 0:
        model.ref_l_at = -2500.0  # REFL active at and below -2500
    else:
        model.ref_r_at = 2500.0  # REFR active at and above 2500
    drv.home_start(direction, 4000.0, 40_000.0, "endstop")
    run_until(spi_bench, drv, lambda s: drv.home_event(s, direction, "endstop"), 5.0)
    with pytest.raises(TmcError, match="ends where it releases"):
        drv.home_finish("endstop")  # at the trigger: still on the switch
    drv.home_release(direction, 250.0, 40_000.0)
    run_until(spi_bench, drv, lambda s: drv.home_released(s, direction), 5.0)
    drv.stop(None)
    run_until(spi_bench, drv, lambda s: s.stopped, 1.0)
    past = drv.home_finish("endstop")
    assert 0 <= past <= 3  # stands at or a little past the release, which is now 0
    assert drv.position() == -direction * past
    assert model.regs[tm.A_SW_MODE] & 0b1_1110_0011 == 0  # stops and latches off again
    drv.move_to(0, 2000.0, 20_000.0, 20_000.0)
    run_until(spi_bench, drv, lambda s: s.xactual == 0 and s.vactual == 0, 5.0)
    # position 0 is the first microstep off the switch (the model's positions are real)
    assert 0 < direction * (direction * 2500 - model.physical) <= 1
    assert not model.switch_active(direction < 0)


def test_homing_by_stallguard_stops_at_the_wall(spi_bench: SpiBench) -> None:
    drv, model = spi_bench.ramp_driver()
    model.wall_at = 3000.0
    drv.home_start(1, 4000.0, 40_000.0, "stall")
    run_until(spi_bench, drv, lambda s: drv.home_event(s, 1, "stall"), 5.0)
    assert model.physical == pytest.approx(3000, abs=5)
    drv.home_finish("stall")
    assert drv.position() == 0
    spi_bench.clock.advance(0.5)
    assert drv.state().vactual == 0  # VMAX = 0 before sg_stop was released


def test_a_tmc5160_reset_in_ramp_mode_restores_the_ramp_set_up(spi_bench: SpiBench) -> None:
    drv, model = spi_bench.ramp_driver()
    model.power_cycle()
    status = drv.poll()
    assert status.fault is not None and "reset" in status.fault
    assert drv.resets == 1
    assert model.regs[tm.A_VSTOP] >= 10 and model.regs[tm.A_SW_MODE] == drv.sw_mode == 0b100
    assert model.regs[tm.A_RAMPMODE] == 0 and model.regs[tm.A_CHOPCONF] & 0xF == 3
