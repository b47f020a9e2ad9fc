"""The shared TMC driver (driver.py) against register-level chip models behind a fake
py-spidev (tests/support/tmc_model.py, spi_bench.py): start-up, version check and
verified configuration, DRV_STATUS as faults and stalls, SPI errors as latched faults, chip
resets; and a driver's fault and stall as the motion engine sees them. Time is a
VirtualClock."""

from __future__ import annotations

import math
from collections.abc import Callable

import pytest

from motorctl.hal.backends.mock.world import world_of
from motorctl.hal.layers.tmc.link import TmcError
from motorctl.hal.layers.tmc.settings import TmcSettings
from motorctl.hal.layers.tmc.tmc2130 import TMC2130
from motorctl.hal.spec import AxisSpec
from motorctl.motion.engine import MotionEngine
from motorctl.motion.types import (
    HomeCmd,
    HomingParams,
    HomingSource,
    MotorState,
    Ramp,
    RunCmd,
)
from tests.support import tmc_model as tm
from tests.support.motor_defaults import motor_params
from tests.support.rigs import engine_rig
from tests.support.spi_bench import S2130, S5160, SpiBench
from tests.support.tmc_model import TmcModel


@pytest.mark.parametrize("settings_", [S2130, S5160], ids=["tmc2130", "tmc5160"])
def test_start_writes_the_configuration_and_reads_it_back(
    spi_bench: SpiBench, settings_: TmcSettings
) -> None:
    model = spi_bench.chip(settings_.chip.name.lower())
    drv = spi_bench.driver(settings_)
    drv.start()
    chop = model.regs[tm.A_CHOPCONF]
    assert chop & 0xF == 3  # TOFF
    assert chop >> 24 & 0xF == 4  # MRES: 16 microsteps
    assert chop >> 28 & 1 == 1  # intpol
    ihold_irun = model.regs[tm.A_IHOLD_IRUN]
    irun, ihold = ihold_irun >> 8 & 0x1F, ihold_irun & 0x1F
    assert ihold_irun >> 16 & 0xF == 6
    assert abs(ihold - (irun + 1) / 2 + 1) <= 1  # half the current
    sgt = model.regs[tm.A_COOLCONF] >> 16 & 0x7F
    assert (sgt - 128 if sgt & 0x40 else sgt) == settings_.stall_threshold
    # TCOOLTHRS: TSTEP at 500 full-rate steps/s = fCLK / (500 * 256/16)
    assert model.regs[tm.A_TCOOLTHRS] == int(12e6 / (500 * 16))
    assert model.regs[tm.A_TPOWERDOWN] == 10
    assert model.gstat == 0  # the reset flag is cleared
    # the RMS current the chip now drives, by the datasheet's formula
    if settings_.chip is TMC2130:
        vfs = 0.18 if chop >> 17 & 1 else 0.32
        rms = (irun + 1) / 32 * vfs / (0.11 + 0.02) / math.sqrt(2)
    else:
        gs = model.regs[tm.A_GLOBALSCALER] or 256
        rms = gs / 256 * (irun + 1) / 32 * 0.325 / 0.075 / math.sqrt(2)
    assert rms == pytest.approx(settings_.run_current, rel=0.04)


def test_a_wrong_chip_is_refused_naming_both(spi_bench: SpiBench) -> None:
    spi_bench.chip("tmc5160")
    with pytest.raises(TmcError) as e:
        spi_bench.driver(S2130).start()
    msg = str(e.value)
    assert "/dev/spidev0.0" in msg and "TMC2130" in msg and "found a TMC5160" in msg
    assert 'driver = "tmc5160"' in msg


def test_a_register_that_does_not_read_back_is_an_error(spi_bench: SpiBench) -> None:
    model = spi_bench.chip("tmc2130")
    drv = spi_bench.driver(S2130)
    drv.start()
    model.regs[tm.A_CHOPCONF] ^= 1 << 28  # the chip holds something else
    with pytest.raises(TmcError, match="CHOPCONF reads back"):
        drv.verify()


def test_a_transfer_error_at_start_is_a_clear_error(spi_bench: SpiBench) -> None:
    spi_bench.chip("tmc2130")
    spi_bench.kernel.fail_xfers = 1
    with pytest.raises(TmcError, match=r"m0: cannot transfer on /dev/spidev0.0: Input/output"):
        spi_bench.driver(S2130).start()


