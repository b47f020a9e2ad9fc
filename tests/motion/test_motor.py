"""One stepper motor (motion/motor.py): its state machine, queue, stops, homing, limits,
faults and positions.

First the motor alone against a stand-in executor (tests/support/executors.py's
RecordingExecutor): its side of the executor's contract (motion/executors/base.py) -- each
plan starts where the executor committed, with a new generation; events of replaced plans
are ignored; an axis the executor stopped on its own is answered with a stop before anything
else, and what stopped it decides the fault and whether the position is lost; a hard stop
waits for the executor's confirmation. Then the motor over the mock world on a virtual clock
(tests/support/rigs.py's engine_rig: the engine, the thread step executor, the mock's
mechanics), where what it does shows as steps.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from motorctl.hal.backends.mock.backend import build
from motorctl.hal.backends.mock.world import EventKind, MockWorld, mock_axis, world_of
from motorctl.hal.interfaces import DriverStatus, VirtualClock
from motorctl.hal.spec import AxisSpec, HardwareSpec
from motorctl.motion.executors.base import ExecEvent, ExecEventKind
from motorctl.motion.motor import Motor
from motorctl.motion.profile import Trajectory
from motorctl.motion.types import (
    HomeCmd,
    HomingParams,
    HomingSource,
    MotionCmd,
    MotorParams,
    MotorState,
    MoveToCmd,
    Ramp,
    RunCmd,
)
from motorctl.protocol.codec import wrap24
from tests.support.executors import RecordingExecutor
from tests.support.motor_defaults import motor_params
from tests.support.rigs import engine_rig, planned_times

FAST = settings(max_examples=40, deadline=None)
RAMP = Ramp(2000.0, 8000.0, 8000.0)
POLL = 0.01
K = ExecEventKind
TICK = 2e-9  # step times are whole nanoseconds: a gap may be 1 ns off


# ---------------------------------------------------------------- the motor alone


def alone(
    params: MotorParams | None = None, *, stops_at_once: bool = True
) -> tuple[Motor, RecordingExecutor, list[str], MockWorld]:
    """A motor over a stand-in executor and a mock driver; the events it notifies."""
    ex = RecordingExecutor(1, stops_at_once=stops_at_once)
    hw = build(HardwareSpec(axes=(AxisSpec(),)), VirtualClock())
    notes: list[str] = []
    m = Motor(0, params or motor_params(), hw.steppers[0].driver, ex, lambda _, e: notes.append(e))
    return m, ex, notes, world_of(hw)


def state(m: Motor) -> MotorState:
    """The motor's state, read afresh (a call, so type checkers do not pin it)."""
    return m.state


def followed(ex: RecordingExecutor) -> list[tuple[int, Trajectory, bool]]:
    """(generation, plan, end stops watched) of each follow()."""
    return [(gen, traj, watch) for _, _, gen, traj, watch, _ in ex.of("follow")]  # type: ignore[misc]


def test_a_plan_starts_where_the_executor_committed_with_a_new_generation() -> None:
    m, ex, notes, _ = alone()
    ex.positions[0] = 100
    m.submit(MoveToCmd(250, RAMP), 1.0)
    assert ex.of("committed") == [("committed", 0, 1.0)]
    ((gen, traj, watch),) = followed(ex)
    assert (gen, watch) == (1, True) and m.gen == 1 and m.traj is traj
    assert (traj.start_time, traj.position(1.0), traj.end_position) == (1.0, 100.0, 250.0)
    assert state(m) is MotorState.MOVING and not m.idle and notes == ["start"]
    ex.positions[0] = 250
    m.on_event(ex.report(K.DONE, 0, 1), 2.0)
    assert state(m) is MotorState.IDLE and m.idle and m.traj is None
    assert notes == ["start", "idle"] and m.position == 250


def test_a_plan_that_makes_no_step_is_done_at_once() -> None:
    m, ex, notes, _ = alone()
    ex.moves = False
    m.submit(MoveToCmd(10, RAMP), 0.0)
    assert m.idle and notes == ["start", "idle"]


def test_the_done_of_a_replaced_plan_is_ignored() -> None:
    m, ex, notes, _ = alone(motor_params(soft_min=-(10**6), soft_max=10**6))
    m.submit(RunCmd(1, RAMP), 0.0)
    m.submit(RunCmd(1, Ramp(4000.0, 8000.0, 8000.0)), 0.5)  # a new speed: re-planned at once
    assert [gen for gen, _, _ in followed(ex)] == [1, 2]
    m.on_event(ex.report(K.DONE, 0, 1), 0.6)
    assert m.state is MotorState.RUNNING and m.traj is not None
    m.on_event(ex.report(K.DONE, 0, 2), 0.7)  # the second plan reached the soft limit
    assert m.idle and notes == ["start", "idle"]


def test_a_hard_stop_waits_for_the_executors_confirmation() -> None:
    m, ex, notes, _ = alone(stops_at_once=False)
    m.submit(MoveToCmd(500, RAMP), 0.0)
    assert m.stop(hard=True, now=0.1)
    assert ex.of("stop") == [("stop", 0, 2)] and m.stopping and not m.idle
    assert m.queue_full is False and m.stops_settled == 0
    m.on_event(ex.report(K.DONE, 0, 1), 0.2)  # the stopped plan's end: not the answer
    assert m.stopping
    m.on_event(ex.report(K.STOPPED, 0, 2), 0.2)
    assert m.idle and not m.stopping and m.stops_settled == 1 and notes[-1] == "idle"


def test_a_soft_stop_decelerates_from_the_committed_state() -> None:
    m, ex, _, _ = alone()
    m.submit(RunCmd(-1, RAMP), 0.0)
    assert m.stop(hard=False, now=0.5)
    (gen, traj, _), stop = followed(ex)[-1], ex.of("committed")[-1]
    assert gen == 2 and stop == ("committed", 0, 0.5)
    assert m.state is MotorState.STOPPING and traj.end_velocity == 0.0
    assert m.soft_stops == 1 and m.takeover_steps == (0, 0)
    m.on_event(ex.report(K.DONE, 0, 2), 1.0)
    assert m.idle


def test_an_end_stop_outside_homing_is_answered_with_a_stop_and_latches_a_fault() -> None:
    m, ex, notes, _ = alone()
    m.submit(MoveToCmd(500, RAMP), 0.0)
    ex.positions[0] = 120
    m.on_event(ex.report(K.ENDSTOP, 0, 1, direction=1, speed=2000.0), 0.3)
    # the answer lifts the executor's block on the axis, before anything else is planned
    assert ex.of("stop") == [("stop", 0, 2)] and m.gen == 2
    assert m.state is MotorState.FAULT and m.fault == "end stop hit at 120 outside homing"
    assert m.faults == {"endstop": 1} and not m.position_lost and notes[-1] == "fault"
    assert m.position == 120 and not m.stopping  # its position is final


def test_an_event_overtaken_by_a_stop_of_ours_is_left_to_that_stop() -> None:
    m, ex, _, _ = alone(stops_at_once=False)
    m.submit(MoveToCmd(500, RAMP), 0.0)
    m.stop(hard=True, now=0.1)  # generation 2, awaited
    m.on_event(ex.report(K.ENDSTOP, 0, 1, direction=1), 0.1)
    assert len(ex.of("stop")) == 1 and m.fault is None  # no second answer, no fault
    m.on_event(ex.report(K.STOPPED, 0, 2), 0.2)
    assert m.idle and m.fault is None


