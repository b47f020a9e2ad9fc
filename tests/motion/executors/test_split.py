"""One seam over several executors (motion/executors/split.py): SplitExecutor routes each
motor and maps the events back, shows the step executor's lateness and process, adds the
parts' counts; with_ramp_motors splits only when a ramp chip is configured, numbers the
step executor's motors among themselves, and the daemon's step executor never gets a motor
that its chip moves itself."""

from __future__ import annotations

import pytest

from motorctl.daemon.config import parse_config
from motorctl.daemon.start.assemble import build_executor, hardware_spec, motor_params
from motorctl.hal.backends.mock.backend import build
from motorctl.hal.backends.mock.world import EventKind, world_of
from motorctl.hal.interfaces import VirtualClock
from motorctl.hal.layers.tmc.settings import TmcSpec
from motorctl.hal.registry import open_step_io
from motorctl.hal.spec import AxisSpec, HardwareSpec
from motorctl.motion.engine import MotionEngine
from motorctl.motion.executors.base import ExecEvent, ExecEventKind
from motorctl.motion.executors.chip_ramp import RampExecutor
from motorctl.motion.executors.split import SplitExecutor, with_ramp_motors
from motorctl.motion.executors.thread import ThreadStepExecutor
from motorctl.motion.profile import plan_move_to
from motorctl.motion.types import MoveToCmd, Ramp
from tests.support.executors import RAMP_SETTINGS, RampRig, RecordingExecutor

K = ExecEventKind
RAMP = Ramp(4000.0, 40_000.0, 40_000.0)


def test_split_executor_routes_motors_and_maps_events_back() -> None:
    steps, ramp = RecordingExecutor(3), RecordingExecutor(1)
    steps.positions = [100, 101, 102]
    split = SplitExecutor([(steps, 0), (ramp, 0), (steps, 2)])
    assert split.motors == 3
    traj = plan_move_to(0.0, 0.0, 0.0, 10.0, 100.0, 1e3, 1e3)
    split.follow(1, traj, RAMP, 1)
    split.follow(2, traj, RAMP, 1)
    assert [c[:2] for c in ramp.calls] == [("follow", 0)]
    assert [c[:2] for c in steps.calls] == [("follow", 2)]
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

    class Steps(RecordingExecutor):
        pid = 4242
        stats = LatencyStats()

        def step_lateness(self) -> LatencyStats:
            return self.stats

    ramp, steps = RecordingExecutor(1), Steps(1)
    assert SplitExecutor([(ramp, 0)]).step_lateness() is None
    assert SplitExecutor([(ramp, 0)]).pid is None
    split = SplitExecutor([(ramp, 0), (steps, 0)])
    assert split.step_lateness() is steps.stats and split.pid == 4242


def test_split_executor_adds_counts_but_keeps_the_smallest_gap() -> None:
    from motorctl.motion.executors.base import ExecutorHealth

    class Counting(RecordingExecutor):
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


def test_with_ramp_motors_splits_only_when_a_ramp_chip_is_configured() -> None:
    rig = RampRig()
    steps = RecordingExecutor(2)
    assert with_ramp_motors(steps, [object(), object()], rig.clock) is steps
    split = with_ramp_motors(steps, [object(), rig.chips[0]], rig.clock)
    assert isinstance(split, SplitExecutor)
    assert split.routes[0] == (steps, 0)
    ramp_ex, local = split.routes[1]
    assert isinstance(ramp_ex, RampExecutor) and local == 0 and ramp_ex.chips == rig.chips


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
    ramp = TmcSpec("/dev/spidev0.0", RAMP_SETTINGS, ramp=True)
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
    hw.poller.forget(hw.steppers[1].driver)
    hw.steppers[1].driver = rig.chips[0]  # what attach_drivers does with the real chip
    hw.poller.watch(rig.chips[0], "z")
    hw.poller.period_s = 0.005
    params = motor_params(config)
    ex = build_executor(config, hw, spec, params)
    assert isinstance(ex, SplitExecutor)
    steps, local = ex.routes[0]
    assert isinstance(steps, ThreadStepExecutor) and local == 0
    assert steps.io.outputs.motors == 1 and len(steps.positions) == 1  # no slot for z
    ramp_ex, local = ex.routes[1]
    assert isinstance(ramp_ex, RampExecutor) and local == 0
    engine = MotionEngine(hw, params, ex)
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
    split = with_ramp_motors(RecordingExecutor(1), [rig.chips[0], object()], rig.clock)
    assert isinstance(split, SplitExecutor) and split.routes[1][1] == 0  # its own numbering


def test_a_split_times_steps_when_a_part_does() -> None:
    rig = RampRig()
    steps = RecordingExecutor(1)
    assert rig.ex.times_steps is False and steps.times_steps is True
    assert SplitExecutor([(rig.ex, 0)]).times_steps is False
    assert SplitExecutor([(rig.ex, 0), (steps, 0)]).times_steps is True
    rig.ex.close()
