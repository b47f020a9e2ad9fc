"""The TMC5160 ramp executor and the split executor, on register-level chip models and a
virtual clock: the seam alone, then the motion engine driving motors through it."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import pytest

from motorctl.daemon.assemble import build_executor, hardware_spec, motor_params
from motorctl.daemon.config import parse_config
from motorctl.hal.backends.mock.backend import EventKind, build, world_of
from motorctl.hal.backends.tmc.ramp import RefSwitches, Tmc5160
from motorctl.hal.backends.tmc.settings import TmcSettings, TmcSpec
from motorctl.hal.backends.tmc.spi import SpiAddress, SpiBuses, SpiDevice
from motorctl.hal.interfaces import VirtualClock
from motorctl.hal.registry import open_step_io
from motorctl.hal.spec import AxisSpec, HardwareSpec
from motorctl.motion.engine import MotionEngine
from motorctl.motion.executors.base import ExecEvent, ExecEventKind, Executor
from motorctl.motion.executors.chip_ramp import RampExecutor, peak_speed
from motorctl.motion.executors.split import SplitExecutor, with_ramp_motors
from motorctl.motion.executors.thread import ThreadStepExecutor
from motorctl.motion.profile import plan_move_to, plan_run
from motorctl.motion.types import (
    HomeCmd,
    HomingParams,
    HomingSource,
    MotorParams,
    MotorState,
    MoveToCmd,
    Ramp,
    RunCmd,
)
from tests.support.rigs import engine_rig
from tests.support.spi_bench import SpiBench
from tests.support.tmc_model import A_CHOPCONF, A_VMAX, A_XTARGET, FakeKernel, TmcModel

K = ExecEventKind
RAMP = Ramp(4000.0, 40_000.0, 40_000.0)
SETTINGS = TmcSettings(
    chip="tmc5160", run_current=2.0, hold_current=1.0, microsteps=16, stall_min_speed=500.0
)


class RampRig:
    """n TMC5160 models on /dev/spidev0.x, started as ramp chips, and a RampExecutor."""

    def __init__(self, n: int = 1) -> None:
        self.bench = SpiBench()
        self.clock = self.bench.clock
        self.kernel = self.bench.kernel
        self.models: list[TmcModel] = []
        self.chips: list[Tmc5160] = []
        for i in range(n):
            model = self.bench.chip("tmc5160", cs=i)
            chip = Tmc5160(f"m{i}", self.bench.device(i, speed=1_000_000), SETTINGS, RefSwitches())
            chip.start()
            self.models.append(model)
            self.chips.append(chip)
        self.ex = RampExecutor(self.chips, self.clock, poll_s=0.002, idle_poll_s=0.02)
        self.ex.start()
        self.seen: list[ExecEvent] = []

    def run(self, until: Callable[[], bool], limit_s: float) -> float:
        """Service the executor on the virtual clock until ``until()``; the time it took."""
        t0 = self.clock.now()
        while True:
            self.seen += self.ex.events()
            if until():
                return self.clock.now() - t0
            assert self.clock.now() - t0 < limit_s, f"not done within {limit_s} s"
            nxt = self.ex.service(self.clock.now())
            self.clock.advance_to(max(nxt, self.clock.now() + 1e-4))

    def kinds(self) -> list[ExecEventKind]:
        return [e.kind for e in self.seen]


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


class Recorder(Executor):
    """A stand-in executor that records what it is asked to do."""

    def __init__(self, motors: int) -> None:
        super().__init__(motors)
        self.calls: list[tuple[str, int]] = []
        self.pending: list[ExecEvent] = []

    def follow(self, motor, traj, ramp, gen, endstops=True):  # type: ignore[no-untyped-def]
        self.calls.append(("follow", motor))
        return True

    def stop(self, motor: int, gen: int) -> int | None:
        self.calls.append(("stop", motor))
        return 0

    def committed(self, motor, now):  # type: ignore[no-untyped-def]
        raise AssertionError

    def service(self, now: float) -> float:
        return now + 1.0

    def events(self) -> list[ExecEvent]:
        out, self.pending = self.pending, []
        return out

    def planned(self, motor: int) -> bool:
        return False

    def position(self, motor: int) -> int:
        return 100 + motor

    def endstop_active(self, motor: int, direction: int) -> bool:
        return False

    def health(self):  # type: ignore[no-untyped-def]
        from motorctl.motion.executors.base import ExecutorHealth

        return ExecutorHealth(True, 1)


def test_split_executor_routes_motors_and_maps_events_back() -> None:
    steps, ramp = Recorder(3), Recorder(1)
    split = SplitExecutor([(steps, 0), (ramp, 0), (steps, 2)])
    assert split.motors == 3
    traj = plan_move_to(0.0, 0.0, 0.0, 10.0, 100.0, 1e3, 1e3)
    split.follow(1, traj, RAMP, 1)
    split.follow(2, traj, RAMP, 1)
    assert ramp.calls == [("follow", 0)] and steps.calls == [("follow", 2)]
    assert split.position(2) == 102
    steps.pending = [
        ExecEvent(K.DONE, 2, 1, 10, 0.0),
        ExecEvent(K.DONE, 1, 1, 10, 0.0),  # motor 1 of the step executor is not routed
        ExecEvent(K.DIED, -1, 0, 0, 0.0, detail="gone"),
    ]
    evs = split.events()
    # a part's death is the executor's: DIED for every motor (the engine faults them all
    # and the daemon exits 3), not faults of a few motors that leave the daemon running
    assert [(e.kind, e.motor) for e in evs] == [(K.DONE, 2), (K.DIED, -1)]
    assert evs[-1].detail == "gone"
    with pytest.raises(ValueError, match="taken"):
        SplitExecutor([(steps, 0), (steps, 0)])


def test_split_executor_shows_the_step_executors_lateness_and_process() -> None:
    from motorctl.motion.latency import LatencyStats

    class Steps(Recorder):
        pid = 4242
        stats = LatencyStats()

        def step_lateness(self) -> LatencyStats:
            return self.stats

    ramp, steps = Recorder(1), Steps(1)
    assert SplitExecutor([(ramp, 0)]).step_lateness() is None
    assert SplitExecutor([(ramp, 0)]).pid is None
    split = SplitExecutor([(ramp, 0), (steps, 0)])
    assert split.step_lateness() is steps.stats and split.pid == 4242


def test_split_executor_adds_counts_but_keeps_the_smallest_gap() -> None:
    from motorctl.motion.executors.base import ExecutorHealth

    class Counting(Recorder):
        def __init__(self, counters: dict[str, int]) -> None:
            super().__init__(1)
            self.counters = counters

        def health(self) -> ExecutorHealth:
            return ExecutorHealth(True, 1, counters=dict(self.counters))

    a = Counting({"steps": 10, "endstops": 1, "min_gap_ns": 90_000})
    b = Counting({"steps": 5, "endstops": 2, "min_gap_ns": 40_000})
    none = Counting({"steps": 0, "min_gap_ns": 0})  # no gap seen yet
    c = SplitExecutor([(a, 0), (none, 0), (b, 0)]).health().counters
    assert c == {"steps": 15, "endstops": 3, "min_gap_ns": 40_000}
    assert SplitExecutor([(none, 0), (a, 0)]).health().counters["min_gap_ns"] == 90_000
    assert SplitExecutor([(none, 0)]).health().counters["min_gap_ns"] == 0


# ------------------------------------------------------------------ through the engine


def ramp_engine(homing: HomingParams | None = None) -> tuple[RampRig, MotionEngine]:
    rig = RampRig()
    engine = engine_rig(
        MotorParams(homing=homing or HomingParams()),
        axes=[AxisSpec()],
        clock=rig.clock,
        driver_poll_s=0.005,
        drivers=rig.chips,
        executor=lambda hw, spec, params: rig.ex,
    ).engine
    return rig, engine


def poll_drivers(rig: RampRig, engine: MotionEngine, seconds: float) -> None:
    """Run the engine with the driver monitor's polls (virtual time)."""
    end = rig.clock.now() + seconds
    while rig.clock.now() < end:
        rig.chips[0].poll()
        engine.run_until(rig.clock.now() + 0.005)


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


