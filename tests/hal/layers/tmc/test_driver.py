"""TMC2130/TMC5160 drivers over SPI against register-level chip models behind a fake py-spidev.

No kernel device is needed: tests/support/tmc_model.py implements py-spidev's API (open, mode,
max_speed_hz, xfer2 overwriting its list) in front of chip models written from the datasheets.
Time is a VirtualClock; the one test of the monitor thread waits on a deadline.
"""

from __future__ import annotations

import errno
import math
import sys
import threading
import time
import types
from collections.abc import Callable
from dataclasses import dataclass, field

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from motorctl.daemon.assemble import hardware_spec
from motorctl.daemon.config import ConfigError, parse_config
from motorctl.hal.backends.mock.world import world_of
from motorctl.hal.interfaces import HalError, MonotonicClock
from motorctl.hal.layers.tmc.config import driver_spec
from motorctl.hal.layers.tmc.driver import TmcDriver
from motorctl.hal.layers.tmc.fields import Chip, mres_of
from motorctl.hal.layers.tmc.layer import probe
from motorctl.hal.layers.tmc.link import TmcError, TmcLink
from motorctl.hal.layers.tmc.monitor import DriverMonitor
from motorctl.hal.layers.tmc.ramp import RampState, RefSwitches, Tmc5160
from motorctl.hal.layers.tmc.settings import (
    TmcSettings,
    TmcSpec,
    current_setting,
    register_values,
)
from motorctl.hal.layers.tmc.spi import SpiAddress, SpiError
from motorctl.hal.layers.tmc.tmc2130 import TMC2130
from motorctl.hal.layers.tmc.tmc5160 import TMC5160, F, RampUnits, Reg
from motorctl.hal.registry import open_hardware
from motorctl.hal.spec import AxisSpec, HardwareSpec
from motorctl.motion.engine import MotionEngine
from motorctl.motion.types import (
    HomeCmd,
    HomingParams,
    HomingSource,
    MotorParams,
    MotorState,
    Ramp,
    RunCmd,
)
from tests.support import tmc_model as tm
from tests.support.rigs import engine_rig
from tests.support.spi_bench import SPEED, SpiBench
from tests.support.tmc_model import FakeKernel, FakeSpiDev, TmcModel


@pytest.fixture
def bench() -> SpiBench:
    return SpiBench()


S2130 = TmcSettings(
    chip="tmc2130",
    run_current=0.8,
    hold_current=0.4,
    microsteps=16,
    stall_threshold=5,
    stall_min_speed=500.0,
)
S5160 = TmcSettings(
    chip="tmc5160",
    run_current=2.0,
    hold_current=1.0,
    microsteps=16,
    stall_threshold=-3,
    stall_min_speed=500.0,
)


# ------------------------------------------------------------------ the fake is py-spidev


def test_fake_spidev_keeps_py_spidevs_contract(bench: SpiBench) -> None:
    bench.chip("tmc2130")
    dev = FakeSpiDev(bench.kernel)
    with pytest.raises(OSError) as e:
        dev.mode = 3  # before open: the ioctl fails on fd -1
    assert e.value.errno == errno.EBADF
    with pytest.raises(OSError) as e:
        dev.open(0, 7)
    assert e.value.errno == errno.ENOENT
    dev.open(0, 0)
    dev.mode = 3
    buf = [0x04, 0, 0, 0, 0]
    out = dev.xfer2(buf)
    assert out is buf  # xfer2 writes the received bytes into the list it was given
    assert buf[0] & 0x01  # reset_flag after power-up, in the status byte


def test_spi_address_parsing() -> None:
    assert SpiAddress.parse("/dev/spidev1.2") == SpiAddress(1, 2)
    assert SpiAddress.parse("0.1").path == "/dev/spidev0.1"
    with pytest.raises(ValueError, match=r"/dev/spidevB.C"):
        SpiAddress.parse("/dev/ttyAMA0")


# ------------------------------------------------------------------ datagrams on the wire


