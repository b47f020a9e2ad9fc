"""Tests of the motion engine on the mock world under a virtual clock (no real time)."""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from motorctl.hal.backends.mock.backend import EventKind, build, build_step_io, mock_axis, world_of
from motorctl.hal.interfaces import BridgeState, MonotonicClock, VirtualClock
from motorctl.hal.spec import AxisSpec, HardwareSpec
from motorctl.motion.engine import MotionEngine
from motorctl.motion.executors.base import from_ticks, to_ticks
from motorctl.motion.executors.planner import axis_limits
from motorctl.motion.executors.thread import ThreadStepExecutor
from motorctl.motion.latency import LatencyStats
from motorctl.motion.profile import Steps, plan_move_to
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
from tests.support.rigs import engine_rig

FAST = settings(max_examples=40, deadline=None)
RAMP = Ramp(2000.0, 8000.0, 8000.0)
POLL = 0.01
MAX_LATENESS = 1e-3
TICK = 2e-9  # step times are whole nanoseconds: a gap may be 1 ns off


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


def on_tick(t: float) -> float:
    """``t`` on the step path's integer clock (1 ns ticks)."""
    return from_ticks(to_ticks(t))


def planned_times(t0: float, start: int, target: int, r: Ramp) -> list[float]:
    """The planned step times, on the executor's 1 ns ticks."""
    traj = plan_move_to(t0, float(start), 0.0, float(target), r.speed, r.acc, r.dec)
    return [on_tick(t) for t, _ in Steps(traj, start)]


def trapezoid_times(distance: int, vmax: float, acc: float, dec: float) -> list[float]:
    """Closed-form step times (from 0) of a move from rest to rest over ``distance`` steps."""
    n_total = abs(distance)
    d = float(n_total)
    if vmax * vmax / (2 * acc) + vmax * vmax / (2 * dec) <= d:
        vp = vmax
    else:
        vp = math.sqrt(2 * d * acc * dec / (acc + dec))
    da, dd = vp * vp / (2 * acc), vp * vp / (2 * dec)
    ta, td = vp / acc, vp / dec
    tc = (d - da - dd) / vp
    total = ta + tc + td
    out = []
    for n in range(1, n_total + 1):
        if n <= da:
            out.append(math.sqrt(2 * n / acc))
        elif n <= d - dd:
            out.append(ta + (n - da) / vp)
        else:
            out.append(total - math.sqrt(max(2 * (d - n) / dec, 0.0)))
    return out


# ---------------------------------------------------------------- single moves


@pytest.mark.parametrize(
    ("target", "ramp"),
    [
        (200, Ramp(2000.0, 8000.0, 8000.0)),  # triangular
        (900, Ramp(2000.0, 8000.0, 8000.0)),  # trapezoid
        (-700, Ramp(1500.0, 6000.0, 20000.0)),  # downwards, asymmetric ramps
        (1, Ramp(100.0, 1000.0, 1000.0)),
    ],
)
def test_move_timeline_is_the_planned_one(target: int, ramp: Ramp) -> None:
    rig = engine_rig()
    t0 = rig.clock.now()
    rig.submit(MoveToCmd(target, ramp))
    assert rig.state() is MotorState.MOVING
    rig.engine.run_until_idle()

    times = rig.times()
    assert times == planned_times(t0, 0, target, ramp)
    closed = [t0 + t for t in trapezoid_times(target, ramp.speed, ramp.acc, ramp.dec)]
    assert times == pytest.approx(closed, abs=1e-9)
    assert set(rig.dirs()) == {target > 0}
    assert rig.m.position == target == rig.axis()
    assert rig.state() is MotorState.IDLE and rig.m.idle
    assert rig.event_times("start") == [t0]
    assert rig.event_times("idle") == [times[-1]]
    # DIR was set once, a setup time before the first step; no step was late.
    dir_events = rig.world.timeline.of(EventKind.DIR, 0)
    assert len(dir_events) == 1 and dir_events[0].value == (target > 0)
    assert times[0] - dir_events[0].t >= rig.m.params.dir_setup_s
    assert rig.executor.stats.count == abs(target)
    assert rig.executor.stats.max_s == 0.0