def test_engine_homing_on_the_chips_reference_switch() -> None:
    rig, engine = ramp_engine(HomingParams(max_travel=20_000))
    rig.models[0].ref_l_at = -3000.0
    m = engine.motors[0]
    with engine.lock:
        m.submit(HomeCmd(-1, RAMP), rig.clock.now())
    engine.run_until_idle(10.0)
    assert m.fault is None and m.state is MotorState.IDLE
    assert m.position == pytest.approx(0, abs=2)  # at the switch
    with engine.lock:
        m.submit(MoveToCmd(1000, RAMP), rig.clock.now())
    engine.run_until_idle(10.0)
    assert rig.models[0].physical == pytest.approx(-3000 + 1000, abs=3)


def test_engine_stall_homing_with_the_chips_stallguard_stop() -> None:
    homing = HomingParams(source=HomingSource.STALL, max_travel=20_000)
    rig, engine = ramp_engine(homing)
    rig.models[0].wall_at = 2200.0
    m = engine.motors[0]
    with engine.lock:
        m.submit(HomeCmd(1, RAMP), rig.clock.now())
    deadline = rig.clock.now() + 10.0
    while m.state is not MotorState.IDLE:
        assert rig.clock.now() < deadline, "stall homing did not finish"
        poll_drivers(rig, engine, 0.01)
    assert m.fault is None
    assert rig.models[0].physical == pytest.approx(2200, abs=10)
    assert m.position == 0


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


def test_with_ramp_motors_splits_only_when_a_ramp_chip_is_configured() -> None:
    rig = RampRig()
    steps = Recorder(2)
    assert with_ramp_motors(steps, [object(), object()], rig.clock) is steps
    split = with_ramp_motors(steps, [object(), rig.chips[0]], rig.clock)
    assert isinstance(split, SplitExecutor)
    assert split.routes[0] == (steps, 0)
    ramp_ex, local = split.routes[1]
    assert isinstance(ramp_ex, RampExecutor) and local == 0 and ramp_ex.chips == rig.chips