def test_reads_are_pipelined_and_writes_echo(bench: SpiBench) -> None:
    model = bench.chip("tmc2130")
    dev = bench.device()
    dev.open()
    assert bench.kernel.opened[0].mode == 3 and bench.kernel.opened[0].max_speed_hz == SPEED
    link = TmcLink(dev, TMC2130)
    assert link.read(Reg.IOIN) >> 24 == 0x11
    tx, _ = model.log[-2]
    assert tx == bytes([0x04, 0, 0, 0, 0])  # a read: bit 7 clear, zero data
    _, rx2 = model.log[-1]
    assert rx2[1:] == (0x11 << 24 | 1 << 6).to_bytes(4, "big")  # answered one datagram later
    link.write(Reg.CHOPCONF, 0x12345678)
    wtx, _ = model.log[-2]
    assert wtx == bytes([0x80 | 0x6C, 0x12, 0x34, 0x56, 0x78])
    assert model.log[-1][1][1:] == bytes([0x12, 0x34, 0x56, 0x78])  # the echo
    assert link.read_many([Reg.GCONF, Reg.CHOPCONF]) == [0, 0x12345678]


def test_status_byte_flags_are_counted_on_their_rising_edge(bench: SpiBench) -> None:
    model = bench.chip("tmc2130")
    drv = bench.driver(S2130)
    drv.start()  # the reset flag was up, and went down when GSTAT was read
    counts = drv.link.flag_counts
    assert counts["reset_flag"] == 1 and counts["standstill"] == 1
    model.step_rate, model.stall = 2000.0, True
    for _ in range(3):
        drv.poll()
    assert counts["sg2"] == 1  # one rising edge, however many datagrams saw it
    model.stall = False
    drv.poll()
    model.stall = True
    drv.poll()
    assert counts["sg2"] == 2


# ------------------------------------------------------------------ start: version, config


@pytest.mark.parametrize("settings_", [S2130, S5160], ids=["tmc2130", "tmc5160"])
def test_start_writes_the_configuration_and_reads_it_back(
    bench: SpiBench, settings_: TmcSettings
) -> None:
    model = bench.chip(settings_.chip)
    drv = bench.driver(settings_)
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
    if settings_.chip == "tmc2130":
        vfs = 0.18 if chop >> 17 & 1 else 0.32
        rms = (irun + 1) / 32 * vfs / (0.11 + 0.02) / math.sqrt(2)
    else:
        gs = model.regs[tm.A_GLOBALSCALER] or 256
        rms = gs / 256 * (irun + 1) / 32 * 0.325 / 0.075 / math.sqrt(2)
    assert rms == pytest.approx(settings_.run_current, rel=0.04)


@settings(max_examples=60, deadline=None)
@given(
    chip=st.sampled_from([TMC2130, TMC5160]),
    sense=st.sampled_from([0.05, 0.075, 0.11, 0.22]),
    frac=st.floats(0.05, 1.0),
)
def test_current_scaling_hits_the_requested_current(chip: Chip, sense: float, frac: float) -> None:
    top = (0.32 / (sense + 0.02) if chip is TMC2130 else 0.325 / sense) / math.sqrt(2)
    run = top * frac
    setting = current_setting(chip, sense, run, run / 2)
    step = setting.rms(chip, sense, 31) / 32  # one current-scale step
    assert abs(setting.rms(chip, sense, setting.irun) - run) <= step / 2 + 1e-9
    assert 0 <= setting.ihold <= setting.irun <= 31


def test_impossible_settings_are_refused_with_the_reason() -> None:
    with pytest.raises(ValueError, match=r"above the .* A a TMC2130 gives"):
        current_setting(TMC2130, 0.11, 3.0, 1.0)
    with pytest.raises(ValueError, match="power of two"):
        mres_of(12)
    with pytest.raises(ValueError, match="unknown driver chip"):
        register_values(TmcSettings(chip="tmc2209"))


def test_a_wrong_chip_is_refused_naming_both(bench: SpiBench) -> None:
    bench.chip("tmc5160")
    with pytest.raises(TmcError) as e:
        bench.driver(S2130).start()
    msg = str(e.value)
    assert "/dev/spidev0.0" in msg and "TMC2130" in msg and "found a TMC5160" in msg
    assert 'driver = "tmc5160"' in msg