@pytest.mark.parametrize(
    ("kind", "speed", "lost", "cause"),
    [
        (K.TIMING_LOST, 50.0, False, "timing_lost"),  # at or below the start speed: no slip
        (K.TIMING_LOST, 5000.0, True, "timing_lost"),
        (K.FAULT, 50.0, False, "io_error"),
        (K.FAULT, 5000.0, True, "io_error"),
    ],
)
def test_what_stopped_the_axis_decides_whether_its_position_is_lost(
    kind: ExecEventKind, speed: float, lost: bool, cause: str
) -> None:
    m, ex, _, _ = alone(motor_params(start_speed=100.0))
    m.submit(RunCmd(1, RAMP), 0.0)
    m.on_event(ex.report(kind, 0, 1, speed=speed, detail="what happened"), 0.2)
    assert ex.of("stop") == [("stop", 0, 2)]
    assert m.state is MotorState.FAULT and m.position_lost is lost and m.faults == {cause: 1}
    assert m.fault is not None and "what happened" in m.fault


def test_the_executors_death_faults_the_motor_with_its_position_lost() -> None:
    m, _, _, _ = alone()
    m.submit(RunCmd(1, RAMP), 0.0)
    m.on_event(ExecEvent(K.DIED, -1, -1, 0, 0.2, detail="exit code -9"), 0.2)
    assert m.state is MotorState.FAULT and m.position_lost
    assert m.fault == "step executor died: exit code -9" and m.faults == {"executor_died": 1}


def test_stopmove_clears_a_fault_unless_the_driver_still_reports_one() -> None:
    m, ex, notes, world = alone()
    m.submit(MoveToCmd(500, RAMP), 0.0)
    m.on_event(ex.report(K.ENDSTOP, 0, 1, direction=1), 0.1)
    world.inject_fault(0, "short")
    assert m.stop(hard=True, now=0.2) is False and m.state is MotorState.FAULT
    world.inject_fault(0, None)
    assert m.stop(hard=True, now=0.3) is True
    assert m.idle and m.fault is None and notes[-1] == "cleared"


def test_stall_homing_follows_without_end_stops() -> None:
    m, ex, _, _ = alone(motor_params(homing=HomingParams(source=HomingSource.STALL)))
    m.submit(HomeCmd(-1, RAMP), 0.0)
    ((_, traj, watch),) = followed(ex)
    assert watch is False and traj.velocity(10.0) < 0  # the driver's stall flag ends it
    m2, ex2, _, _ = alone()
    m2.submit(HomeCmd(-1, RAMP), 0.0)
    assert followed(ex2)[0][2] is True


def test_after_the_trigger_homing_backs_off_slowly_and_zeroes_where_it_released() -> None:
    m, ex, notes, _ = alone(stops_at_once=False)
    m.submit(HomeCmd(-1, Ramp(2000.0, 8000.0, 8000.0)), 0.0)
    ex.positions[0] = -700
    m.on_event(ex.report(K.ENDSTOP, 0, 1, direction=-1), 0.4)
    assert ex.of("stop") == [("stop", 0, 2)]  # the trigger answered, then the back-off:
    _, _, gen, traj, watch, release = ex.of("follow")[-1]
    assert isinstance(traj, Trajectory) and (gen, watch, release) == (3, True, True)
    assert traj.velocity(10.0) == 250.0  # up, at second_speed, at most max_travel
    assert traj.end_position == -700 + 40_000
    assert m.state is MotorState.HOMING and "homed" not in notes
    ex.positions[0] = -695  # where the executor stopped the axis: two steps past the release
    m.on_event(ex.report(K.RELEASED, 0, 3, direction=-1, mark=-697), 0.5)
    assert ex.of("stop")[-1] == ("stop", 0, 4) and m.stopping  # answered; zero once it stands
    m.on_event(ex.report(K.STOPPED, 0, 4), 0.51)
    assert m.idle and m.position == 2 and notes[-2:] == ["homed", "idle"]
    ex.positions[0] = -697
    assert m.position == 0  # where the switch released


def test_a_release_after_a_soft_stop_of_the_back_off_ends_it_without_homing() -> None:
    m, ex, notes, _ = alone()
    m.submit(HomeCmd(1, RAMP), 0.0)
    m.on_event(ex.report(K.ENDSTOP, 0, 1, direction=1), 0.4)
    assert m.stop(hard=False, now=0.45)  # StopMove while backing off
    m.on_event(ex.report(K.RELEASED, 0, 3, direction=1, mark=-3), 0.46)  # it came first
    assert ex.of("stop")[-1] == ("stop", 0, 5)  # answered
    assert m.idle and m.fault is None and "homed" not in notes


def test_a_stall_read_before_the_motor_stepped_again_is_the_last_motions() -> None:
    """Right after stall homing the driver may still say "stall" (a real one until it sees
    standstill, the mock while DIR still points into the hard stop): a host's first MoveTo
    away must not fault on that reading; one read once the motor has stepped counts."""
    m, ex, _, _ = alone(motor_params(homing=HomingParams(source=HomingSource.STALL)))
    stalled = DriverStatus(stall=True)
    m.submit(HomeCmd(1, RAMP), 0.0)
    ex.positions[0] = 1200
    m.on_driver_status(stalled, 0.5, steps=1200)
    assert m.idle and m.position == 0  # homed where it stalled
    m.submit(MoveToCmd(-500, RAMP), 0.6)
    m.on_driver_status(stalled, 0.61, steps=1200)  # read before its first step
    assert m.fault is None and state(m) is MotorState.MOVING
    ex.positions[0] = 1190
    m.on_driver_status(stalled, 0.62, steps=1200)  # read before it, acted on after: the same
    assert m.fault is None
    m.on_driver_status(stalled, 0.63, steps=1190)  # read while it steps: a stall
    assert state(m) is MotorState.FAULT and m.fault == "stall"


def test_the_host_sees_a_wrapped_linear_counter_or_a_rotary_angle() -> None:
    m, ex, _, _ = alone(motor_params(host_position=wrap24))
    ex.positions[0] = 2**23 + 5
    assert m.abs_steps == 2**23 + 5 and m.position == -(2**23) + 5
    m.set_position(10)  # declared: here is 10
    assert m.position == 10 and m.offset == 2**23 - 5
    r, rex, _, _ = alone(motor_params(steps_per_rev=200))
    rex.positions[0] = -30
    assert r.position == 170


def test_the_queue_is_full_at_its_depth_behind_the_running_command() -> None:
    m, _, _, _ = alone(motor_params(queue_depth=2))
    assert not m.queue_full  # idle: a command starts at once
    m.submit(MoveToCmd(100, RAMP), 0.0)
    m.submit(MoveToCmd(200, RAMP), 0.0)
    assert not m.queue_full
    m.submit(MoveToCmd(300, RAMP), 0.0)
    assert m.queue_full and len(m.queue) == 2


# ---------------------------------------------------------------- over the mock world


# ---------------------------------------------------------------- step-time helpers


def direction_runs(dirs: Sequence[bool]) -> list[tuple[bool, int]]:
    """Collapse a list of step directions into (direction, count) runs."""
    runs: list[tuple[bool, int]] = []
    for d in dirs:
        if runs and runs[-1][0] == d:
            runs[-1] = (d, runs[-1][1] + 1)
        else:
            runs.append((d, 1))
    return runs


def test_move_to_current_position_does_nothing() -> None:
    rig = engine_rig()
    rig.submit(MoveToCmd(0, RAMP))
    assert rig.m.idle
    rig.advance(1.0)
    assert rig.times() == []


# ---------------------------------------------------------------- the queue