def test_move_to_current_position_does_nothing() -> None:
    rig = engine_rig()
    rig.submit(MoveToCmd(0, RAMP))
    assert rig.m.idle
    rig.advance(1.0)
    assert rig.times() == []


def test_invert_dir_swaps_the_dir_line_not_the_motion() -> None:
    rig = engine_rig(axes=[AxisSpec(invert_dir=True)])
    rig.submit(MoveToCmd(30, RAMP))
    rig.engine.run_until_idle()
    assert [e.value for e in rig.world.timeline.of(EventKind.DIR, 0)] == [False]
    assert rig.m.position == 30 == rig.axis()


def test_two_motors_step_independently() -> None:
    rig = engine_rig(MotorParams(name="a"), MotorParams(name="b"))
    t0 = rig.clock.now()
    rig.submit(MoveToCmd(300, RAMP), 0)
    rig.submit(MoveToCmd(-150, Ramp(900.0, 3000.0, 3000.0)), 1)
    rig.engine.run_until_idle()
    assert rig.times(0) == planned_times(t0, 0, 300, RAMP)
    assert rig.times(1) == planned_times(t0, 0, -150, Ramp(900.0, 3000.0, 3000.0))
    assert (rig.motor(0).position, rig.motor(1).position) == (300, -150)
    assert (rig.axis(0), rig.axis(1)) == (300, -150)


def test_position_readable_while_moving() -> None:
    rig = engine_rig()
    rig.submit(MoveToCmd(900, RAMP))
    seen = []
    for _ in range(100):
        if rig.m.idle:
            break
        rig.advance(0.05)
        seen.append(rig.m.position)
        assert rig.m.position == rig.axis()
    assert seen == sorted(seen) and 0 < seen[0] < 900 and seen[-1] == 900 and rig.m.idle


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
    rig = engine_rig(MotorParams(queue_depth=3))
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


def test_engine_shutdown_soft_stops_everything() -> None:
    rig = engine_rig(MotorParams(), MotorParams(), dc=True)
    rig.submit(RunCmd(1, RAMP), 0)
    rig.submit(MoveToCmd(-5000, RAMP), 1)
    with rig.engine.lock:
        rig.engine.dc_run(True, 10.0, BridgeState.COAST)
    rig.advance(0.5)
    rig.engine.shutdown()
    assert rig.engine.dc is not None and not rig.engine.dc.running
    assert rig.world.bridge is not None and rig.world.bridge.state is BridgeState.BRAKE
    rig.engine.run_until_idle(limit_s=1.0)
    assert not rig.engine.any_active
    assert [m.position for m in rig.engine.motors] == [rig.axis(0), rig.axis(1)]


# ---------------------------------------------------------------- homing


def test_one_phase_homing() -> None:
    rig = engine_rig()
    rig.submit(MoveToCmd(300, RAMP))
    rig.submit(HomeCmd(-1, Ramp(1000.0, 5000.0, 5000.0)))
    rig.engine.run_until_idle()
    assert rig.axis() == -1000  # the switch closes at -1000
    assert rig.m.position == 0 and rig.m.idle and rig.m.fault is None
    assert direction_runs(rig.dirs()) == [(True, 300), (False, 1300)]
    assert len(rig.event_times("homed")) == 1
    # Homed means: the next move counts from the switch.
    rig.submit(MoveToCmd(250, RAMP))
    rig.engine.run_until_idle()
    assert rig.m.position == 250 and rig.axis() == -750


def test_homing_clears_a_lost_position() -> None:
    rig = engine_rig()
    rig.m.position_lost = True
    rig.submit(HomeCmd(1, RAMP))
    rig.engine.run_until_idle()
    assert not rig.m.position_lost and rig.axis() == 1000 and rig.m.position == 0