def test_no_chip_answering_is_a_clear_error(bench: SpiBench) -> None:
    bench.chip("tmc2130", dead=True)
    with pytest.raises(TmcError, match=r"no driver chip answers.*0xffffffff.*VIO"):
        bench.driver(S2130).start()


def test_a_register_that_does_not_read_back_is_an_error(bench: SpiBench) -> None:
    model = bench.chip("tmc2130")
    drv = bench.driver(S2130)
    drv.start()
    model.regs[tm.A_CHOPCONF] ^= 1 << 28  # the chip holds something else
    with pytest.raises(TmcError, match="CHOPCONF reads back"):
        drv.verify()


def test_a_garbled_write_is_caught_by_its_echo(bench: SpiBench) -> None:
    model = bench.chip("tmc2130")
    drv = bench.driver(S2130)
    drv.start()
    real = model.transfer

    def flip_bit(tx: bytes) -> bytes:  # a noisy MOSI line: one data bit flips
        return real(bytes([tx[0], tx[1], tx[2], tx[3], tx[4] ^ 0x10]) if tx[0] & 0x80 else tx)

    model.transfer = flip_bit  # type: ignore[method-assign]
    with pytest.raises(TmcError, match=r"did not receive IHOLD_IRUN .* intact.*spi_speed_hz"):
        drv.link.write(Reg.IHOLD_IRUN, 0x61010)


# ------------------------------------------------------------------ SPI errors


def test_missing_device_names_the_path_and_the_fix(bench: SpiBench) -> None:
    with pytest.raises(SpiError) as e:
        bench.driver(S2130, cs=1).start()
    assert "/dev/spidev0.1 does not exist" in str(e.value)
    assert "dtparam=spi=on" in str(e.value)


def test_permission_denied_names_the_group(bench: SpiBench) -> None:
    bench.chip("tmc2130")
    bench.kernel.no_permission.add((0, 0))
    with pytest.raises(SpiError, match=r"no permission to open /dev/spidev0.0.*usermod -aG spi"):
        bench.driver(S2130).start()


