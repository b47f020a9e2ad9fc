"""The TMC5160 ramp executor (motion/executors/chip_ramp.py) on register-level chip models
and a virtual clock (tests/support/executors.py's RampRig): the seam alone, then the motion
engine driving a motor through it, and a protocol step as one XACTUAL microstep."""

from __future__ import annotations

from dataclasses import replace

import pytest

from motorctl.hal.backends.mock.backend import build
from motorctl.hal.interfaces import VirtualClock
from motorctl.hal.layers.tmc.tmc5160 import RefSwitches, Tmc5160
from motorctl.hal.spec import AxisSpec, HardwareSpec
from motorctl.hal.spi import SpiAddress, SpiBus, SpiSettings
from motorctl.motion.engine import MotionEngine
from motorctl.motion.executors.base import ENDSTOP_ALREADY_ACTIVE, ExecEventKind
from motorctl.motion.executors.chip_ramp import RampExecutor, peak_speed
from motorctl.motion.profile import plan_move_to, plan_run
from motorctl.motion.types import (
    HomeCmd,
    HomingParams,
    HomingSource,
    MotorState,
    MoveToCmd,
    Ramp,
    RunCmd,
)
from tests.support.executors import RAMP_SETTINGS, RampRig
from tests.support.motor_defaults import motor_params
from tests.support.rigs import engine_rig
from tests.support.tmc_model import A_CHOPCONF, A_VMAX, A_XTARGET, FakeKernel, TmcModel

K = ExecEventKind
RAMP = Ramp(4000.0, 40_000.0, 40_000.0)


def test_a_move_runs_on_the_chip_and_reports_done() -> None:
    rig = RampRig()
    traj = plan_move_to(rig.clock.now(), 0.0, 0.0, 6000.0, RAMP.speed, RAMP.acc, RAMP.dec)
    assert rig.ex.follow(0, traj, RAMP, gen=1)
    assert rig.ex.planned(0)
    took = rig.run(lambda: K.DONE in rig.kinds(), 5.0)
    done = rig.seen[-1]
    assert (done.motor, done.gen, done.position) == (0, 1, 6000)
    assert rig.ex.position(0) == 6000 and not rig.ex.planned(0)
    assert took == pytest.approx(traj.end_time - traj.start_time, abs=0.02)
    # a plan to where it already is makes no step
    again = plan_move_to(rig.clock.now(), 6000.0, 0.0, 6000.0, 4000.0, 4e4, 4e4)
    assert rig.ex.follow(0, again, RAMP, gen=2) is False


def test_the_peak_speed_of_a_plan_becomes_vmax() -> None:
    rig = RampRig()
    slow = plan_run(rig.clock.now(), 0.0, 0.0, 250.0, 4e4, 4e4, 2000.0)  # to a limit at 2000
    assert peak_speed(slow) == pytest.approx(250.0)
    rig.ex.follow(0, slow, RAMP, gen=1)
    assert rig.chips[0].units.steps_s(rig.models[0].regs[0x27]) == pytest.approx(250, abs=1)
    rig.run(lambda: K.DONE in rig.kinds(), 15.0)
    assert rig.ex.position(0) == 2000


def test_a_run_and_a_hard_stop_report_stopped_with_the_final_position() -> None:
    rig = RampRig()
    run = plan_run(rig.clock.now(), 0.0, 0.0, -3000.0, 30_000.0, 30_000.0, None)
    rig.ex.follow(0, run, RAMP, gen=1)
    assert rig.models[0].regs[0x20] == 2  # RAMPMODE: velocity, negative
    rig.run(lambda: rig.ex.position(0) < -2000, 5.0)
    assert rig.ex.stop(0, gen=2) is None
    rig.run(lambda: K.STOPPED in rig.kinds(), 1.0)
    stopped = rig.seen[-1]
    assert stopped.gen == 2 and stopped.position == rig.chips[0].position()
    assert not rig.ex.planned(0)


def test_the_reference_switch_ahead_stops_the_chip_and_reports_where_it_tripped() -> None:
    rig = RampRig()
    rig.models[0].ref_l_at = -1500.0
    run = plan_run(rig.clock.now(), 0.0, 0.0, -4000.0, 40_000.0, 40_000.0, None)
    rig.ex.follow(0, run, RAMP, gen=1)
    rig.run(lambda: K.ENDSTOP in rig.kinds(), 5.0)
    ev = rig.seen[-1]
    assert (ev.direction, ev.position) == (-1, -1500)  # XLATCH: the switch's edge
    assert rig.ex.endstop_active(0, -1) and not rig.ex.endstop_active(0, 1)
    # until the caller answers with stop(), plans for the axis are dropped
    away = plan_move_to(rig.clock.now(), -1500.0, 0.0, 0.0, 4000.0, 4e4, 4e4)
    assert rig.ex.follow(0, away, RAMP, gen=2) is True
    assert rig.models[0].regs[0x20] != 0  # not positioning: nothing was sent
    rig.ex.stop(0, gen=3)
    rig.run(lambda: K.STOPPED in rig.kinds(), 1.0)
    rig.ex.follow(0, away, RAMP, gen=4)  # leaving the switch upward is allowed
    rig.run(lambda: rig.seen[-1].kind is K.DONE, 5.0)
    assert rig.ex.position(0) == 0


