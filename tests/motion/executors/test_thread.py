"""The ``thread`` step executor: with the engine's threads on the real monotonic clock, and
on a virtual clock the engine's side of the lateness rules (a stall latches E4, or slides).

Every wait is on an event set by an engine listener (or a bounded wait for a condition) with a
generous timeout; the assertions are about positions and step counts, never about timing.
"""

from __future__ import annotations

import gc
import itertools
from collections.abc import Iterator

import pytest

from motorctl.hal.backends.mock.backend import build
from motorctl.hal.backends.mock.world import EventKind, mock_axis, world_of
from motorctl.hal.interfaces import BridgeState, MonotonicClock, VirtualClock
from motorctl.hal.spec import AxisSpec, HardwareSpec
from motorctl.motion.engine import MotionEngine
from motorctl.motion.executors.base import to_ticks
from motorctl.motion.executors.planner import axis_limits
from motorctl.motion.executors.thread import ThreadStepExecutor
from motorctl.motion.rt import GcPolicy
from motorctl.motion.types import HomeCmd, MotorParams, MotorState, MoveToCmd, Ramp, RunCmd
from tests.support.motor_defaults import motor_params
from tests.support.rigs import FAR, EngineRig, engine_rig
from tests.support.wait import until

FAST = Ramp(4000.0, 40000.0, 40000.0)


@pytest.fixture
def live(request: pytest.FixtureRequest) -> Iterator[EngineRig]:
    params: MotorParams = getattr(request, "param", motor_params())
    # the mock's own rule (simulated motors: late steps slide), as the embedded default's
    rig = engine_rig(
        params,
        axes=[mock_axis(endstop_min=-5000, endstop_max=5000)],
        dc=True,
        clock=MonotonicClock(),
        max_error_s=5e-6,
        lag_faults=None,
        driver_poll_s=0.005,
    )
    rig.start()
    try:
        yield rig
    finally:
        rig.close()
        assert rig.executor.health().reason is None  # closed, not died


def test_refuses_a_virtual_clock() -> None:
    clock = VirtualClock()
    spec = HardwareSpec(axes=(AxisSpec(),))
    hw = build(spec, clock)
    ex = ThreadStepExecutor(hw, "mock", spec, axis_limits([motor_params()], 0.0))
    with pytest.raises(ValueError, match="real clock"):
        MotionEngine(hw, [motor_params()], ex).start()


def test_a_short_move_completes(live: EngineRig) -> None:
    report = live.executor.realtime()
    assert report is not None and report.refused() == []  # nothing asked, nothing refused
    live.submit(MoveToCmd(400, FAST))
    live.wait("idle")
    assert live.settled() == (400, 400, 400)
    assert {e.value for e in live.world.timeline.of(EventKind.STEP, 0)} == {True}
    assert live.m.state is MotorState.IDLE and live.m.idle
    assert live.executor.stats.count == 400
    assert live.executor.health().counters["steps"] == 400


def test_queued_moves_run_in_order(live: EngineRig) -> None:
    live.submit(MoveToCmd(300, FAST))
    live.submit(MoveToCmd(-200, FAST))
    live.submit(MoveToCmd(50, FAST))
    live.wait("idle")
    values = [e.value for e in live.world.timeline.of(EventKind.STEP, 0)]
    assert values == [True] * 300 + [False] * 500 + [True] * 250
    assert live.settled() == (50, 50, 1050)


def test_homing_on_the_real_clock(live: EngineRig) -> None:
    live.submit(MoveToCmd(-4000, Ramp(20000.0, 200000.0, 200000.0)))
    live.submit(HomeCmd(-1, FAST))
    live.wait("idle")
    assert live.signals["homed"].is_set()
    pos, axis, _ = live.settled()
    assert (pos, axis) == (0, -4999)  # zero where the switch at -5000 released


@pytest.mark.parametrize("live", [motor_params(soft_min=-100, soft_max=350)], indirect=True)
def test_a_run_ends_at_the_soft_limit(live: EngineRig) -> None:
    live.submit(RunCmd(1, FAST))
    live.wait("idle")
    assert live.settled() == (350, 350, 350)