def test_spidev_missing_is_a_hal_error_saying_how_to_install(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import builtins

    from motorctl.hal.interfaces import HalError
    from motorctl.hal.layers.tmc.spi import spidev_factory

    real_import = builtins.__import__

    def no_spidev(name: str, *args: object, **kw: object) -> object:
        if name == "spidev":
            raise ImportError("No module named 'spidev'")
        return real_import(name, *args, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(builtins, "__import__", no_spidev)
    with pytest.raises(HalError, match="python3-spidev"):
        spidev_factory()


def test_a_transfer_error_at_start_is_a_clear_error(bench: SpiBench) -> None:
    bench.chip("tmc2130")
    bench.kernel.fail_xfers = 1
    with pytest.raises(TmcError, match=r"m0: cannot transfer on /dev/spidev0.0: Input/output"):
        bench.driver(S2130).start()


def test_a_transfer_error_while_running_is_a_latched_fault_not_an_exception(
    bench: SpiBench,
) -> None:
    bench.chip("tmc2130")
    drv = bench.driver(S2130)
    drv.start()
    bench.kernel.fail_xfers = 1
    status = drv.poll()  # does not raise
    assert status.fault is not None and "/dev/spidev0.0" in status.fault
    assert "Input/output error" in status.fault
    assert drv.spi_errors == 1
    assert drv.status().fault == status.fault  # the step path sees it
    assert drv.poll().fault is None  # healthy again, and it was seen once: gone
    assert drv.status().fault is None


# ------------------------------------------------------------------ DRV_STATUS -> faults

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
def test_every_fault_bit_becomes_a_fault(bench: SpiBench, kind: str, bit: int, text: str) -> None:
    model = bench.chip(kind, sd_mode=1)
    drv = bench.driver(S2130 if kind == "tmc2130" else S5160)
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


def test_tmc2130_has_no_short_to_supply_flags(bench: SpiBench) -> None:
    model = bench.chip("tmc2130")
    drv = bench.driver(S2130)
    drv.start()
    model.faults.add(tm.S2VSA)  # bit 12 is not a flag on the TMC2130
    assert drv.poll().fault is None


def test_open_load_at_standstill_is_not_a_fault(bench: SpiBench) -> None:
    model = bench.chip("tmc2130")
    drv = bench.driver(S2130)
    drv.start()
    model.faults.add(tm.OLA)
    assert drv.poll().fault is None  # datasheet: false detection at standstill


def test_open_load_as_warning_and_otpw_are_counted_not_faults(bench: SpiBench) -> None:
    model = bench.chip("tmc2130")
    drv = bench.driver(TmcSettings(open_load="warn"))
    drv.start()
    model.step_rate = 800.0
    model.faults |= {tm.OLB, tm.OTPW}
    assert drv.poll().fault is None
    assert drv.warning_counts["open load on phase B (olb)"] == 1
    assert drv.warning_counts["over-temperature pre-warning (otpw)"] == 1


def test_stall_flag_counts_only_in_motion_above_the_threshold_speed(bench: SpiBench) -> None:
    model = bench.chip("tmc2130")
    drv = bench.driver(S2130)  # stall_min_speed = 500 steps/s
    drv.start()
    model.stall = True
    assert drv.poll().stall is False  # standing still
    model.step_rate = 200.0
    assert drv.poll().stall is False  # slower than stall_min_speed: stallGuard is unreliable
    model.step_rate = 2000.0
    assert drv.poll().stall is True
    assert drv.poll().fault is None  # a stall is not a driver fault; the motion layer decides


def test_a_chip_reset_while_running_is_reported_and_reconfigured(bench: SpiBench) -> None:
    model = bench.chip("tmc2130")
    drv = bench.driver(S2130)
    drv.start()
    configured = dict(model.regs)
    model.power_cycle()
    status = drv.poll()
    assert status.fault is not None and "reset and lost its configuration" in status.fault
    assert model.regs == configured  # written again and verified
    assert drv.status().fault is not None  # the motion layer reads it once...
    assert drv.poll().fault is None  # ...then it is gone


def test_a_monitor_thread_survives_a_failing_poll(bench: SpiBench) -> None:
    bench.chip("tmc2130")
    bench.chip("tmc2130", cs=1)
    good = bench.driver(TmcSettings(poll_ms=1.0))
    bad = bench.driver(TmcSettings(poll_ms=1.0), cs=1)
    good.start()
    bad.start()

    def broken() -> None:
        raise RuntimeError("bug")

    bad.poll = broken  # type: ignore[assignment,method-assign]
    monitor = DriverMonitor([good, bad], time.monotonic)
    monitor.start()
    deadline = time.monotonic() + 10.0
    try:
        while good.polls < 5:
            assert time.monotonic() < deadline, "the monitor did not poll 5 times within 10 s"
            time.sleep(0.005)
        status = bad.status()
        assert status.fault is not None and "internal error in the driver monitor" in status.fault
    finally:
        monitor.stop()
    assert good.polls >= 5


def test_one_bus_lock_keeps_pipelined_reads_whole_across_threads(bench: SpiBench) -> None:
    bench.chip("tmc2130", cs=0)
    bench.chip("tmc5160", cs=1, sd_mode=1)
    a, b = bench.device(0), bench.device(1)
    assert a.lock is b.lock  # one bus, one lock
    assert bench.device(0, bus=1).lock is not a.lock
    a.open()
    b.open()
    links = [TmcLink(a, TMC2130), TmcLink(a, TMC2130), TmcLink(b, TMC5160)]
    wrong: list[str] = []

    def reader(link: TmcLink) -> None:
        for _ in range(300):
            got = link.read(Reg.IOIN) >> 24
            if got != link.chip.version:
                wrong.append(f"{link.chip.name}: 0x{got:02x}")

    threads = [threading.Thread(target=reader, args=(lk,)) for lk in links]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30.0)
        assert not t.is_alive(), "a reader did not finish within 30 s"
    assert wrong == []


# ------------------------------------------------------------------ TMC5160 ramp generator


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


def ramp_driver(bench: SpiBench) -> tuple[Tmc5160, TmcModel]:
    model = bench.chip("tmc5160")
    drv = Tmc5160("x", bench.device(), S5160, RefSwitches(left_active_low=True))
    drv.start()
    return drv, model


def run_until(
    bench: SpiBench, drv: Tmc5160, cond: Callable[[RampState], bool], limit_s: float
) -> float:
    """Advance the virtual clock in 10 ms steps until ``cond(state)``; the time it took."""
    t0 = bench.clock.now()
    while not cond(drv.state()):
        assert bench.clock.now() - t0 < limit_s, f"not reached within {limit_s} s"
        bench.clock.advance(0.01)
    return bench.clock.now() - t0


def test_ramp_mode_needs_sd_mode_low(bench: SpiBench) -> None:
    bench.chip("tmc5160", sd_mode=1)
    drv = Tmc5160("x", bench.device(), S5160)
    with pytest.raises(TmcError, match=r"SD_MODE pin is high.*tie SD_MODE to GND"):
        drv.start()


def test_ramp_start_holds_still_with_the_required_registers(bench: SpiBench) -> None:
    drv, model = ramp_driver(bench)
    assert model.regs[tm.A_RAMPMODE] == 0
    assert model.regs[tm.A_VSTOP] >= 10 and model.regs[tm.A_VSTART] == 0
    assert model.regs[tm.A_SW_MODE] & 0b1100 == 0b0100  # REFL active low
    bench.clock.advance(1.0)
    assert drv.state().xactual == 0


def test_move_to_reaches_xtarget_along_a_trapezoid(bench: SpiBench) -> None:
    drv, model = ramp_driver(bench)
    drv.move_to(10_000, 5000.0, 20_000.0, 10_000.0)
    assert model.regs[tm.A_XTARGET] == 10_000
    assert model.regs[tm.A_D1] != 0  # the datasheet forbids D1 = 0 in positioning mode
    seen_v: list[int] = []

    def done(s: RampState) -> bool:
        seen_v.append(s.vactual)
        return bool(s.xactual == 10_000 and s.vactual == 0)

    took = run_until(bench, drv, done, 10.0)
    # trapezoid: 5000/20000 s up, 5000/10000 s down, the rest at 5000 steps/s
    ideal = 0.25 + 0.5 + (10_000 - 5000**2 / 40_000 - 5000**2 / 20_000) / 5000
    assert took == pytest.approx(ideal, abs=0.05)
    assert max(seen_v) * 12e6 / 2**24 == pytest.approx(5000.0, rel=0.001)
    assert drv.state().flag(F.POSITION_REACHED)
    assert drv.position() == 10_000


def test_run_and_soft_stop_in_velocity_mode(bench: SpiBench) -> None:
    drv, _ = ramp_driver(bench)
    drv.run(-1, 3000.0, 30_000.0)
    run_until(bench, drv, lambda s: s.vactual * 12e6 / 2**24 < -2999, 2.0)
    x0 = drv.position()
    drv.stop(6000.0)
    took = run_until(bench, drv, lambda s: s.vactual == 0, 5.0)
    assert took == pytest.approx(0.5, abs=0.03)  # 3000 / 6000
    assert drv.position() - x0 == pytest.approx(-(3000**2) / 12_000, abs=20)
    bench.clock.advance(0.5)
    assert drv.state().vactual == 0  # stays stopped


def test_hard_stop_uses_the_chips_largest_deceleration(bench: SpiBench) -> None:
    drv, model = ramp_driver(bench)
    drv.run(1, 20_000.0, 200_000.0)
    run_until(bench, drv, lambda s: s.vactual > 0 and s.flag(F.VELOCITY_REACHED), 2.0)
    drv.stop(None)
    assert model.regs[tm.A_AMAX] == 65535
    took = run_until(bench, drv, lambda s: s.vactual == 0, 1.0)
    assert took <= 0.02


def test_homing_on_the_reference_switch_zeroes_at_the_trigger(bench: SpiBench) -> None:
    drv, model = ramp_driver(bench)
    model.ref_l_at = -2500.0
    drv.home_start(-1, 4000.0, 40_000.0, "endstop")
    run_until(bench, drv, lambda s: drv.home_event(s, -1, "endstop"), 5.0)
    overshoot = drv.home_finish("endstop")
    assert overshoot <= 0  # stopped at or beyond the switch, which is now position 0
    assert drv.position() == overshoot
    assert model.regs[tm.A_SW_MODE] & 0b11 == 0  # stop switches off again: it may leave
    drv.move_to(1000, 2000.0, 20_000.0, 20_000.0)
    run_until(bench, drv, lambda s: s.xactual == 1000 and s.vactual == 0, 5.0)
    assert model.physical == pytest.approx(-2500 + 1000, abs=1)  # positions count from the switch


def test_homing_by_stallguard_stops_at_the_wall(bench: SpiBench) -> None:
    drv, model = ramp_driver(bench)
    model.wall_at = 3000.0
    drv.home_start(1, 4000.0, 40_000.0, "stall")
    run_until(bench, drv, lambda s: drv.home_event(s, 1, "stall"), 5.0)
    assert model.physical == pytest.approx(3000, abs=5)
    drv.home_finish("stall")
    assert drv.position() == 0
    bench.clock.advance(0.5)
    assert drv.state().vactual == 0  # VMAX = 0 before sg_stop was released


# ------------------------------------------------------------------ with the motion engine


Tick = Callable[[], None]


def engine_with_tmc(bench: SpiBench, homing: HomingParams) -> tuple[MotionEngine, TmcModel, Tick]:
    model = bench.chip("tmc2130")
    drv = bench.driver(S2130)
    drv.start()
    # the mock's STEP/DIR, a TMC2130 for the status
    engine = engine_rig(
        MotorParams(homing=homing),
        axes=[AxisSpec()],
        clock=bench.clock,
        driver_poll_s=0.005,
        drivers=[drv],
    ).engine

    def monitor_tick() -> None:  # what the monitor thread does, in virtual time
        moving = engine.motors[0].active
        model.step_rate = 2000.0 if moving else 0.0
        drv.poll()

    return engine, model, monitor_tick


def run_engine(bench: SpiBench, engine: MotionEngine, tick: Tick, seconds: float) -> None:
    """Run the engine on the virtual clock with a monitor poll every 10 ms."""
    end = bench.clock.now() + seconds
    while bench.clock.now() < end:
        engine.run_until(bench.clock.now() + 0.01)
        tick()


def test_a_driver_fault_stops_the_motor_and_latches_e4(bench: SpiBench) -> None:
    engine, model, tick = engine_with_tmc(bench, HomingParams())
    motor = engine.motors[0]

    def state() -> MotorState:  # read afresh (a call, so the type checker does not pin it)
        return motor.state

    with engine.lock:
        motor.submit(RunCmd(1, Ramp(2000.0, 8000.0, 8000.0)), bench.clock.now())
    run_engine(bench, engine, tick, 0.3)
    assert state() is MotorState.RUNNING
    model.faults.add(tm.OT)
    run_engine(bench, engine, tick, 0.1)
    assert state() is MotorState.FAULT
    assert motor.fault is not None and "over-temperature" in motor.fault
    with engine.lock:
        assert motor.stop(hard=False, now=bench.clock.now()) is False  # still hot: E4
    model.faults.clear()
    run_engine(bench, engine, tick, 0.1)
    with engine.lock:
        assert motor.stop(hard=False, now=bench.clock.now()) is True  # cooled: cleared
    assert state() is MotorState.IDLE


def test_stall_homing_ends_on_the_drivers_stall_flag(bench: SpiBench) -> None:
    homing = HomingParams(source=HomingSource.STALL, max_travel=100_000)
    engine, model, tick = engine_with_tmc(bench, homing)
    motor = engine.motors[0]
    world = world_of(engine.hw)
    with engine.lock:
        motor.submit(HomeCmd(1, Ramp(2000.0, 8000.0, 8000.0)), bench.clock.now())
    homed_at: list[int] = []
    end = bench.clock.now() + 5.0
    while motor.state is not MotorState.IDLE:
        assert bench.clock.now() < end, "stall homing did not finish within 5 s"
        model.stall = world.axes[0].position >= 1500  # the carriage meets the frame
        run_engine(bench, engine, tick, 0.01)
    homed_at.append(world.axes[0].position)
    assert motor.fault is None
    assert 1500 <= homed_at[0] <= 1500 + 2000 * 0.05  # within a few polls of the stall
    assert motor.position == 0


# ------------------------------------------------------------------ the backend layer


def fake_spidev_module(monkeypatch: pytest.MonkeyPatch, kernel: FakeKernel) -> None:
    """Install the fake as the module ``spidev``: the backend's lazy import finds it."""
    monkeypatch.setitem(sys.modules, "spidev", types.SimpleNamespace(SpiDev=kernel.factory()))


def spec_with(*drivers: TmcSpec | None) -> HardwareSpec:
    return HardwareSpec(tuple(AxisSpec(name=f"m{i}", driver=d) for i, d in enumerate(drivers)))


def test_open_hardware_starts_configured_drivers_and_their_monitor(
    bench: SpiBench, monkeypatch: pytest.MonkeyPatch
) -> None:
    model = bench.chip("tmc2130", cs=1)
    fake_spidev_module(monkeypatch, bench.kernel)
    settings_ = TmcSettings(poll_ms=1.0)
    hw = open_hardware(
        "mock", spec_with(None, TmcSpec("/dev/spidev0.1", settings_)), MonotonicClock()
    )
    try:
        drv = hw.steppers[1].driver
        assert isinstance(drv, TmcDriver) and drv.name == "m1"
        assert not isinstance(hw.steppers[0].driver, TmcDriver)
        assert model.regs[tm.A_CHOPCONF] & 0xF == 3  # configured, energised
        deadline = time.monotonic() + 10.0
        while drv.polls < 3:
            assert time.monotonic() < deadline, "the monitor did not poll within 10 s"
            time.sleep(0.005)
    finally:
        hw.close()
    polls = drv.polls
    assert model.regs[tm.A_CHOPCONF] & 0xF == 0  # disabled at exit
    time.sleep(0.02)
    assert drv.polls == polls  # the monitor stopped


def test_a_failing_driver_closes_the_ones_already_opened(
    bench: SpiBench, monkeypatch: pytest.MonkeyPatch
) -> None:
    bench.chip("tmc2130", cs=0)
    bench.chip("tmc5160", cs=1)
    fake_spidev_module(monkeypatch, bench.kernel)
    good, wrong = TmcSpec("/dev/spidev0.0", S2130), TmcSpec("/dev/spidev0.1", S2130)
    with pytest.raises(TmcError, match=r"m1.*found a TMC5160"):
        open_hardware("mock", spec_with(good, wrong), MonotonicClock())
    assert all(dev._fd == -1 for dev in bench.kernel.opened)  # nothing left open


def test_without_py_spidev_a_configured_driver_says_how_to_install_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setitem(sys.modules, "spidev", None)  # import spidev -> ImportError
    with pytest.raises(HalError, match=r"pip install spidev"):
        open_hardware("mock", spec_with(TmcSpec("/dev/spidev0.0", S2130)), MonotonicClock())
    hw = open_hardware("mock", spec_with(None), MonotonicClock())  # no driver: no spidev needed
    hw.close()


@dataclass
class Report:
    sections: list[tuple[str, list[str]]] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)

    def add(self, title: str, lines: list[str]) -> None:
        self.sections.append((title, lines))