def test_two_phase_homing_backs_off_and_reapproaches_slowly() -> None:
    homing = HomingParams(pull_off=50, second_speed=200.0)
    rig = engine_rig(MotorParams(homing=homing))
    ramp = Ramp(1500.0, 6000.0, 6000.0)
    rig.submit(HomeCmd(-1, ramp))
    assert rig.state() is MotorState.HOMING
    rig.engine.run_until_idle()
    assert rig.m.position == 0 and rig.axis() == -1000 and rig.m.fault is None
    steps = rig.steps()
    assert direction_runs(rig.dirs()) == [(False, 1000), (True, 50), (False, 50)]
    seek, approach = steps[:1000], steps[1050:]
    seek_gaps = [b.t - a.t for a, b in itertools.pairwise(seek)]
    approach_gaps = [b.t - a.t for a, b in itertools.pairwise(approach)]
    assert min(seek_gaps) == pytest.approx(1 / 1500, abs=TICK)
    assert min(approach_gaps) >= 1 / 200 - TICK
    assert approach_gaps[-1] == pytest.approx(1 / 200, abs=TICK)
    assert len(rig.event_times("homed")) == 1 and len(rig.event_times("idle")) == 1


def test_two_phase_homing_with_second_speed_above_the_ramp_uses_the_ramp() -> None:
    homing = HomingParams(pull_off=20, second_speed=5000.0)
    rig = engine_rig(MotorParams(homing=homing))
    rig.submit(HomeCmd(1, Ramp(400.0, 100_000.0, 100_000.0)))
    rig.engine.run_until_idle()
    approach = rig.steps()[1020:]
    assert len(approach) == 20
    gaps = [b.t - a.t for a, b in itertools.pairwise(approach)]
    assert min(gaps) >= 1 / 400 - TICK
    assert rig.axis() == 1000 and rig.m.position == 0


# A stall is read from the driver by the monitor, never on the step path: it is seen within
# one driver poll, so stall homing runs on for up to speed * POLL steps after the stall.
STALL_OVERRUN = int(RAMP.speed * POLL) + 1


def test_stall_homing() -> None:
    rig = engine_rig(MotorParams(homing=HomingParams(source=HomingSource.STALL)))
    rig.submit(HomeCmd(1, RAMP))
    rig.engine.run_until_idle()
    # The mock stalls once it is pushed past its end stop.
    assert rig.m.fault is None and rig.m.position == 0
    assert 1001 <= rig.axis() <= 1001 + STALL_OVERRUN
    assert rig.event_times("homed")


def test_two_phase_stall_homing() -> None:
    homing = HomingParams(source=HomingSource.STALL, pull_off=30, second_speed=300.0)
    rig = engine_rig(MotorParams(homing=homing))
    rig.submit(HomeCmd(-1, RAMP))
    rig.engine.run_until_idle()
    assert rig.m.fault is None and rig.m.position == 0
    runs = direction_runs(rig.dirs())
    assert [d for d, _ in runs] == [False, True, False] and runs[1] == (True, 30)
    assert 1001 <= runs[0][1] <= 1001 + STALL_OVERRUN
    # the re-approach stalls again once past the stop (seen within a poll at 300 step/s)
    assert -1001 - int(300 * POLL) - 1 <= rig.axis() <= -1001


def test_after_stall_homing_the_motor_moves_away_without_a_stall_fault() -> None:
    rig = engine_rig(MotorParams(homing=HomingParams(source=HomingSource.STALL)))
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
    rig = engine_rig(MotorParams(homing=HomingParams(max_travel=300)))
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
    rig = engine_rig(MotorParams(homing=HomingParams(pull_off=40)), axes=[far])
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
    rig = engine_rig(MotorParams(homing=HomingParams(pull_off=40)), axes=[far])
    rig.submit(HomeCmd(1, RAMP))
    rig.advance(0.2)
    rig.world.force_endstop(0, "max", True)
    rig.engine.run_until_idle()
    assert rig.state() is MotorState.FAULT
    assert rig.m.fault is not None and "still active" in rig.m.fault
    assert direction_runs(rig.dirs())[-1] == (False, 40)


def test_homing_that_starts_on_the_switch_does_not_move() -> None:
    rig = engine_rig()
    rig.world.axes[0].position = -1000  # resting on the min switch
    rig.submit(HomeCmd(-1, RAMP))
    assert rig.m.idle and rig.m.position == 0
    rig.advance(0.5)
    assert rig.times() == [] and rig.m.fault is None
    assert len(rig.event_times("homed")) == 1