def on_the_switch(rig: RampRig, side: int) -> TmcModel:
    """Motor 0's chip model standing on its reference switch on ``side`` (-1: REFL, at and
    below 5; 1: REFR, at and above -5), at 0."""
    model = rig.models[0]
    if side < 0:
        model.ref_l_at = 5.0
    else:
        model.ref_r_at = -5.0
    return model


@pytest.mark.parametrize("side", [-1, 1])
def test_a_motion_toward_a_switch_active_already_is_not_sent_to_the_chip(side: int) -> None:
    """On the switch (the read the motion starts from, ``committed()``, says it is active):
    ENDSTOP at once where it stands, "already active", and no datagram written to the chip;
    the other way the chip moves as ever."""
    rig = RampRig()
    model = on_the_switch(rig, side)
    rig.ex.committed(0, rig.clock.now())
    writes = sum(1 for tx, _ in model.log if tx[0] & 0x80)
    toward = plan_run(rig.clock.now(), 0.0, 0.0, 3000.0 * side, 3e4, 3e4, None)
    assert rig.ex.follow(0, toward, RAMP, gen=1)
    rig.run(lambda: K.ENDSTOP in rig.kinds(), 1.0)
    ev = rig.seen[-1]
    assert (ev.gen, ev.position, ev.direction, ev.detail) == (1, 0, side, ENDSTOP_ALREADY_ACTIVE)
    assert sum(1 for tx, _ in model.log if tx[0] & 0x80) == writes
    rig.ex.stop(0, gen=2)
    rig.run(lambda: rig.seen[-1].kind is K.STOPPED, 1.0)
    rig.ex.committed(0, rig.clock.now())
    away = plan_move_to(rig.clock.now(), 0.0, 0.0, -2000.0 * side, 4000.0, 4e4, 4e4)
    assert rig.ex.follow(0, away, RAMP, gen=3)
    rig.run(lambda: rig.seen[-1].kind is K.DONE, 5.0)
    assert rig.ex.position(0) == -2000 * side


@pytest.mark.parametrize("side", [-1, 1])
def test_a_back_off_stops_the_chip_where_the_switch_behind_releases(side: int) -> None:
    """Homing's back-off (``release``): the switch it leaves latches the position at its
    inactive edge; once a poll sees it released the executor stops the chip and reports
    RELEASED with that position (``mark``), the chip standing a little further on."""
    rig = RampRig()
    model = on_the_switch(rig, side)
    away = plan_run(rig.clock.now(), 0.0, 0.0, -250.0 * side, 4e4, 4e4, -5000.0 * side)
    assert rig.ex.follow(0, away, RAMP, gen=1, release=True)
    sw = model.regs[0x34]
    assert sw & (1 << (6 if side < 0 else 8))  # SW_MODE.latch_l/r_inactive
    assert sw & (0b10 if side < 0 else 0b01)  # and the stop switch ahead, as any move's
    rig.run(lambda: K.RELEASED in rig.kinds(), 5.0)
    ev = rig.seen[-1]
    # XLATCH: the first microstep off the switch
    assert (ev.direction, ev.mark, ev.detail) == (side, -6 * side, "reference switch")
    assert side * (ev.mark - ev.position) >= 0  # it stood at or past the release
    assert not rig.ex.endstop_active(0, side)
    rig.ex.stop(0, gen=2)  # the answer
    rig.run(lambda: rig.seen[-1].kind is K.STOPPED, 1.0)
    assert 0 <= side * (ev.mark - rig.ex.position(0)) <= 3  # a few steps on at 250 step/s


def test_a_plan_without_end_stops_arms_stallguard_and_a_stop_reads_as_a_stall() -> None:
    rig = RampRig()
    rig.models[0].wall_at = 2500.0
    run = plan_run(rig.clock.now(), 0.0, 0.0, 4000.0, 40_000.0, 40_000.0, None)
    rig.ex.follow(0, run, RAMP, gen=1, endstops=False)
    assert rig.models[0].regs[0x34] & (1 << 10)  # SW_MODE.sg_stop
    rig.run(lambda: rig.chips[0].sg_stopped, 5.0)
    assert rig.models[0].physical == pytest.approx(2500, abs=10)
    assert rig.chips[0].status().stall is True  # what the engine's driver monitor sees
    rig.ex.stop(0, gen=2)
    rig.ex.follow(0, plan_move_to(rig.clock.now(), 2500.0, 0.0, 0.0, 4e3, 4e4, 4e4), RAMP, 3)
    assert rig.chips[0].status().stall is False  # the next plan re-arms