def test_queued_moves_run_in_order_back_to_back() -> None:
    rig = engine_rig()
    t0 = rig.clock.now()
    targets = [(100, RAMP), (-50, Ramp(800.0, 4000.0, 2000.0)), (300, RAMP)]
    for target, r in targets:
        rig.submit(MoveToCmd(target, r))
    assert len(rig.m.queue) == 2
    rig.engine.run_until_idle()

    expected: list[float] = []
    start, t = 0, t0
    for target, r in targets:
        part = planned_times(t, start, target, r)
        expected += part
        start, t = target, part[-1]
    assert rig.times() == expected
    assert direction_runs(rig.dirs()) == [(True, 100), (False, 150), (True, 350)]
    assert rig.m.position == 300 == rig.axis()
    # One motion from the host's point of view: started once, idle once at the very end.
    assert rig.event_times("start") == [t0]
    assert rig.event_times("idle") == [expected[-1]]


def test_queue_full_at_queue_depth_behind_the_running_command() -> None:
    rig = engine_rig(motor_params(queue_depth=3))
    assert not rig.m.queue_full
    rig.submit(MoveToCmd(500, RAMP))  # runs at once, queue still empty
    assert not rig.m.queue and not rig.m.queue_full
    for i in range(3):
        assert not rig.m.queue_full
        rig.submit(MoveToCmd(-10 * i, RAMP))
    assert len(rig.m.queue) == 3 and rig.m.queue_full
    assert not rig.m.idle
    rig.engine.run_until_idle()
    assert not rig.m.queue_full and rig.m.idle
    assert rig.m.position == -20 == rig.axis()


def test_move_behind_a_move_to_waits_for_it() -> None:
    rig = engine_rig()
    rig.submit(MoveToCmd(200, RAMP))
    rig.submit(RunCmd(-1, RAMP))
    assert len(rig.m.queue) == 1 and rig.state() is MotorState.MOVING
    rig.advance(0.5)
    assert rig.state() is MotorState.RUNNING
    runs = direction_runs(rig.dirs())
    assert runs[0] == (True, 200) and runs[1][0] is False


def test_run_with_commands_queued_behind_it_is_not_replanned() -> None:
    rig = engine_rig()
    rig.submit(MoveToCmd(100, RAMP))
    rig.submit(RunCmd(1, RAMP))
    rig.submit(MoveToCmd(0, RAMP))
    rig.advance(0.5)
    assert rig.state() is MotorState.RUNNING and len(rig.m.queue) == 1
    rig.submit(RunCmd(-1, RAMP))  # the queue is not empty: it waits its turn
    assert len(rig.m.queue) == 2
    rig.advance(0.3)
    assert set(rig.dirs()) == {True}
    assert rig.stop(hard=True) and not rig.m.queue


def test_run_speed_change_replans_at_once() -> None:
    rig = engine_rig(axes=[mock_axis(endstop_min=-100_000, endstop_max=100_000)])
    rig.submit(RunCmd(1, Ramp(1000.0, 5000.0, 5000.0)))
    ts = rig.advance(1.0)
    before = rig.times()
    assert before[-1] - before[-2] == pytest.approx(1e-3)
    rig.submit(RunCmd(1, Ramp(3000.0, 5000.0, 5000.0)))
    assert rig.state() is MotorState.RUNNING and not rig.m.queue
    rig.advance(1.0)
    after = [t for t in rig.times() if t > ts]
    gaps = [b - a for a, b in itertools.pairwise(after)]
    # The very first steps already come faster: it accelerates at once, along the ramp.
    assert after[0] - before[-1] < 1e-3
    assert gaps[0] < 1e-3 and gaps[0] > gaps[10] > gaps[100]
    assert gaps[-1] == pytest.approx(1 / 3000, abs=TICK)
    assert min(gaps) >= 1 / 3000 - TICK
    assert set(rig.dirs()) == {True}
    assert len(rig.world.timeline.of(EventKind.DIR, 0)) == 1
    # Slow down again, with the new command's deceleration.
    ts2 = rig.clock.now()
    rig.submit(RunCmd(1, Ramp(500.0, 5000.0, 1000.0)))
    rig.advance(3.0)
    later = [t for t in rig.times() if t > ts2]
    assert later[-1] - later[-2] == pytest.approx(1 / 500, abs=TICK)
    # Decelerating 3000 -> 500 at 1000 step/s^2 takes 2.5 s: halfway it is still fast.
    mid = [t for t in later if t < ts2 + 1.25]
    assert mid[-1] - mid[-2] < 1 / 1000
    assert rig.m.position == rig.axis()


def test_run_reversal_changes_direction_once() -> None:
    rig = engine_rig(axes=[mock_axis(endstop_min=-100_000, endstop_max=100_000)])
    rig.submit(RunCmd(1, Ramp(2000.0, 8000.0, 8000.0)))
    ts = rig.advance(1.0)
    up_before = len(rig.times())
    rig.submit(RunCmd(-1, Ramp(1000.0, 8000.0, 4000.0)))
    assert rig.state() is MotorState.RUNNING
    rig.advance(2.0)
    assert rig.stop(hard=True)
    runs = direction_runs(rig.dirs())
    assert len(runs) == 2 and runs[0][0] is True and runs[1][0] is False
    # Stopping from 2000 step/s with the new DEC 4000 takes 2000^2/(2*4000) = 500 steps.
    assert 499 <= runs[0][1] - up_before <= 501
    assert len(rig.world.timeline.of(EventKind.DIR, 0)) == 2
    assert rig.m.position == runs[0][1] - runs[1][1] == rig.axis()
    times = rig.times()
    assert times[-1] - times[-2] == pytest.approx(1 / 1000, abs=TICK)
    assert all(t > ts for t in times[up_before:])


# ---------------------------------------------------------------- stops


@pytest.mark.parametrize("cmd", [MoveToCmd(5000, RAMP), RunCmd(1, RAMP)])
def test_soft_stop_decelerates_and_empties_the_queue(cmd: MotionCmd) -> None:
    rig = engine_rig(axes=[mock_axis(endstop_min=-100_000, endstop_max=100_000)])
    rig.submit(cmd)
    rig.submit(MoveToCmd(-300, RAMP))
    rig.submit(MoveToCmd(700, RAMP))
    ts = rig.advance(0.6)
    v = rig.m.traj.velocity(ts) if rig.m.traj is not None else 0.0
    assert v == pytest.approx(2000.0)
    n_before = len(rig.times())
    assert rig.stop(hard=False)
    assert not rig.m.queue and rig.state() is MotorState.STOPPING
    rig.engine.run_until_idle()
    after = [t for t in rig.times() if t > ts]
    assert len(rig.times()) == n_before + len(after)
    limit = v * v / (2 * RAMP.dec)
    assert limit - 1 <= len(after) <= limit + 1
    assert set(rig.dirs()) == {True}
    gaps = [b - a for a, b in itertools.pairwise(after)]
    assert gaps == sorted(gaps)  # slower and slower
    assert after[-1] == pytest.approx(ts + v / RAMP.dec, abs=2e-3)
    assert rig.m.idle and rig.m.position == rig.axis() == n_before + len(after)


def test_soft_stop_when_idle_is_harmless() -> None:
    rig = engine_rig()
    assert rig.stop(hard=False) and rig.stop(hard=True)
    assert rig.m.idle and rig.times() == []