def test_two_phase_homing_that_starts_on_the_switch_backs_off_first() -> None:
    rig = engine_rig(MotorParams(homing=HomingParams(pull_off=25, second_speed=100.0)))
    rig.world.axes[0].position = 1000
    rig.submit(HomeCmd(1, RAMP))
    assert rig.state() is MotorState.HOMING
    rig.engine.run_until_idle()
    assert direction_runs(rig.dirs()) == [(False, 25), (True, 25)]
    assert rig.axis() == 1000 and rig.m.position == 0 and rig.m.fault is None


def test_homing_with_debounce_ignores_short_glitches() -> None:
    far = mock_axis(endstop_min=-100_000, endstop_max=100_000)
    rig = engine_rig(MotorParams(debounce_s=0.02), axes=[far])
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
    rig.engine.run_until_idle()
    assert rig.m.fault is None and rig.m.position == 0
    first_active = min(t for t in rig.times() if t >= t_on)
    t_trigger = rig.times()[-1]
    assert first_active + 0.02 <= t_trigger < first_active + 0.02 + 1.5e-3


def test_endstop_hit_with_debounce_outside_homing() -> None:
    far = mock_axis(endstop_min=-100_000, endstop_max=100_000)
    rig = engine_rig(MotorParams(debounce_s=0.0105), axes=[far])
    rig.submit(RunCmd(-1, Ramp(1000.0, 1e6, 1e6)))
    rig.advance(0.1)
    rig.world.force_endstop(0, "min", True)
    t_on = rig.clock.now()
    rig.advance(0.1)
    assert rig.m.fault == "end stop hit"
    after = [t for t in rig.times() if t > t_on]  # the steps that read it active
    # debounced from the edge's own time (the kernel's timestamp on real lines)
    assert 0.0105 - TICK <= after[-1] - t_on < 0.0105 + 1e-3
    assert len(after) in (11, 12)


def test_debounce_forgets_what_it_no_longer_watches() -> None:
    """Two short glitches far apart, each shorter than the debounce, never add up."""
    far = mock_axis(endstop_min=-100_000, endstop_max=100_000)
    rig = engine_rig(MotorParams(debounce_s=0.02), axes=[far])
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
    assert rig.axis() == 400 and rig.m.position == 0 and rig.m.fault is None


# ---------------------------------------------------------------- end stops and faults


def test_endstop_hit_outside_homing_is_a_hard_stop_and_fault() -> None:
    rig = engine_rig()
    rig.submit(MoveToCmd(1500, RAMP))
    rig.submit(MoveToCmd(0, RAMP))
    rig.engine.run_until_idle()
    assert rig.state() is MotorState.FAULT and rig.m.fault == "end stop hit"
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
    rig.submit(MoveToCmd(-299, RAMP))  # one step towards it: that hits it
    rig.engine.run_until_idle()
    assert rig.m.fault == "end stop hit"


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
    rig = engine_rig(MotorParams(steps_per_rev=200))
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
        MotorParams(steps_per_rev=100), axes=[mock_axis(endstop_min=-(10**6), endstop_max=10**6)]
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
    rig = engine_rig(MotorParams(steps_per_rev=360))
    rig.submit(HomeCmd(1, RAMP))
    rig.engine.run_until_idle()
    assert rig.m.position == 0 and rig.axis() == 1000
    rig.submit(MoveToCmd(10, RAMP, -1))
    rig.engine.run_until_idle()
    assert rig.m.position == 10 and rig.axis() == 650


# ---------------------------------------------------------------- soft limits


def soft(lo: int, hi: int) -> MotorParams:
    return MotorParams(soft_min=lo, soft_max=hi)


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
        MotorParams(host_position=wrap24),
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


# ---------------------------------------------------------------- DC motor


@pytest.mark.parametrize("end", [BridgeState.BRAKE, BridgeState.COAST])
def test_dc_run_ends_at_exactly_now_plus_duration(end: BridgeState) -> None:
    rig = engine_rig(dc=True)
    t0 = rig.clock.now()
    with rig.engine.lock:
        rig.engine.dc_run(False, 0.25, end)
    assert rig.engine.any_active
    rig.engine.run_until_idle()
    dc = [(e.t, e.value) for e in rig.world.timeline.of(EventKind.DC)]
    assert dc == [(t0, "reverse"), (t0 + 0.25, end.value)]
    assert rig.world.bridge is not None and rig.world.bridge.state is end