def test_probe_reports_chip_versions_and_drv_status_without_writing(bench: SpiBench) -> None:
    ok = bench.chip("tmc2130", cs=0)
    ok.faults.add(tm.OTPW)
    bench.chip("tmc2130", cs=1)  # configured as a TMC5160 below: a mismatch
    spec = spec_with(
        TmcSpec("/dev/spidev0.0", S2130),
        TmcSpec("/dev/spidev0.1", S5160),
        TmcSpec("/dev/spidev0.2", S2130),  # no such device
    )
    report = Report()
    probe(spec, bench.clock, report, factory=bench.kernel.factory())
    ((title, lines),) = report.sections
    assert title == "SPI stepper drivers"
    text = "\n".join(lines)
    assert "m0: /dev/spidev0.0: TMC2130 (IOIN=0x11000040) ok" in text
    assert "flags: stst otpw" in text and "CS_ACTUAL=" in text
    assert "reset_flag" in text  # the SPI status byte, decoded
    assert "m1: /dev/spidev0.1: TMC2130" in text and "MISMATCH: configured TMC5160" in text
    assert any("/dev/spidev0.2 does not exist" in p for p in report.problems)
    assert any("MISMATCH" in p for p in report.problems)
    assert all(not tx[0] & 0x80 for tx, _ in ok.log)  # reads only
    assert ok.gstat & 1  # GSTAT untouched