@pytest.mark.parametrize("cmd", [MoveToCmd(5000, RAMP), RunCmd(-1, RAMP), HomeCmd(1, RAMP)])
def test_hard_stop_stops_at_once(cmd: MotionCmd) -> None:
    rig = engine_rig(axes=[mock_axis(endstop_min=-100_000, endstop_max=100_000)])
    rig.submit(cmd)
    rig.submit(MoveToCmd(3, RAMP))
    ts = rig.advance(0.4)
    n = len(rig.times())
    assert n > 100
    assert rig.stop(hard=True)
    assert rig.m.idle and rig.state() is MotorState.IDLE and rig.m.traj is None
    assert not rig.executor.planned(0)
    assert rig.event_times("idle") == [ts]
    rig.advance(1.0)
    assert len(rig.times()) == n and max(rig.times()) <= ts
    assert abs(rig.m.position) == n and rig.m.position == rig.axis()


@pytest.mark.parametrize("debounce_s", [0.0, 0.02])
def test_a_motion_toward_an_end_stop_pressed_already_faults_without_a_step(
    debounce_s: float,
) -> None:
    """A run up until the max switch closes (a hit), StopMove clears it; each Move or
    MoveTo toward it again latches the fault at once, no step made ("already active"); a
    MoveTo away works."""
    far = mock_axis(endstop_min=-100_000, endstop_max=100_000)
    rig = engine_rig(motor_params(debounce_s=debounce_s), axes=[far])
    rig.submit(RunCmd(1, RAMP))
    rig.advance(0.2)
    rig.world.force_endstop(0, "max", True)  # closed from now on
    rig.engine.run_until_idle()
    on_it = rig.axis()
    assert rig.m.fault == f"end stop hit at {on_it} outside homing" and on_it > 0
    steps = len(rig.times())
    cmds: list[MotionCmd] = [RunCmd(1, RAMP), MoveToCmd(on_it + 500, RAMP), RunCmd(1, RAMP)]
    for cmd in cmds:
        assert rig.stop(hard=False) and rig.m.idle
        rig.submit(cmd)
        rig.engine.run_until_idle()
        assert rig.state() is MotorState.FAULT
        assert rig.m.fault == f"end stop already active at {on_it} outside homing"
        assert len(rig.times()) == steps and rig.axis() == on_it == rig.m.position
    assert rig.m.faults == {"endstop": 4} and not rig.m.position_lost
    assert rig.stop(hard=False)
    rig.submit(MoveToCmd(on_it - 500, RAMP))  # backing off: the switch behind is no fault
    rig.engine.run_until_idle()
    assert rig.m.fault is None and rig.m.idle and rig.axis() == on_it - 500 == rig.m.position


# ---------------------------------------------------------------- homing


def test_one_phase_homing() -> None:
    rig = engine_rig()
    rig.submit(MoveToCmd(300, RAMP))
    rig.submit(HomeCmd(-1, Ramp(1000.0, 5000.0, 5000.0)))
    rig.engine.run_until_idle()
    # the switch closes at -1000 and opens again one step back at -999: zero there
    assert rig.axis() == -999
    assert rig.m.position == 0 and rig.m.idle and rig.m.fault is None
    assert direction_runs(rig.dirs()) == [(True, 300), (False, 1300), (True, 1)]
    assert len(rig.event_times("homed")) == 1
    # Homed means: the next move counts from where the switch released.
    rig.submit(MoveToCmd(250, RAMP))
    rig.engine.run_until_idle()
    assert rig.m.position == 250 and rig.axis() == -749


def test_homing_clears_a_lost_position() -> None:
    rig = engine_rig()
    rig.m.position_lost = True
    rig.submit(HomeCmd(1, RAMP))
    rig.engine.run_until_idle()
    assert not rig.m.position_lost and rig.axis() == 999 and rig.m.position == 0


def test_two_phase_homing_backs_off_and_reapproaches_slowly() -> None:
    homing = HomingParams(pull_off=50, second_speed=200.0)
    rig = engine_rig(motor_params(homing=homing))
    ramp = Ramp(1500.0, 6000.0, 6000.0)
    rig.submit(HomeCmd(-1, ramp))
    assert rig.state() is MotorState.HOMING
    rig.engine.run_until_idle()
    assert rig.m.position == 0 and rig.axis() == -999 and rig.m.fault is None
    steps = rig.steps()
    assert direction_runs(rig.dirs()) == [(False, 1000), (True, 50), (False, 50), (True, 1)]
    seek, approach = steps[:1000], steps[1050:1100]
    seek_gaps = [b.t - a.t for a, b in itertools.pairwise(seek)]
    approach_gaps = [b.t - a.t for a, b in itertools.pairwise(approach)]
    assert min(seek_gaps) == pytest.approx(1 / 1500, abs=TICK)
    assert min(approach_gaps) >= 1 / 200 - TICK
    assert approach_gaps[-1] == pytest.approx(1 / 200, abs=TICK)
    assert len(rig.event_times("homed")) == 1 and len(rig.event_times("idle")) == 1


def test_two_phase_homing_with_second_speed_above_the_ramp_uses_the_ramp() -> None:
    homing = HomingParams(pull_off=20, second_speed=5000.0)
    rig = engine_rig(motor_params(homing=homing))
    rig.submit(HomeCmd(1, Ramp(400.0, 100_000.0, 100_000.0)))
    rig.engine.run_until_idle()
    approach = rig.steps()[1020:1040]
    assert direction_runs(rig.dirs())[-2:] == [(True, 20), (False, 1)]
    gaps = [b.t - a.t for a, b in itertools.pairwise(approach)]
    assert min(gaps) >= 1 / 400 - TICK
    assert rig.axis() == 999 and rig.m.position == 0


# A stall is read from the driver by the monitor, never on the step path: it is seen within
# one driver poll, so stall homing runs on for up to speed * POLL steps after the stall
# (pulses lost against the mock's hard stop).
STALL_OVERRUN = int(RAMP.speed * POLL) + 1


def test_stall_homing() -> None:
    rig = engine_rig(motor_params(homing=HomingParams(source=HomingSource.STALL)))
    rig.submit(HomeCmd(1, RAMP))
    rig.engine.run_until_idle()
    # The mock stalls once it is pushed against its hard stop (at its end stop): the pulses
    # after that are lost, the axis stays there; zero is where it stalled.
    assert rig.m.fault is None and rig.m.position == 0
    assert rig.axis() == 1000 and 1001 <= len(rig.times()) <= 1001 + STALL_OVERRUN
    assert direction_runs(rig.dirs())[-1][0] is True  # no back-off: it zeroes where it stalled
    assert rig.event_times("homed")


def test_two_phase_stall_homing() -> None:
    homing = HomingParams(source=HomingSource.STALL, pull_off=30, second_speed=300.0)
    rig = engine_rig(motor_params(homing=homing))
    rig.submit(HomeCmd(-1, RAMP))
    rig.engine.run_until_idle()
    assert rig.m.fault is None and rig.m.position == 0
    runs = direction_runs(rig.dirs())
    assert [d for d, _ in runs] == [False, True, False] and runs[1] == (True, 30)
    assert 1001 <= runs[0][1] <= 1001 + STALL_OVERRUN
    # the re-approach stalls again at the stop (seen within a poll at 300 step/s)
    assert 31 <= runs[2][1] <= 31 + int(300 * POLL) + 1 and rig.axis() == -1000


def test_after_stall_homing_the_motor_moves_away_without_a_stall_fault() -> None:
    rig = engine_rig(motor_params(homing=HomingParams(source=HomingSource.STALL)))
    rig.submit(HomeCmd(1, RAMP))
    rig.engine.run_until_idle()
    rig.advance(0.1)
    # A slow start: several driver polls happen before the first step leaves the stop.
    home = rig.axis()
    rig.submit(MoveToCmd(-500, Ramp(1000.0, 500.0, 500.0)))
    rig.engine.run_until_idle()
    assert rig.m.fault is None
    assert rig.m.position == -500 and rig.axis() == home - 500