def test_dc_new_run_replaces_the_old_one() -> None:
    rig = engine_rig(dc=True)
    t0 = rig.clock.now()
    with rig.engine.lock:
        rig.engine.dc_run(True, 1.0, BridgeState.COAST)
    t1 = rig.advance(0.3)
    with rig.engine.lock:
        rig.engine.dc_run(True, 0.5, BridgeState.BRAKE)
    t2 = rig.advance(0.25)
    with rig.engine.lock:
        rig.engine.dc_run(False, 0.5, BridgeState.COAST)
    rig.advance(2.0)
    dc = [(e.t, e.value) for e in rig.world.timeline.of(EventKind.DC)]
    assert dc == [(t0, "forward"), (t2, "reverse"), (t2 + 0.5, "coast")]
    assert t1 + 0.5 > t2  # the second run never got to brake


def test_dc_duration_zero_stops_at_once() -> None:
    rig = engine_rig(dc=True)
    t0 = rig.clock.now()
    with rig.engine.lock:
        rig.engine.dc_run(True, 1.0, BridgeState.COAST)
    t1 = rig.advance(0.1)
    with rig.engine.lock:
        rig.engine.dc_run(True, 0.0, BridgeState.BRAKE)
    assert rig.engine.dc is not None and not rig.engine.dc.running
    rig.advance(2.0)
    dc = [(e.t, e.value) for e in rig.world.timeline.of(EventKind.DC)]
    assert dc == [(t0, "forward"), (t1, "brake")]


def test_dc_run_rejects_a_driving_end_state_and_missing_motor() -> None:
    rig = engine_rig(dc=True)
    with rig.engine.lock, pytest.raises(ValueError):
        rig.engine.dc_run(True, 1.0, BridgeState.FORWARD)
    with engine_rig().engine.lock, pytest.raises(LookupError):
        engine_rig().engine.dc_run(True, 1.0, BridgeState.BRAKE)


# ---------------------------------------------------------------- latency statistics


def test_latency_percentiles_on_known_data() -> None:
    stats = LatencyStats(threshold_s=50e-6)
    for us in range(1, 101):
        stats.record(us * 1e-6)
    assert stats.count == 100
    assert stats.percentile_us(50) == 50.0
    assert stats.percentile_us(90) == 90.0
    assert stats.percentile_us(99) == 99.0
    assert stats.percentile_us(100) == 100.0
    assert stats.percentile_us(0) == 1.0
    assert stats.late == 50
    assert stats.max_s == pytest.approx(100e-6)


def test_latency_every_microsecond_lands_in_its_bin() -> None:
    stats = LatencyStats()
    for us in range(20_000):
        stats.record(us * 1e-6)
    assert stats.bins == [1] * 20_000 + [0]
    stats.record(20_000e-6)
    assert stats.bins[-1] == 1


def test_latency_nearest_rank() -> None:
    stats = LatencyStats()
    for us in range(1, 1001):
        stats.record(us * 1e-6)
    assert stats.percentile_us(99.9) == 999.0
    assert stats.percentile_us(99) == 990.0
    s = stats.summary()
    assert (s["steps"], s["p50_us"], s["p99_us"], s["p999_us"]) == (1000, 500.0, 990.0, 999.0)
    assert s["max_us"] == 1000.0