def test_spi_errors_become_fault_events_never_exceptions() -> None:
    rig = RampRig()
    traj = plan_move_to(rig.clock.now(), 0.0, 0.0, 6000.0, RAMP.speed, RAMP.acc, RAMP.dec)
    rig.ex.follow(0, traj, RAMP, gen=1)
    rig.kernel.fail_xfers = 1000
    rig.run(lambda: K.FAULT in rig.kinds(), 1.0)
    fault = rig.seen[-1]
    assert "/dev/spidev0.0" in fault.detail and "Input/output error" in fault.detail
    assert rig.ex.follow(0, traj, RAMP, gen=2) is True  # dropped until stop(): no raise
    assert rig.ex.stop(0, gen=3) == rig.ex.position(0)  # final at once: no further event
    assert rig.ex.events() == []
    assert rig.ex.health().alive and rig.ex.counters["spi_errors"] >= 2


# ------------------------------------------------------------------ through the engine


def ramp_engine(homing: HomingParams | None = None) -> tuple[RampRig, MotionEngine]:
    rig = RampRig()
    engine = engine_rig(
        motor_params(homing=homing or HomingParams()),
        axes=[AxisSpec()],
        clock=rig.clock,
        driver_poll_s=0.005,
        drivers=rig.chips,
        executor=lambda hw, spec, params: rig.ex,
    ).engine
    return rig, engine


def test_engine_moveto_and_getabspos_through_the_chip() -> None:
    rig, engine = ramp_engine()
    m = engine.motors[0]
    with engine.lock:
        m.submit(MoveToCmd(5000, RAMP), rig.clock.now())
    engine.run_until_idle(10.0)
    assert m.position == 5000 and rig.models[0].physical == pytest.approx(5000, abs=0.5)
    with engine.lock:
        m.submit(RunCmd(-1, RAMP), rig.clock.now())
    engine.run_until(rig.clock.now() + 0.5)
    with engine.lock:
        assert m.stop(hard=False, now=rig.clock.now())
    engine.run_until_idle(10.0)
    assert m.state is MotorState.IDLE
    assert m.position == rig.chips[0].position()


#: the homing kinds on the chip: its reference switch (with and without the second
#: approach), its stallGuard stop (the re-approach above the chip's stall_min_speed)
CHIP_HOMING = {
    "endstop": HomingParams(max_travel=20_000),
    "endstop_pull_off": HomingParams(max_travel=20_000, pull_off=200, second_speed=300.0),
    "stall": HomingParams(source=HomingSource.STALL, max_travel=20_000),
    "stall_pull_off": HomingParams(
        source=HomingSource.STALL, max_travel=20_000, pull_off=200, second_speed=1000.0
    ),
}


@pytest.mark.parametrize("direction", [1, -1])
@pytest.mark.parametrize("kind", list(CHIP_HOMING))
def test_engine_homing_through_the_chip_then_moveto_0_stays_off_the_switch(
    kind: str, direction: int
) -> None:
    homing = CHIP_HOMING[kind]
    rig, engine = ramp_engine(homing)
    model = rig.models[0]
    endstop = homing.source is HomingSource.ENDSTOP
    if endstop and direction < 0:
        model.ref_l_at = -3000.0
    elif endstop:
        model.ref_r_at = 3000.0
    elif direction < 0:
        model.wall_low_at = -3000.0
    else:
        model.wall_at = 3000.0
    m = engine.motors[0]
    with engine.lock:
        m.submit(HomeCmd(direction, RAMP), rig.clock.now())
    deadline = rig.clock.now() + 20.0
    while not m.idle and m.fault is None:
        assert rig.clock.now() < deadline, "homing did not finish"
        engine.run_until(rig.clock.now() + 0.01)  # the driver poller's reads among the rest
    assert m.fault is None
    # the chip stands where it stopped: at the stall, or braked a few steps past the release
    assert 0 <= -direction * m.position <= (3 if endstop else 0)
    for target in (-direction * 1500, 0):  # away, and back (WaitMoved)
        with engine.lock:
            m.submit(MoveToCmd(target, RAMP), rig.clock.now())
        while not m.idle and m.fault is None:
            assert rig.clock.now() < deadline + 20.0, "the move did not finish"
            engine.run_until(rig.clock.now() + 0.01)  # the driver poller's reads among the rest
    assert m.fault is None  # no E4: neither the switch nor a stall on the way back
    assert m.position == 0  # GetAbsPos
    if endstop:  # zero: the first microstep off the switch (the model's positions are real)
        assert 0 < direction * (direction * 3000 - model.physical) <= 1
        assert not model.switch_active(direction < 0)
    else:  # zero: where it stalled, at the hard stop
        assert model.physical == pytest.approx(direction * 3000, abs=0.5)