def test_stall_during_endstop_homing_is_a_fault() -> None:
    rig = engine_rig()
    rig.submit(HomeCmd(1, RAMP))
    rig.advance(0.1)
    rig.world.inject_stall(0, True)
    rig.advance(2 * POLL)
    assert rig.state() is MotorState.FAULT and rig.m.fault == "stall"


def test_homing_fails_beyond_max_travel() -> None:
    rig = engine_rig(motor_params(homing=HomingParams(max_travel=300)))
    rig.submit(HomeCmd(-1, RAMP))
    rig.submit(MoveToCmd(50, RAMP))
    rig.engine.run_until_idle()
    assert rig.state() is MotorState.FAULT
    assert rig.m.fault is not None and rig.m.fault.startswith("homing failed")
    assert "300" in rig.m.fault
    assert rig.axis() == -300 == rig.m.position  # it stopped at max_travel, not beyond
    assert not rig.m.queue and not rig.m.idle
    assert rig.event_times("fault") == [rig.times()[-1]]
    assert rig.stop(hard=False)  # the driver is healthy: StopMove clears it
    assert rig.state() is MotorState.IDLE and rig.m.fault is None and rig.m.idle


def test_homing_fails_when_the_reapproach_finds_nothing() -> None:
    far = mock_axis(endstop_min=-100_000, endstop_max=100_000)
    rig = engine_rig(motor_params(homing=HomingParams(pull_off=40)), axes=[far])
    rig.submit(HomeCmd(1, RAMP))
    rig.advance(0.2)
    rig.world.force_endstop(0, "max", True)
    rig.advance(0.001)
    rig.world.force_endstop(0, "max", False)  # gone for good: the re-approach misses it
    rig.engine.run_until_idle()
    assert rig.state() is MotorState.FAULT
    assert rig.m.fault == "homing failed: no end stop within 80 steps"
    runs = direction_runs(rig.dirs())
    assert [d for d, _ in runs] == [True, False, True] and runs[1:] == [(False, 40), (True, 80)]


def test_homing_fails_when_the_switch_stays_active_after_pull_off() -> None:
    far = mock_axis(endstop_min=-100_000, endstop_max=100_000)
    rig = engine_rig(motor_params(homing=HomingParams(pull_off=40)), axes=[far])
    rig.submit(HomeCmd(1, RAMP))
    rig.advance(0.2)
    rig.world.force_endstop(0, "max", True)
    rig.engine.run_until_idle()
    assert rig.state() is MotorState.FAULT
    assert rig.m.fault is not None and "still active" in rig.m.fault
    assert direction_runs(rig.dirs())[-1] == (False, 40)


def test_homing_that_starts_on_the_switch_only_backs_off_it() -> None:
    rig = engine_rig()
    rig.world.axes[0].position = -1002  # resting on the min switch, 3 steps from its edge
    rig.submit(HomeCmd(-1, RAMP))
    assert rig.state() is MotorState.HOMING
    rig.engine.run_until_idle()
    assert direction_runs(rig.dirs()) == [(True, 3)]  # never further toward it
    assert rig.axis() == -999 and rig.m.position == 0 and rig.m.fault is None
    assert len(rig.event_times("homed")) == 1


def test_two_phase_homing_that_starts_on_the_switch_backs_off_first() -> None:
    rig = engine_rig(motor_params(homing=HomingParams(pull_off=25, second_speed=100.0)))
    rig.world.axes[0].position = 1000
    rig.submit(HomeCmd(1, RAMP))
    assert rig.state() is MotorState.HOMING
    rig.engine.run_until_idle()
    assert direction_runs(rig.dirs()) == [(False, 25), (True, 25), (False, 1)]
    assert rig.axis() == 999 and rig.m.position == 0 and rig.m.fault is None


def test_homing_with_debounce_that_starts_on_the_switch_only_backs_off_it() -> None:
    """With a debounce the motor cannot tell the switch from a glitch before its run: the
    executor does, before the first step, and the run goes straight to the back-off."""
    rig = engine_rig(motor_params(debounce_s=0.02))
    rig.world.axes[0].position = -1002  # resting on the min switch, 3 steps from its edge
    rig.advance(0.05)  # for longer than the debounce
    rig.submit(HomeCmd(-1, RAMP))
    rig.engine.run_until_idle()
    assert direction_runs(rig.dirs())[0][0] is True  # never a step toward it
    assert rig.m.fault is None and rig.m.idle and len(rig.event_times("homed")) == 1
    # zero where it released (-999), the steps of the debounce on top
    assert rig.m.position == rig.axis() + 999 and rig.axis() > -999


def test_homing_with_debounce_ignores_short_glitches() -> None:
    """Both ways: a trigger counts once active for the debounce time, and so does a release
    (a bounce open while backing off is no release); zero is where it released for good,
    and the steps made while that was debounced count from there."""
    far = mock_axis(endstop_min=-100_000, endstop_max=100_000)
    rig = engine_rig(motor_params(debounce_s=0.02), axes=[far])
    ramp = Ramp(1000.0, 1e6, 1e6)  # 1 ms per step almost at once
    rig.submit(HomeCmd(1, ramp))
    rig.advance(0.2)
    rig.world.force_endstop(0, "max", True)  # a 15 ms glitch: shorter than the debounce
    rig.advance(0.015)
    rig.world.force_endstop(0, "max", False)
    rig.advance(0.2)
    assert rig.state() is MotorState.HOMING
    t_on = rig.clock.now()
    rig.world.force_endstop(0, "max", True)
    rig.advance(0.1)  # triggered, now backing off at second_speed (250 step/s) on the switch
    ups = [e.t for e in rig.steps() if e.value]
    first_active = min(t for t in ups if t >= t_on)
    assert first_active + 0.02 <= ups[-1] < first_active + 0.02 + 1.5e-3
    assert not rig.steps()[-1].value and rig.state() is MotorState.HOMING
    rig.world.force_endstop(0, "max", False)  # a 10 ms bounce open: no release yet
    rig.advance(0.01)
    rig.world.force_endstop(0, "max", True)
    rig.advance(0.05)
    assert rig.state() is MotorState.HOMING
    t_off = rig.clock.now()
    rig.world.force_endstop(0, "max", False)  # released for good
    rig.engine.run_until_idle()
    assert rig.m.fault is None and rig.m.idle
    after = [e for e in rig.steps() if e.t > t_off]
    assert not any(e.value for e in after)  # backing off, 4 ms a step
    assert after[-2].t < t_off + 0.02 <= after[-1].t  # stopped once debounced
    # zero at the first step that saw it released; the steps since count from there
    assert rig.m.position == -(len(after) - 1)
    released_at = rig.axis() + len(after) - 1
    rig.submit(MoveToCmd(0, Ramp(1000.0, 5000.0, 5000.0)))
    rig.engine.run_until_idle()
    assert rig.m.fault is None and rig.m.position == 0 and rig.axis() == released_at


def test_endstop_hit_with_debounce_outside_homing() -> None:
    far = mock_axis(endstop_min=-100_000, endstop_max=100_000)
    rig = engine_rig(motor_params(debounce_s=0.0105), axes=[far])
    rig.submit(RunCmd(-1, Ramp(1000.0, 1e6, 1e6)))
    rig.advance(0.1)
    rig.world.force_endstop(0, "min", True)
    t_on = rig.clock.now()
    rig.advance(0.1)
    assert rig.m.fault == f"end stop hit at {rig.m.position} outside homing"
    after = [t for t in rig.times() if t > t_on]  # the steps that read it active
    # debounced from the edge's own time (the kernel's timestamp on real lines)
    assert 0.0105 - TICK <= after[-1] - t_on < 0.0105 + 1e-3
    assert len(after) in (11, 12)