def test_latency_overflow_early_and_reset() -> None:
    stats = LatencyStats(threshold_s=100e-6)
    assert stats.percentile_us(50) == 0.0
    stats.record(-5e-6)  # early edges count as on time
    stats.record(0.0)
    stats.record(0.035)  # beyond the histogram: reported as the maximum
    assert stats.percentile_us(50) == 0.0
    assert stats.percentile_us(100) == pytest.approx(35_000.0)
    assert stats.late == 1
    stats.reset()
    assert stats.count == 0 and stats.late == 0 and stats.percentile_us(99) == 0.0


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.one_of(st.integers(-50, 3_000), st.integers(0, 25_000)), min_size=1, max_size=400),
    st.booleans(),
)
def test_latency_blocks_agree_with_a_full_scan(lateness_us: list[int], shared: bool) -> None:
    """The status reads the histogram and percentiles through the block counts (a cost of
    the busy blocks, not 20,001 bins): the same answers as a scan of every bin."""
    import array

    from motorctl.motion.latency import BINS, CELLS

    cells = memoryview(array.array("q", bytes(8 * CELLS))) if shared else None
    stats = LatencyStats(cells=cells)
    for us in lateness_us:
        stats.record_ns(us * 1000 + 500)
    bins = stats.bins
    assert stats.histogram() == {us: n for us, n in enumerate(bins) if n}
    cum = list(itertools.accumulate(bins))
    for q in (0, 1, 50, 99, 99.9, 100):
        rank = max(1, math.ceil(q / 100 * len(lateness_us) - 1e-12 * q / 100 * len(lateness_us)))
        us = next(i for i, c in enumerate(cum) if c >= rank)
        want = float(us) if us < BINS else stats.max_s * 1e6
        assert stats.percentile_us(q) == want, q


# ---------------------------------------------------------------- engine plumbing


def test_engine_checks_its_configuration_and_clock() -> None:
    clock = VirtualClock()
    spec = HardwareSpec(axes=(AxisSpec(),))
    hw = build(spec, clock)
    one = ThreadStepExecutor(hw, "mock", spec, axis_limits([MotorParams()], 0.0))
    with pytest.raises(ValueError, match="2 motors configured"):
        MotionEngine(hw, [MotorParams(), MotorParams()], one)
    with pytest.raises(ValueError, match="real clock"):
        MotionEngine(hw, [MotorParams()], one).start()
    real = build(spec, MonotonicClock())
    ex = ThreadStepExecutor(real, "mock", spec, axis_limits([MotorParams()], 0.0))
    engine = MotionEngine(real, [MotorParams()], ex)
    with pytest.raises(TypeError):
        engine.run_until(1.0)
    with pytest.raises(TypeError):
        engine.run_until_idle()
    with pytest.raises(TypeError, match="virtual clock"):
        ex.advance(1.0)


def test_run_until_idle_gives_up_on_an_endless_run() -> None:
    rig = engine_rig(axes=[mock_axis(endstop_min=-100_000, endstop_max=100_000)])
    rig.submit(RunCmd(1, Ramp(10.0, 100.0, 100.0)))
    with pytest.raises(TimeoutError):
        rig.engine.run_until_idle(limit_s=1.0)


def test_deadlines() -> None:
    rig = engine_rig(dc=True)
    e = rig.engine
    assert rig.executor.next_deadline() is None
    assert e.next_deadline() == rig.clock.now() + POLL
    with e.lock:
        e.dc_run(True, 0.001, BridgeState.BRAKE)
        e.service(rig.clock.now())
    assert e.next_deadline() == rig.clock.now() + 0.001
    rig.submit(MoveToCmd(10, RAMP))
    with e.lock:
        e.service(rig.clock.now())
    first = planned_times(rig.clock.now(), 0, 10, RAMP)[0]
    assert e.next_deadline() == rig.clock.now() + 0.001 < first
    rig.advance(0.002)
    assert rig.executor.next_deadline() == first  # handed to the step core
    assert e.next_deadline() == min(first, rig.clock.now() - 0.002 + POLL)


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
        MotorParams(steps_per_rev=spr), axes=[mock_axis(endstop_min=-100_000, endstop_max=100_000)]
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
    rig = engine_rig(MotorParams(debounce_s=0.02), axes=[far])
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


RAMPS = [
    Ramp(3000.0, 30000.0, 30000.0),
    Ramp(800.0, 4000.0, 1500.0),
    Ramp(5000.0, 8000.0, 100000.0),
    Ramp(2000.0, 100000.0, 3000.0),
]
actions = st.lists(
    st.one_of(
        st.tuples(
            st.just("move"), st.integers(min_value=-1000, max_value=1000), st.sampled_from(RAMPS)
        ),
        st.tuples(st.just("run"), st.sampled_from([1, -1]), st.sampled_from(RAMPS)),
        st.tuples(st.just("stop"), st.booleans(), st.just(RAMPS[0])),
    ),
    min_size=1,
    max_size=8,
)