def test_engine_homing_fails_when_the_chips_switch_does_not_release() -> None:
    rig, engine = ramp_engine(HomingParams(max_travel=2000))
    rig.models[0].ref_l_at = 10_000.0  # REFL active everywhere this homing reaches
    m = engine.motors[0]
    with engine.lock:
        m.submit(HomeCmd(-1, RAMP), rig.clock.now())
    engine.run_until(rig.clock.now() + 20.0)
    assert m.state is MotorState.FAULT and m.faults == {"homing": 1}
    assert m.fault == "homing failed: end stop still active after backing off 2000 steps"
    assert rig.chips[0].position() == 2000  # backed off max_travel, and no further


def test_engine_faults_on_spi_failure_without_raising() -> None:
    rig, engine = ramp_engine()
    m = engine.motors[0]
    with engine.lock:
        m.submit(MoveToCmd(50_000, RAMP), rig.clock.now())
    engine.run_until(rig.clock.now() + 0.2)
    rig.kernel.fail_xfers = 10_000
    engine.run_until(rig.clock.now() + 0.2)
    assert m.state is MotorState.FAULT and m.position_lost
    assert m.fault is not None and "/dev/spidev0.0" in m.fault


def test_a_chip_reset_faults_the_axis_with_its_position_lost() -> None:
    rig, engine = ramp_engine()
    m = engine.motors[0]
    with engine.lock:
        m.submit(MoveToCmd(8000, RAMP), rig.clock.now())
    engine.run_until(rig.clock.now() + 0.3)
    rig.models[0].power_cycle()
    engine.run_until(rig.clock.now() + 0.2)  # the driver poller notices, reconfigures the chip
    assert m.state is MotorState.FAULT and m.position_lost
    assert m.fault is not None and "reset" in m.fault


def test_positions_are_xactual_from_construction_for_a_restore_before_start() -> None:
    rig = RampRig()
    rig.chips[0].set_position(12_345)  # where an earlier daemon left the chip
    ex = RampExecutor(rig.chips, rig.clock)
    assert ex.position(0) == 12_345  # before start(): the daemon restores offsets now


# ------------------------------------------ units: a protocol step is one XACTUAL microstep


@pytest.mark.parametrize(("microsteps", "mres"), [(16, 4), (256, 0)])
def test_a_protocol_step_is_one_xactual_microstep_at_the_configured_resolution(
    microsteps: int, mres: int
) -> None:
    """TMC5160A datasheet Rev. 1.14: XACTUAL/XTARGET and VMAX count microsteps of the
    sequencer input (12.1, p. 81), each 2^MRES sine-table entries (CHOPCONF.MRES, 6.5.2,
    p. 51), 256 entries a full step. So XTARGET is the protocol position unscaled, VMAX does
    not depend on the resolution, and two full steps are 2 * microsteps protocol steps."""
    clock = VirtualClock()
    kernel = FakeKernel()
    model = TmcModel("tmc5160", clock=clock)
    kernel.chips[(0, 0)] = model
    dev = SpiBus(SpiAddress(0, 0), SpiSettings(1_000_000), kernel.factory())
    chip = Tmc5160("m", dev, replace(RAMP_SETTINGS, microsteps=microsteps), RefSwitches())
    chip.start()
    assert model.reg(A_CHOPCONF) >> 24 & 0xF == mres
    hw = build(HardwareSpec((AxisSpec(),)), clock)
    hw.steppers[0].driver = chip
    engine = MotionEngine(hw, [motor_params()], RampExecutor([chip], clock))
    m = engine.motors[0]
    target = 2 * microsteps  # two full steps
    with engine.lock:
        m.submit(MoveToCmd(target, Ramp(1000.0, 100_000.0, 100_000.0)), clock.now())
    engine.run_until(clock.now() + 0.005)
    assert model.reg(A_XTARGET) == target
    assert model.reg(A_VMAX) == round(1000.0 * 2**24 / 12e6)  # 1398 at either resolution
    engine.run_until_idle(10.0)
    assert m.position == target == chip.position() == round(model.x)  # XACTUAL over SPI
    assert model.mscnt() == 512  # 2 full steps of 256 table entries: the motor moved 2 steps
    hw.close()