def test_debounce_forgets_what_it_no_longer_watches() -> None:
    """Two short glitches far apart, each shorter than the debounce, never add up."""
    far = mock_axis(endstop_min=-100_000, endstop_max=100_000)
    rig = engine_rig(motor_params(debounce_s=0.02), axes=[far])
    ramp = Ramp(1000.0, 1e6, 1e6)
    rig.submit(RunCmd(1, ramp))
    rig.advance(0.1)
    rig.world.force_endstop(0, "max", True)  # a glitch right when the motor is stopped
    rig.advance(0.0025)
    assert rig.stop(hard=True)
    rig.world.force_endstop(0, "max", False)
    rig.advance(1.0)
    rig.world.force_endstop(0, "max", True)  # another glitch, at the first steps
    rig.submit(RunCmd(1, ramp))
    rig.advance(0.0025)
    rig.world.force_endstop(0, "max", False)
    rig.advance(0.1)
    assert rig.m.fault is None and rig.state() is MotorState.RUNNING


def test_homing_with_active_low_end_stops() -> None:
    axis = mock_axis(endstop_active_low=True, endstop_min=-400, endstop_max=400)
    rig = engine_rig(axes=[axis], lows=[True])
    rig.submit(HomeCmd(1, RAMP))
    rig.engine.run_until_idle()
    assert rig.axis() == 399 and rig.m.position == 0 and rig.m.fault is None


#: the homing kinds: on the end stop (with and without the second approach), by stall (the
#: mock axis without switches: a stall-homed axis has none)
HOMING_KINDS = {
    "endstop": HomingParams(),
    "endstop_pull_off": HomingParams(pull_off=30, second_speed=300.0),
    "stall": HomingParams(source=HomingSource.STALL),
    "stall_pull_off": HomingParams(source=HomingSource.STALL, pull_off=30, second_speed=300.0),
}


@pytest.mark.parametrize("direction", [1, -1])
@pytest.mark.parametrize("kind", list(HOMING_KINDS))
def test_after_homing_moveto_0_comes_back_without_touching_the_end_stop(
    kind: str, direction: int
) -> None:
    homing = HOMING_KINDS[kind]
    endstop = homing.source is HomingSource.ENDSTOP
    axis = mock_axis(endstop_min=-1000, endstop_max=1000, switches=endstop)
    rig = engine_rig(motor_params(homing=homing), axes=[axis])
    rig.submit(MoveToCmd(-direction * 200, RAMP))
    rig.submit(HomeCmd(direction, RAMP))
    rig.engine.run_until_idle()
    assert rig.m.fault is None and rig.m.idle and rig.m.position == 0
    side = "max" if direction > 0 else "min"
    home = rig.axis()
    # zero: the first position off the switch; for a stall, the hard stop where it stalled
    assert home == direction * (999 if endstop else 1000)
    assert not rig.world.axes[0].endstop_active(side)
    rig.submit(MoveToCmd(-direction * 700, RAMP))  # away
    rig.submit(MoveToCmd(0, RAMP))  # and back
    rig.engine.run_until_idle()  # WaitMoved
    assert rig.m.fault is None and rig.m.idle  # no E4
    assert rig.m.position == 0 and rig.axis() == home  # GetAbsPos 0, where it homed
    assert direction_runs(rig.dirs())[-1] == (direction > 0, 700)  # the way back


@pytest.mark.parametrize("direction", [1, -1])
def test_after_homing_a_step_beyond_0_toward_the_switch_is_an_end_stop_hit(
    direction: int,
) -> None:
    """Zero is the first position off the switch: one step further is on it, and an end stop
    hit outside homing still faults (E4)."""
    rig = engine_rig()
    rig.submit(HomeCmd(direction, RAMP))
    rig.engine.run_until_idle()
    assert rig.m.position == 0 and rig.m.fault is None
    rig.submit(MoveToCmd(direction, RAMP))
    rig.engine.run_until_idle()
    assert rig.state() is MotorState.FAULT
    assert rig.m.fault == f"end stop hit at {direction} outside homing"
    assert rig.m.faults == {"endstop": 1} and rig.axis() == direction * 1000


@pytest.mark.parametrize("direction", [1, -1])
def test_homing_fails_when_the_switch_does_not_release_within_max_travel(
    direction: int,
) -> None:
    far = mock_axis(endstop_min=-100_000, endstop_max=100_000)
    rig = engine_rig(motor_params(homing=HomingParams(max_travel=300)), axes=[far])
    side = "max" if direction > 0 else "min"
    rig.world.force_endstop(0, side, True)  # a switch stuck active
    rig.submit(HomeCmd(direction, RAMP))
    rig.submit(MoveToCmd(0, RAMP))
    rig.engine.run_until_idle()
    assert rig.state() is MotorState.FAULT and rig.m.faults == {"homing": 1}
    assert rig.m.fault == "homing failed: end stop still active after backing off 300 steps"
    assert direction_runs(rig.dirs()) == [(direction < 0, 300)]  # at the slow speed, and no
    gaps = [b - a for a, b in itertools.pairwise(rig.times())]  # further
    assert min(gaps) >= 1 / 250 - TICK
    assert rig.axis() == -direction * 300 and not rig.m.queue
    assert rig.stop(hard=False) and rig.m.idle  # StopMove clears it


# ---------------------------------------------------------------- end stops and faults


def test_endstop_hit_outside_homing_is_a_hard_stop_and_fault() -> None:
    rig = engine_rig()
    rig.submit(MoveToCmd(1500, RAMP))
    rig.submit(MoveToCmd(0, RAMP))
    rig.engine.run_until_idle()
    assert rig.state() is MotorState.FAULT and rig.m.fault == "end stop hit at 1000 outside homing"
    assert rig.axis() == 1000 == rig.m.position
    t_hit = rig.times()[-1]
    assert rig.event_times("fault") == [t_hit]
    assert not rig.m.queue
    rig.advance(1.0)
    assert rig.times()[-1] == t_hit
    # Cleared by StopMove, then leaving the switch the other way is fine.
    assert rig.stop(hard=True) and rig.m.fault is None
    rig.submit(MoveToCmd(200, RAMP))
    rig.engine.run_until_idle()
    assert rig.m.fault is None and rig.axis() == 200 == rig.m.position


def test_leaving_an_active_endstop_is_fine() -> None:
    rig = engine_rig()
    rig.world.force_endstop(0, "max", True)
    rig.submit(MoveToCmd(-300, RAMP))
    rig.engine.run_until_idle()
    assert rig.m.fault is None and rig.axis() == -300
    rig.submit(MoveToCmd(-299, RAMP))  # towards it, active all along: not even one step
    rig.engine.run_until_idle()
    assert rig.m.fault == "end stop already active at -300 outside homing"
    assert rig.axis() == -300 == rig.m.position