# ------------------------------------------------------------------ the config section

TMC_MOTOR = '[[motors]]\nname = "x"\n[motors.tmc]\n'


def config_error(text: str) -> str:
    with pytest.raises(ConfigError) as e:
        parse_config(text, "t.toml")
    return str(e.value)


def test_config_section_maps_to_the_driver_spec() -> None:
    config = parse_config(
        TMC_MOTOR + 'driver = "tmc5160"\nspi = "/dev/spidev1.2"\nmode = "ramp"\n'
        "run_current = 1.5\nhold_current = 0.5\nmicrosteps = 32\nstall_threshold = -4\n"
        "ref_left_active_low = true\n" + '[[motors]]\nname = "y"\n',
        "t.toml",
    )
    spec = driver_spec(config.motors[0])
    assert spec is not None and driver_spec(config.motors[1]) is None
    assert spec.spi == "/dev/spidev1.2" and spec.ramp and spec.ref_left_active_low
    s = spec.settings
    assert (s.chip, s.run_current, s.hold_current, s.microsteps, s.stall_threshold) == (
        "tmc5160",
        1.5,
        0.5,
        32,
        -4,
    )
    axes = hardware_spec(config).axes
    assert axes[0].driver == spec and axes[0].name == "x" and axes[1].driver is None