def test_a_transfer_error_while_running_is_a_latched_fault_not_an_exception(
    spi_bench: SpiBench,
) -> None:
    spi_bench.chip("tmc2130")
    drv = spi_bench.driver(S2130)
    drv.start()
    spi_bench.kernel.fail_xfers = 1
    status = drv.poll()  # does not raise
    assert status.fault is not None and "/dev/spidev0.0" in status.fault
    assert "Input/output error" in status.fault
    assert drv.spi_errors == 1
    assert drv.status().fault == status.fault  # the step path sees it
    assert drv.poll().fault is None  # healthy again, and it was seen once: gone
    assert drv.status().fault is None


FAULTS = [
    ("tmc2130", tm.OT, "over-temperature"),
    ("tmc2130", tm.S2GA, "short to ground on phase A"),
    ("tmc2130", tm.S2GB, "short to ground on phase B"),
    ("tmc5160", tm.OT, "over-temperature"),
    ("tmc5160", tm.S2GA, "short to ground on phase A"),
    ("tmc5160", tm.S2GB, "short to ground on phase B"),
    ("tmc5160", tm.S2VSA, "short to supply on phase A"),
    ("tmc5160", tm.S2VSB, "short to supply on phase B"),
    ("tmc2130", tm.OLA, "open load on phase A"),
    ("tmc2130", tm.OLB, "open load on phase B"),
    ("tmc5160", tm.OLA, "open load on phase A"),
    ("tmc5160", tm.OLB, "open load on phase B"),
]


@pytest.mark.parametrize(("kind", "bit", "text"), FAULTS)
def test_every_fault_bit_becomes_a_fault(
    spi_bench: SpiBench, kind: str, bit: int, text: str
) -> None:
    model = spi_bench.chip(kind, sd_mode=1)
    drv = spi_bench.driver(S2130 if kind == "tmc2130" else S5160)
    drv.start()
    assert drv.poll().fault is None
    model.step_rate = 1000.0  # moving: open load is only meaningful in motion
    model.faults.add(bit)
    status = drv.poll()
    assert status.fault is not None and text in status.fault
    assert drv.fault_counts
    if bit in (tm.S2GA, tm.S2GB, tm.S2VSA, tm.S2VSB):
        assert model.regs[tm.A_CHOPCONF] & 0xF == 0  # the driver switched the bridges off
        assert "restart motorctld" in status.fault
        assert drv.poll().fault == status.fault  # stays although TOFF=0 cleared the flags
    else:
        model.faults.discard(bit)
        assert drv.poll().fault is None  # over-temperature and open load clear themselves


def test_tmc2130_has_no_short_to_supply_flags(spi_bench: SpiBench) -> None:
    model = spi_bench.chip("tmc2130")
    drv = spi_bench.driver(S2130)
    drv.start()
    model.faults.add(tm.S2VSA)  # bit 12 is not a flag on the TMC2130
    assert drv.poll().fault is None


def test_open_load_at_standstill_is_not_a_fault(spi_bench: SpiBench) -> None:
    model = spi_bench.chip("tmc2130")
    drv = spi_bench.driver(S2130)
    drv.start()
    model.faults.add(tm.OLA)
    assert drv.poll().fault is None  # datasheet: false detection at standstill


def test_open_load_as_warning_and_otpw_are_counted_not_faults(spi_bench: SpiBench) -> None:
    model = spi_bench.chip("tmc2130")
    drv = spi_bench.driver(TmcSettings(open_load="warn"))
    drv.start()
    model.step_rate = 800.0
    model.faults |= {tm.OLB, tm.OTPW}
    assert drv.poll().fault is None
    assert drv.warning_counts["open load on phase B (olb)"] == 1
    assert drv.warning_counts["over-temperature pre-warning (otpw)"] == 1


def test_stall_flag_counts_only_in_motion_above_the_threshold_speed(spi_bench: SpiBench) -> None:
    model = spi_bench.chip("tmc2130")
    drv = spi_bench.driver(S2130)  # stall_min_speed = 500 steps/s
    drv.start()
    model.stall = True
    assert drv.poll().stall is False  # standing still
    model.step_rate = 200.0
    assert drv.poll().stall is False  # slower than stall_min_speed: stallGuard is unreliable
    model.step_rate = 2000.0
    assert drv.poll().stall is True
    assert drv.poll().fault is None  # a stall is not a driver fault; the motion layer decides