def test_a_chip_reset_faults_the_axis_with_its_position_lost() -> None:
    rig, engine = ramp_engine()
    m = engine.motors[0]
    with engine.lock:
        m.submit(MoveToCmd(8000, RAMP), rig.clock.now())
    engine.run_until(rig.clock.now() + 0.3)
    rig.models[0].power_cycle()
    for _ in range(20):
        rig.chips[0].poll()  # the driver monitor notices, reconfigures the chip
        engine.run_until(rig.clock.now() + 0.01)
    assert m.state is MotorState.FAULT and m.position_lost
    assert m.fault is not None and "reset" in m.fault


def test_positions_are_xactual_from_construction_for_a_restore_before_start() -> None:
    rig = RampRig()
    rig.chips[0].set_position(12_345)  # where an earlier daemon left the chip
    ex = RampExecutor(rig.chips, rig.clock)
    assert ex.position(0) == 12_345  # before start(): the daemon restores offsets now


# ------------------------------------- the step executor never gets a motor the chip moves itself

MIXED = """
[[motors]]
name = "x"

[[motors]]
name = "z"
  [motors.tmc]
  driver = "tmc5160"
  spi = "/dev/spidev0.0"
  mode = "ramp"
"""


def test_the_mock_step_io_leaves_out_a_ramp_axis() -> None:
    ramp = TmcSpec("/dev/spidev0.0", SETTINGS, ramp=True)
    spec = HardwareSpec((AxisSpec(driver=ramp), AxisSpec()))
    assert spec.stepped() == (1,)
    clock = VirtualClock()
    hw = build(spec, clock)
    io = open_step_io("mock", spec, clock, parent=hw)
    assert io.outputs.motors == 1 and io.endstops == ((2, 3),)  # axis 1's end stops
    io.outputs.set_direction(0, True)
    clock.advance_to(clock.now() + 1e-3)
    io.outputs.pulse([0], 2e-6)
    world = world_of(hw)
    assert [a.position for a in world.axes] == [0, 1]
    assert [e.index for e in world.timeline.of(EventKind.STEP)] == [1]
    io.close()
    hw.close()


def test_the_daemon_gives_the_step_executor_only_the_stepped_motors() -> None:
    rig = RampRig()
    config = parse_config(MIXED, "mixed.toml")
    spec = hardware_spec(config)
    hw = build(spec, rig.clock)
    hw.steppers[1].driver = rig.chips[0]  # what attach_drivers does with the real chip
    params = motor_params(config)
    ex = build_executor(config, hw, spec, params)
    assert isinstance(ex, SplitExecutor)
    steps, local = ex.routes[0]
    assert isinstance(steps, ThreadStepExecutor) and local == 0
    assert steps.io.outputs.motors == 1 and len(steps.positions) == 1  # no slot for z
    ramp_ex, local = ex.routes[1]
    assert isinstance(ramp_ex, RampExecutor) and local == 0
    engine = MotionEngine(hw, params, ex, driver_poll_s=0.005)
    x, z = engine.motors
    with engine.lock:
        x.submit(MoveToCmd(300, RAMP), rig.clock.now())
        z.submit(MoveToCmd(-2000, RAMP), rig.clock.now())
    engine.run_until_idle(10.0)
    assert (x.position, z.position) == (300, -2000)
    world = world_of(hw)
    assert [a.position for a in world.axes] == [300, 0]  # z was never stepped
    assert {e.index for e in world.timeline.of(EventKind.STEP)} == {0}
    assert rig.models[0].physical == pytest.approx(-2000, abs=0.5)
    ex.close()
    hw.close()


def test_a_machine_of_ramp_motors_only_has_no_step_executor() -> None:
    rig = RampRig(2)
    assert with_ramp_motors(None, rig.chips, rig.clock) is not None
    assert isinstance(with_ramp_motors(None, rig.chips, rig.clock), RampExecutor)
    with pytest.raises(ValueError, match=r"motors \[1\] need a step executor"):
        with_ramp_motors(None, [rig.chips[0], object()], rig.clock)
    split = with_ramp_motors(Recorder(1), [rig.chips[0], object()], rig.clock)
    assert isinstance(split, SplitExecutor) and split.routes[1][1] == 0  # its own numbering


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
    dev = SpiDevice(SpiAddress(0, 0), SpiBuses(), kernel.factory(), 1_000_000)
    chip = Tmc5160("m", dev, replace(SETTINGS, microsteps=microsteps), RefSwitches())
    chip.start()
    assert model.reg(A_CHOPCONF) >> 24 & 0xF == mres
    hw = build(HardwareSpec((AxisSpec(),)), clock)
    hw.steppers[0].driver = chip
    engine = MotionEngine(hw, [MotorParams()], RampExecutor([chip], clock), driver_poll_s=0.005)
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