def test_driver_fault_while_moving_stops_at_once_and_latches() -> None:
    rig = engine_rig()
    rig.submit(MoveToCmd(900, RAMP))
    rig.submit(MoveToCmd(0, RAMP))
    t_inject = rig.advance(0.2)
    rig.world.inject_fault(0, "over-temperature")
    rig.advance(1.0)
    assert rig.state() is MotorState.FAULT
    assert rig.m.fault == "driver fault: over-temperature"
    (t_fault,) = rig.event_times("fault")
    assert t_inject <= t_fault <= t_inject + POLL
    assert max(rig.times()) <= t_fault and not rig.m.queue
    assert rig.m.position == rig.axis() == len(rig.times())
    # StopMove cannot clear it while the driver still reports it ...
    assert not rig.stop(hard=False)
    assert not rig.stop(hard=True)
    assert rig.state() is MotorState.FAULT and rig.m.fault is not None
    # ... and can once it no longer does; the latched fault stays until then.
    rig.world.inject_fault(0, None)
    rig.advance(0.1)
    assert rig.m.fault == "driver fault: over-temperature"
    assert rig.stop(hard=False)
    assert rig.m.fault is None and rig.m.idle
    assert rig.event_times("cleared")
    rig.submit(MoveToCmd(0, RAMP))
    rig.engine.run_until_idle()
    assert rig.m.position == 0 == rig.axis()


def test_driver_fault_while_idle_latches_too() -> None:
    rig = engine_rig()
    rig.world.inject_fault(0, "short")
    rig.advance(2 * POLL)
    assert rig.m.fault == "driver fault: short"


def test_stall_outside_homing_is_a_fault() -> None:
    rig = engine_rig()
    rig.submit(RunCmd(1, Ramp(500.0, 5000.0, 5000.0)))
    t_inject = rig.advance(0.3)
    rig.world.inject_stall(0, True)
    rig.advance(0.5)
    assert rig.m.fault == "stall" and rig.state() is MotorState.FAULT
    (t_fault,) = rig.event_times("fault")
    assert t_fault <= t_inject + POLL and max(rig.times()) <= t_fault
    assert rig.stop(hard=False) and rig.m.idle  # the stall flag is no driver fault


def test_stall_while_idle_is_not_a_fault() -> None:
    rig = engine_rig()
    rig.world.inject_stall(0, True)
    rig.advance(0.1)
    assert rig.m.fault is None


# ---------------------------------------------------------------- rotary axes


def test_rotary_moves_in_the_given_direction() -> None:
    rig = engine_rig(motor_params(steps_per_rev=200))
    rig.submit(MoveToCmd(150, RAMP, 1))  # 0 -> 150 up: 150 steps
    rig.submit(MoveToCmd(50, RAMP, 1))  # 150 -> 50 up, across 0: 100 steps
    rig.submit(MoveToCmd(150, RAMP, -1))  # 50 -> 150 down, across 0: 100 steps
    rig.submit(MoveToCmd(-10, RAMP, -1))  # 150 -> 190 down: 160 steps
    rig.submit(MoveToCmd(190, RAMP, 1))  # already there: no steps
    rig.submit(MoveToCmd(405, RAMP, 1))  # 190 -> 5 up: 15 steps
    rig.engine.run_until_idle()
    assert direction_runs(rig.dirs()) == [(True, 250), (False, 260), (True, 15)]
    assert rig.m.position == 5
    assert rig.axis() == 250 - 260 + 15
    assert rig.axis() % 200 == rig.m.position


def test_rotary_position_stays_in_range_while_moving() -> None:
    rig = engine_rig(
        motor_params(steps_per_rev=100), axes=[mock_axis(endstop_min=-(10**6), endstop_max=10**6)]
    )
    rig.submit(MoveToCmd(30, Ramp(2000.0, 20000.0, 20000.0), -1))
    rig.submit(MoveToCmd(30, Ramp(2000.0, 20000.0, 20000.0), -1))
    seen = set()
    for _ in range(1000):
        if rig.m.idle:
            break
        rig.advance(0.003)
        p = rig.m.position
        assert 0 <= p < 100 and p == rig.axis() % 100
        seen.add(p)
    assert rig.m.idle and rig.m.position == 30 and rig.axis() == -70
    assert max(seen) > 90 and min(seen) < 40


def test_rotary_homing_sets_zero() -> None:
    rig = engine_rig(motor_params(steps_per_rev=360))
    rig.submit(HomeCmd(1, RAMP))
    rig.engine.run_until_idle()
    assert rig.m.position == 0 and rig.axis() == 999
    rig.submit(MoveToCmd(10, RAMP, -1))
    rig.engine.run_until_idle()
    assert rig.m.position == 10 and rig.axis() == 649


# ---------------------------------------------------------------- soft limits


def soft(lo: int, hi: int) -> MotorParams:
    return motor_params(soft_min=lo, soft_max=hi)


def test_target_allowed() -> None:
    rig = engine_rig(soft(-500, 800))
    m = rig.m
    assert m.target_allowed(800) and m.target_allowed(-500) and m.target_allowed(0)
    assert not m.target_allowed(801) and not m.target_allowed(-501)
    free = engine_rig().m
    assert free.target_allowed(8_388_607) and free.target_allowed(-8_388_608)


@pytest.mark.parametrize(("direction", "limit"), [(1, 800), (-1, -500)])
def test_run_stops_exactly_at_the_soft_limit(direction: int, limit: int) -> None:
    rig = engine_rig(soft(-500, 800), axes=[mock_axis(endstop_min=-100_000, endstop_max=100_000)])
    rig.submit(MoveToCmd(100, RAMP))
    rig.submit(RunCmd(direction, RAMP))
    rig.engine.run_until_idle()
    assert rig.m.position == limit == rig.axis() and rig.m.idle
    positions = []
    p = 0
    for d in rig.dirs():
        p += 1 if d else -1
        positions.append(p)
    assert max(positions) <= 800 and min(positions) >= -500
    # Once there, another Move the same way does nothing; the other way is fine.
    rig.submit(RunCmd(direction, RAMP))
    assert rig.m.idle and rig.m.position == limit
    rig.submit(RunCmd(-direction, RAMP))
    rig.advance(0.2)
    assert rig.state() is MotorState.RUNNING


def test_run_replanned_faster_still_stops_at_the_soft_limit() -> None:
    rig = engine_rig(soft(-5000, 3000), axes=[mock_axis(endstop_min=-100_000, endstop_max=100_000)])
    rig.submit(RunCmd(1, Ramp(500.0, 2000.0, 2000.0)))
    rig.advance(0.5)
    rig.submit(RunCmd(1, Ramp(4000.0, 20000.0, 20000.0)))
    rig.engine.run_until_idle()
    assert rig.m.position == 3000 == rig.axis()
    assert set(rig.dirs()) == {True}


# ---------------------------------------------------------------- 24-bit position


def test_linear_position_wraps_at_24_bits() -> None:
    rig = engine_rig(
        motor_params(host_position=wrap24),
        axes=[mock_axis(endstop_min=-100_000, endstop_max=100_000)],
    )
    with rig.engine.lock:
        rig.m.set_position(8_388_600)
    assert rig.m.position == 8_388_600
    rig.submit(MoveToCmd(8_388_607, RAMP))
    rig.engine.run_until_idle()
    assert rig.m.position == 8_388_607 and rig.axis() == 7
    rig.submit(RunCmd(1, Ramp(1000.0, 1e6, 1e6)))
    rig.advance(0.0205)
    assert rig.stop(hard=True)
    n = rig.axis()
    assert n > 7
    assert rig.m.position == wrap24(8_388_600 + n) == -8_388_608 + (n - 8)
    # And back down across the wrap.
    rig.submit(RunCmd(-1, Ramp(1000.0, 1e6, 1e6)))
    rig.advance(0.05)
    assert rig.stop(hard=True)
    assert rig.m.position == 8_388_600 + rig.axis() and rig.m.position > 0