@pytest.mark.parametrize(
    ("body", "expected"),
    [
        ('mode = "ramp"\n', 'motors[0].tmc.mode = "ramp": the ramp generator is a TMC5160'),
        ("microsteps = 12\n", "motors[0].tmc.microsteps = 12: not a power of two"),
        ("run_current = 5.0\n", "above the 1.74 A a TMC2130 gives with a 0.11 ohm"),
        ('spi = "/dev/spi0"\n', "/dev/spidevB.C"),
        ("hold_current = 2.0\n", "hold_current"),
        (
            'driver = "tmc5160"\nmode = "ramp"\n[motors.homing]\nsource = "stall"\n',
            "stall_min_speed > 0",
        ),
    ],
)
def test_config_section_refuses_what_cannot_work(body: str, expected: str) -> None:
    assert expected in config_error(TMC_MOTOR + body)


def test_config_refuses_one_spi_device_for_two_motors() -> None:
    text = TMC_MOTOR + '[[motors]]\nname = "y"\n[motors.tmc]\nspi = "/dev/spidev0.0"\n'
    assert "motors[1].tmc.spi" in config_error(text)
    assert "also the device of motors[0]" in config_error(text)


def test_a_transient_fault_set_between_two_publications_is_not_lost(bench: SpiBench) -> None:
    bench.chip("tmc2130")
    drv = bench.driver(S2130)
    drv.start()
    drv.poll()
    drv._set_transient("SPI: simulated")  # the monitor latched it, not yet published...
    assert drv.status().fault is None  # ...a reader in between sees the old status
    assert drv._publish(None).fault == "SPI: simulated"  # still reported
    assert drv.status().fault == "SPI: simulated"
    assert drv.poll().fault is None


def test_a_tmc5160_reset_in_ramp_mode_restores_the_ramp_set_up(bench: SpiBench) -> None:
    drv, model = ramp_driver(bench)
    model.power_cycle()
    status = drv.poll()
    assert status.fault is not None and "reset" in status.fault
    assert drv.resets == 1
    assert model.regs[tm.A_VSTOP] >= 10 and model.regs[tm.A_SW_MODE] == drv.sw_mode == 0b100
    assert model.regs[tm.A_RAMPMODE] == 0 and model.regs[tm.A_CHOPCONF] & 0xF == 3