@pytest.mark.parametrize("hard", [True, False])
def test_stop_from_another_thread(live: EngineRig, hard: bool) -> None:
    live.submit(RunCmd(-1, Ramp(2000.0, 20000.0, 20000.0)))
    live.wait("start")
    live.wait_steps(100)
    assert live.stop(hard=hard)
    live.wait("idle")
    pos, axis, steps = live.settled()
    assert pos == axis == -steps and steps >= 100
    assert live.m.idle


def test_driver_fault_on_the_real_clock(live: EngineRig) -> None:
    live.submit(RunCmd(1, Ramp(2000.0, 20000.0, 20000.0)))
    live.wait_steps(20)
    live.world.inject_fault(0, "over-temperature")
    live.wait("fault")
    assert live.m.fault == "driver fault: over-temperature"
    assert not live.stop(hard=False)
    live.world.inject_fault(0, None)
    assert live.stop(hard=False)
    live.wait("cleared")
    pos, axis, steps = live.settled()
    assert pos == axis == steps


def test_dc_run_on_the_real_clock(live: EngineRig) -> None:
    bridge = live.world.bridge
    assert bridge is not None
    with live.engine.lock:
        live.engine.dc_run(True, 0.05, BridgeState.COAST)
    live.engine.wake.set()

    def done() -> bool:
        with live.engine.lock:
            return not live.engine.any_active

    until("the DC run's end", done, every_s=0.005)
    assert bridge.state is BridgeState.COAST
    assert [e.value for e in live.world.timeline.of(EventKind.DC)] == ["forward", "coast"]


def test_gc_policy_switches_automatic_collection() -> None:
    was = gc.isenabled()
    policy = GcPolicy()
    try:
        policy.motion(True)
        assert not gc.isenabled()
        policy.motion(False)
        assert gc.isenabled()
    finally:
        if was:
            gc.enable()
        else:
            gc.disable()


def test_gc_policy_ready_collects_freezes_and_turns_automatic_collection_on() -> None:
    """A serving start runs with automatic collection off (daemon/start/launch.py): ready()
    turns it on again after its collection."""
    was = gc.isenabled()
    gc.disable()
    try:
        GcPolicy().ready()
        assert gc.isenabled()
        assert gc.get_freeze_count() > 0
    finally:
        gc.unfreeze()
        if not was:
            gc.disable()


# ---------------------------------------------------------------- the engine's side


def engine_rig_1(
    start_speed: float, lag_faults: bool = True, ahead_s: float | None = None
) -> tuple[VirtualClock, MotionEngine, ThreadStepExecutor]:
    """One motor on a virtual clock; ``ahead_s`` None: one step ahead (re-plans at once)."""
    clock = VirtualClock()
    rig = engine_rig(
        motor_params(max_speed=10_000.0, start_speed=start_speed),
        axes=[FAR],
        clock=clock,
        lag_faults=lag_faults,
        ahead_s=ahead_s,
    )
    return clock, rig.engine, rig.executor


def test_a_lag_beyond_the_tolerance_latches_e4_and_loses_the_position() -> None:
    clock, engine, ex = engine_rig_1(100.0)
    with engine.lock:
        engine.motors[0].submit(RunCmd(1, Ramp(5000.0, 1e6, 1e6)), clock.now())
    engine.run_until(clock.now() + 0.2)
    made = ex.position(0)
    clock.advance(0.05)  # the executor stalls
    engine.run_until(clock.now() + 0.2)
    m = engine.motors[0]
    assert m.state is MotorState.FAULT and m.fault is not None
    assert m.fault.startswith("step timing lost") and "full steps" in m.fault
    assert m.position_lost and m.faults == {"timing_lost": 1}
    assert ex.position(0) == made
    assert ex.health().counters["timing_lost"] == 1
    assert ex.motor_timing(0)["lag_faults"] == 1
    with engine.lock:  # StopMove clears it (the driver reports nothing)
        assert m.stop(hard=True, now=clock.now())
    assert m.idle and m.fault is None and m.position_lost