def test_linear_position_unbounded_without_a_host_counter() -> None:
    """Motion itself counts without bound; the 24-bit wrap is the protocol's, passed in."""
    rig = engine_rig(axes=[mock_axis(endstop_min=-100_000, endstop_max=100_000)])
    with rig.engine.lock:
        rig.m.set_position(8_388_600)
    rig.submit(MoveToCmd(8_388_610, RAMP))
    rig.engine.run_until_idle()
    assert rig.m.position == 8_388_610 and rig.axis() == 10


# ---------------------------------------------------------------- properties


moves = st.lists(
    st.tuples(
        st.integers(min_value=-400, max_value=400),
        st.sampled_from(
            [
                Ramp(3000.0, 30000.0, 30000.0),
                Ramp(1000.0, 50000.0, 8000.0),
                Ramp(5000.0, 8000.0, 100000.0),
            ]
        ),
    ),
    min_size=1,
    max_size=5,
)


@FAST
@given(moves)
def test_random_queues_end_at_the_last_target(queue: list[tuple[int, Ramp]]) -> None:
    rig = engine_rig(axes=[mock_axis(endstop_min=-100_000, endstop_max=100_000)])
    for target, r in queue:
        rig.submit(MoveToCmd(target, r))
    rig.engine.run_until_idle()
    last = queue[-1][0]
    assert rig.m.position == last == rig.axis()
    path = [0] + [t for t, _ in queue]
    assert len(rig.times()) == sum(abs(b - a) for a, b in itertools.pairwise(path))
    times = rig.times()
    assert all(b > a for a, b in itertools.pairwise(times))
    legs = [b - a for a, b in itertools.pairwise(path) if b != a]
    expected_runs: list[tuple[bool, int]] = []
    for leg in legs:
        if expected_runs and expected_runs[-1][0] == (leg > 0):
            expected_runs[-1] = (leg > 0, expected_runs[-1][1] + abs(leg))
        else:
            expected_runs.append((leg > 0, abs(leg)))
    assert direction_runs(rig.dirs()) == expected_runs


run_changes = st.lists(
    st.tuples(
        st.sampled_from([1, -1]),
        st.floats(min_value=100.0, max_value=4000.0),
        st.floats(min_value=0.01, max_value=0.3),
    ),
    min_size=1,
    max_size=6,
)


@FAST
@given(run_changes, st.booleans())
def test_random_run_changes_keep_counter_and_mechanics_together(
    changes: list[tuple[int, float, float]], hard: bool
) -> None:
    rig = engine_rig(axes=[mock_axis(endstop_min=-100_000, endstop_max=100_000)])
    for direction, speed, dt in changes:
        rig.submit(RunCmd(direction, Ramp(speed, 20000.0, 15000.0)))
        assert rig.state() is MotorState.RUNNING and not rig.m.queue
        rig.advance(dt)
        assert rig.m.position == rig.axis()
    t_stop = rig.clock.now()
    traj = rig.m.traj
    v = traj.velocity(t_stop) if traj is not None else 0.0
    before = len(rig.times())
    assert rig.stop(hard=hard)
    rig.engine.run_until_idle()
    after = len(rig.times()) - before
    if hard:
        assert after == 0
    else:
        assert after <= v * v / (2 * 15000.0) + 1
    assert rig.m.idle and rig.m.position == rig.axis()
    # DIR changes on the line match the direction changes of the steps.
    dir_events = rig.world.timeline.of(EventKind.DIR, 0)
    assert len(dir_events) >= len(direction_runs(rig.dirs()))
    line: bool | None = None
    for e in rig.world.timeline.events:
        if e.kind is EventKind.DIR:
            assert e.value != line  # only real changes are written
            line = e.value
        elif e.kind is EventKind.STEP:
            assert e.value == line


@FAST
@given(
    st.lists(
        st.tuples(st.integers(min_value=-500, max_value=500), st.sampled_from([1, -1])),
        min_size=1,
        max_size=5,
    )
)
def test_random_rotary_moves(queue: list[tuple[int, int]]) -> None:
    spr = 97
    rig = engine_rig(
        motor_params(steps_per_rev=spr), axes=[mock_axis(endstop_min=-100_000, endstop_max=100_000)]
    )
    expected = 0
    pos = 0
    for target, direction in queue:
        goal = target % spr
        expected += (goal - pos) % spr if direction > 0 else -((pos - goal) % spr)
        pos = goal
        rig.submit(MoveToCmd(target, Ramp(5000.0, 50000.0, 50000.0), direction))
    rig.engine.run_until_idle()
    assert rig.m.position == pos == queue[-1][0] % spr
    assert rig.axis() == expected


def test_debounce_forgets_the_end_stop_behind_a_reversal() -> None:
    far = mock_axis(endstop_min=-100_000, endstop_max=100_000)
    rig = engine_rig(motor_params(debounce_s=0.02), axes=[far])
    ramp = Ramp(1000.0, 1e6, 1e6)
    rig.submit(RunCmd(1, ramp))
    rig.advance(0.1)
    rig.world.force_endstop(0, "max", True)  # a glitch as the motor turns round
    rig.advance(0.0025)
    rig.submit(RunCmd(-1, ramp))
    rig.advance(0.0025)
    rig.world.force_endstop(0, "max", False)
    rig.advance(0.1)
    rig.world.force_endstop(0, "max", True)  # another glitch as it turns round again
    rig.submit(RunCmd(1, ramp))
    rig.advance(0.004)
    rig.world.force_endstop(0, "max", False)
    rig.advance(0.1)
    assert direction_runs(rig.dirs())[-1][0] is True
    assert rig.m.fault is None and rig.state() is MotorState.RUNNING


@pytest.mark.parametrize(("direction", "soft_stop"), [(1, False), (-1, False), (1, True)])
def test_run_replanned_with_a_lower_dec_still_stops_at_the_soft_limit(
    direction: int, soft_stop: bool
) -> None:
    rig = engine_rig(soft(-3000, 3000), axes=[mock_axis(endstop_min=-100_000, endstop_max=100_000)])
    rig.submit(RunCmd(1, Ramp(4000.0, 40000.0, 40000.0)))
    for _ in range(2000):
        if rig.m.position >= 2500:
            break
        rig.advance(0.001)
    # 500 steps before the limit at 4000 step/s; DEC 2000 would need 4000 steps to stop.
    rig.submit(RunCmd(direction, Ramp(1000.0, 2000.0, 2000.0)))
    if soft_stop:
        rig.advance(0.001)
        assert rig.stop(hard=False)
    rig.engine.run_until_idle()
    positions = []
    p = 0
    for d in rig.dirs():
        p += 1 if d else -1
        positions.append(p)
    assert max(positions) <= 3000
    assert rig.m.position == rig.axis()
    if not soft_stop:
        assert rig.m.position == 3000 * direction


def test_a_move_queued_behind_homing_counts_from_the_switch() -> None:
    rig = engine_rig()
    rig.submit(MoveToCmd(400, RAMP))
    rig.submit(HomeCmd(1, RAMP))
    rig.submit(MoveToCmd(-300, RAMP))
    rig.engine.run_until_idle()
    assert rig.m.position == -300 and rig.axis() == 699
    assert direction_runs(rig.dirs()) == [(True, 1000), (False, 301)]


def test_rotary_run_wraps_and_agrees_with_the_mechanics() -> None:
    rig = engine_rig(
        motor_params(steps_per_rev=50), axes=[mock_axis(endstop_min=-100_000, endstop_max=100_000)]
    )
    rig.submit(RunCmd(-1, Ramp(1000.0, 1e6, 1e6)))
    rig.advance(0.3)
    assert rig.stop(hard=True)
    assert rig.axis() < -250 and rig.m.position == rig.axis() % 50