@FAST
@given(actions, st.lists(st.floats(min_value=0.0, max_value=0.4), min_size=8, max_size=8))
def test_random_command_mixes_keep_every_invariant(
    script: list[tuple[str, int | bool, Ramp]], waits: list[float]
) -> None:
    rig = engine_rig(soft(-1000, 1000), axes=[mock_axis(endstop_min=-100_000, endstop_max=100_000)])
    for (kind, arg, ramp), dt in zip(script, waits, strict=False):
        if kind == "stop":
            assert rig.stop(hard=bool(arg))
            if arg:
                assert rig.m.idle and rig.m.traj is None and not rig.executor.planned(0)
            assert not rig.m.queue
        elif not rig.m.queue_full:
            if kind == "move":
                assert rig.m.target_allowed(int(arg))
                rig.submit(MoveToCmd(int(arg), ramp))
            else:
                rig.submit(RunCmd(int(arg), ramp))
        rig.advance(dt)
        assert rig.m.position == rig.axis()
        assert rig.m.fault is None
    assert rig.stop(hard=False)
    rig.engine.run_until_idle()
    assert rig.m.idle and rig.m.position == rig.axis()
    p = lo = hi = 0
    for d in rig.dirs():
        p += 1 if d else -1
        lo, hi = min(lo, p), max(hi, p)
    assert lo >= -1000 and hi <= 1000
    times = rig.times()
    assert all(b > a for a, b in itertools.pairwise(times))


def test_a_move_queued_behind_homing_counts_from_the_switch() -> None:
    rig = engine_rig()
    rig.submit(MoveToCmd(400, RAMP))
    rig.submit(HomeCmd(1, RAMP))
    rig.submit(MoveToCmd(-300, RAMP))
    rig.engine.run_until_idle()
    assert rig.m.position == -300 and rig.axis() == 700
    assert direction_runs(rig.dirs()) == [(True, 1000), (False, 300)]


def test_a_fault_on_one_motor_leaves_the_other_alone() -> None:
    rig = engine_rig(MotorParams(), MotorParams())
    rig.submit(MoveToCmd(800, RAMP), 0)
    rig.submit(MoveToCmd(-800, RAMP), 1)
    rig.advance(0.1)
    rig.world.inject_fault(0, "short")
    rig.engine.run_until_idle()
    assert rig.motor(0).fault == "driver fault: short" and rig.motor(1).fault is None
    assert rig.motor(1).position == -800 == rig.axis(1)
    assert rig.motor(0).position == rig.axis(0) < 800


def test_rotary_run_wraps_and_agrees_with_the_mechanics() -> None:
    rig = engine_rig(
        MotorParams(steps_per_rev=50), axes=[mock_axis(endstop_min=-100_000, endstop_max=100_000)]
    )
    rig.submit(RunCmd(-1, Ramp(1000.0, 1e6, 1e6)))
    rig.advance(0.3)
    assert rig.stop(hard=True)
    assert rig.axis() < -250 and rig.m.position == rig.axis() % 50


def test_mock_stall_only_while_driven_past_the_stop() -> None:
    clock = VirtualClock()
    spec = HardwareSpec(axes=(mock_axis(endstop_min=-5, endstop_max=5),))
    hw = build(spec, clock)
    world = world_of(hw)
    out, driver = build_step_io(spec, clock, hw).outputs, hw.steppers[0].driver
    out.set_direction(0, True)
    for _ in range(5):
        out.pulse([0], 1e-6)
    assert not driver.status().stall and world.axes[0].position == 5
    out.pulse([0], 1e-6)
    assert driver.status().stall  # pushed past the max stop
    out.set_direction(0, False)
    assert not driver.status().stall  # backing out
    world.inject_stall(0, True)
    assert driver.status().stall
    world.inject_stall(0, False)
    for _ in range(12):
        out.pulse([0], 1e-6)
    assert world.axes[0].position == -6 and driver.status().stall
    spec2 = HardwareSpec(axes=(mock_axis(invert_dir=True, endstop_max=0),))
    hw2 = build(spec2, clock)
    out2 = build_step_io(spec2, clock, hw2).outputs
    out2.set_direction(0, True)
    out2.pulse([0], 1e-6)
    assert hw2.steppers[0].driver.status().stall  # logical direction, not the DIR level