def _move_with_a_stall(
    start_speed: float, lag_faults: bool, stall: float, ahead_s: float | None
) -> tuple[VirtualClock, MotionEngine, ThreadStepExecutor, float]:
    """MoveTo 3,000 at 5,000 step/s; the executor stalls ``stall`` s in the cruise."""
    clock, engine, ex = engine_rig_1(start_speed, lag_faults, ahead_s)
    t0 = clock.now()
    with engine.lock:
        engine.motors[0].submit(MoveToCmd(3000, Ramp(5000.0, 1e6, 1e6)), t0)
    engine.run_until(t0 + 0.1)
    clock.advance(stall)
    engine.run_until(t0 + 2.0)
    return clock, engine, ex, t0


@pytest.mark.parametrize("ahead_s", [0.02, None])
@pytest.mark.parametrize(("start_speed", "lag_faults"), [(9000.0, True), (100.0, False)])
def test_a_slid_move_ends_at_its_target_later_by_the_stall(
    start_speed: float, lag_faults: bool, ahead_s: float | None
) -> None:
    """Below the start speed (real rule) and on a simulated motor (any speed), a 50 ms stall
    (longer than the planner's 20 ms horizon) slides the move: it reaches its target, no
    fault; every step keeps the spacing it has without the stall but the one after the
    stall: the planner went on feeding the executor on the motor's slid time."""
    _clock, engine, ex, t0 = _move_with_a_stall(start_speed, lag_faults, 0.05, ahead_s)
    m = engine.motors[0]
    assert m.idle and m.fault is None and not m.position_lost and m.faults == {}
    assert m.position == 3000 == ex.position(0)
    times = world_of(engine.hw).timeline.step_times(0)
    timing = ex.motor_timing(0)
    assert timing["late_absorbed"] == 1 and timing["lag_faults"] == 0
    assert 49.7 <= timing["slid_ms"] <= 50.0
    assert timing["worst_late_us"] == pytest.approx(timing["slid_ms"] * 1000, abs=0.1)
    assert timing["worst_lag_full_steps"] == pytest.approx(
        timing["slid_ms"] / 1000 * 5000 / 16, rel=1e-3
    )
    # the same move without the stall: the same gaps, but one longer by the slide
    _, engine2, _, t2 = _move_with_a_stall(start_speed, lag_faults, 0.0, ahead_s)
    plain = world_of(engine2.hw).timeline.step_times(0)
    assert len(times) == len(plain) == 3000
    gaps = [to_ticks(b) - to_ticks(a) for a, b in itertools.pairwise(times)]
    plain_gaps = [to_ticks(b) - to_ticks(a) for a, b in itertools.pairwise(plain)]
    differ = [i for i, (g, h) in enumerate(zip(gaps, plain_gaps, strict=True)) if abs(g - h) > 2]
    assert len(differ) == 1
    i = differ[0]
    assert gaps[i] - plain_gaps[i] == pytest.approx(timing["slid_ms"] * 1e6, abs=2)
    assert times[-1] - t0 - (plain[-1] - t2) == pytest.approx(timing["slid_ms"] / 1000, abs=1e-6)


def test_a_soft_stop_after_a_slide_decelerates_from_the_executed_state() -> None:
    """30 ms of slide, then a soft StopMove: the deceleration takes over within the lead and
    one segment of the command (not after everything handed over), as the status reports."""
    clock, engine, ex = engine_rig_1(9000.0, ahead_s=0.02)
    t0 = clock.now()
    with engine.lock:
        engine.motors[0].submit(RunCmd(1, Ramp(5000.0, 50_000.0, 50_000.0)), t0)
    engine.run_until(t0 + 0.2)
    clock.advance(0.03)
    engine.run_until(clock.now() + 0.0101)
    m = engine.motors[0]
    at = ex.position(0)
    with engine.lock:
        assert m.stop(hard=False, now=clock.now())
    engine.run_until(clock.now() + 1.0)
    assert m.idle and m.fault is None
    assert m.soft_stops == 1
    assert 0 < m.takeover_s[0] <= ex.lead_s + 0.002 + 1e-9
    assert m.takeover_steps[0] <= (ex.lead_s + 0.002) * 5000 + 1
    # the deceleration from 5,000 step/s at 50,000 step/s^2: 250 steps, from the takeover
    assert m.abs_steps - at == pytest.approx(m.takeover_steps[0] + 250, abs=2)
    times = world_of(engine.hw).timeline.step_times(0)
    gaps = [b - a for a, b in itertools.pairwise(times)]
    assert min(gaps) >= 1 / 10_000 - 1e-9