def test_a_chip_reset_while_running_is_reported_and_reconfigured(spi_bench: SpiBench) -> None:
    model = spi_bench.chip("tmc2130")
    drv = spi_bench.driver(S2130)
    drv.start()
    configured = dict(model.regs)
    model.power_cycle()
    status = drv.poll()
    assert status.fault is not None and "reset and lost its configuration" in status.fault
    assert model.regs == configured  # written again and verified
    assert drv.status().fault is not None  # the motion layer reads it once...
    assert drv.poll().fault is None  # ...then it is gone


Tick = Callable[[], None]


def engine_with_tmc(
    spi_bench: SpiBench, homing: HomingParams
) -> tuple[MotionEngine, TmcModel, Tick]:
    model = spi_bench.chip("tmc2130")
    drv = spi_bench.driver(S2130)
    drv.start()
    # the mock's STEP/DIR, a TMC2130 for the status, read by the engine's driver poller
    engine = engine_rig(
        motor_params(homing=homing),
        axes=[AxisSpec()],
        clock=spi_bench.clock,
        driver_poll_s=0.005,
        drivers=[drv],
    ).engine

    def chip_tick() -> None:  # the chip model sees the motor's motion (STEP/DIR are mock's)
        moving = engine.motors[0].active
        model.step_rate = 2000.0 if moving else 0.0

    return engine, model, chip_tick


def run_engine(spi_bench: SpiBench, engine: MotionEngine, tick: Tick, seconds: float) -> None:
    """Run the engine on the virtual clock (its driver poller reads the chip every 5 ms),
    the chip model told the motor's motion every 10 ms."""
    end = spi_bench.clock.now() + seconds
    while spi_bench.clock.now() < end:
        tick()
        engine.run_until(spi_bench.clock.now() + 0.01)


def test_a_driver_fault_stops_the_motor_and_latches_e4(spi_bench: SpiBench) -> None:
    engine, model, tick = engine_with_tmc(spi_bench, HomingParams())
    motor = engine.motors[0]

    def state() -> MotorState:  # read afresh (a call, so the type checker does not pin it)
        return motor.state

    with engine.lock:
        motor.submit(RunCmd(1, Ramp(2000.0, 8000.0, 8000.0)), spi_bench.clock.now())
    run_engine(spi_bench, engine, tick, 0.3)
    assert state() is MotorState.RUNNING
    model.faults.add(tm.OT)
    run_engine(spi_bench, engine, tick, 0.1)
    assert state() is MotorState.FAULT
    assert motor.fault is not None and "over-temperature" in motor.fault
    with engine.lock:
        assert motor.stop(hard=False, now=spi_bench.clock.now()) is False  # still hot: E4
    model.faults.clear()
    run_engine(spi_bench, engine, tick, 0.1)
    with engine.lock:
        assert motor.stop(hard=False, now=spi_bench.clock.now()) is True  # cooled: cleared
    assert state() is MotorState.IDLE


def test_stall_homing_ends_on_the_drivers_stall_flag(spi_bench: SpiBench) -> None:
    homing = HomingParams(source=HomingSource.STALL, max_travel=100_000)
    engine, model, tick = engine_with_tmc(spi_bench, homing)
    motor = engine.motors[0]
    world = world_of(engine.hw)
    with engine.lock:
        motor.submit(HomeCmd(1, Ramp(2000.0, 8000.0, 8000.0)), spi_bench.clock.now())
    homed_at: list[int] = []
    end = spi_bench.clock.now() + 5.0
    while motor.state is not MotorState.IDLE:
        assert spi_bench.clock.now() < end, "stall homing did not finish within 5 s"
        model.stall = world.axes[0].position >= 1500  # the carriage meets the frame
        run_engine(spi_bench, engine, tick, 0.01)
    homed_at.append(world.axes[0].position)
    assert motor.fault is None
    assert 1500 <= homed_at[0] <= 1500 + 2000 * 0.05  # within a few polls of the stall
    assert motor.position == 0


def test_a_transient_fault_set_between_two_publications_is_not_lost(spi_bench: SpiBench) -> None:
    spi_bench.chip("tmc2130")
    drv = spi_bench.driver(S2130)
    drv.start()
    drv.poll()
    drv._set_transient("SPI: simulated")  # the monitor latched it, not yet published...
    assert drv.status().fault is None  # ...a reader in between sees the old status
    assert drv._publish(None).fault == "SPI: simulated"  # still reported
    assert drv.status().fault == "SPI: simulated"
    assert drv.poll().fault is None
