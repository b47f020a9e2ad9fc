"""The step planner (motion/executors/planner.py), the half of a step executor that cuts
plans into segments: the fail-safe bounds it gives each motor, the transport each kind must
implement, re-plans (a soft stop, a new speed) that take over within ``lead + span`` of the
command instead of after everything handed over, an empty re-plan behind handed-over steps,
and every motor topped up in one pass. (The cutter itself: test_segments.py; what the core
does with a cut: test_step_core.py.)"""

from __future__ import annotations

import itertools

import pytest

from motorctl.hal.backends.mock.backend import build
from motorctl.hal.interfaces import VirtualClock
from motorctl.hal.spec import HardwareSpec
from motorctl.motion.engine import MotionEngine
from motorctl.motion.executors.base import ExecEvent, ExecEventKind, ExecutorHealth
from motorctl.motion.executors.core_cells import COUNTER_NAMES
from motorctl.motion.executors.planner import REFILL_S, StepExecutor, axis_limits
from motorctl.motion.executors.thread import ThreadStepExecutor
from motorctl.motion.profile import Segment, Trajectory, plan_move_to
from motorctl.motion.types import MotorState, Ramp, RunCmd
from tests.support.motor_defaults import motor_params
from tests.support.rigs import FAR, engine_rig

K = ExecEventKind


def test_each_motor_is_bounded_by_its_maximum_speed_less_the_step_error() -> None:
    fast, slow = motor_params(max_speed=10_000.0), motor_params(max_speed=100.0, start_speed=50.0)
    a, b = axis_limits([fast, slow], 5e-6, slide_after_s=50e-6, lag_faults=False)
    assert a.min_interval_s == pytest.approx(95e-6) and a.min_interval_s < 95e-6
    assert b.min_interval_s == pytest.approx(0.01 - 5e-6)
    assert (b.start_speed, b.slide_after_s, b.lag_faults) == (50.0, 50e-6, False)
    assert (a.pulse_s, a.microsteps) == (fast.pulse_s, fast.microsteps)
    (never,) = axis_limits([motor_params(max_speed=1e9)], 5e-6)  # faster than the error
    assert never.min_interval_s == 0.0


def test_a_kind_without_its_transport_cannot_be_made() -> None:
    """The transport to the core is each kind's own: a step executor that does not say how
    its segments, stops and events travel is not a step executor."""

    class NoTransport(StepExecutor):
        def position(self, motor: int) -> int:
            return 0

        def endstop_active(self, motor: int, direction: int) -> bool:
            return False

        def health(self) -> ExecutorHealth:
            return ExecutorHealth(True, 0)

    # Python 3.11 lists them bare, 3.12 and later quoted (Debian 13's 3.13: make test-root)
    with pytest.raises(TypeError, match=r"_push'?, '?_push_stop'?, '?_raw_events"):
        NoTransport(VirtualClock(), axis_limits([motor_params()], 0.0))  # type: ignore[abstract]


# ---------------------------------------------------------------- re-plans


def rig(ahead_s: float = 0.05) -> tuple[VirtualClock, MotionEngine, ThreadStepExecutor]:
    """A thread executor on a virtual clock that plans ``ahead_s`` ahead, as on a real clock."""
    clock = VirtualClock()
    r = engine_rig(
        motor_params(max_speed=10_000.0),
        axes=[FAR],
        clock=clock,
        max_error_s=5e-6,
        ahead_s=ahead_s,
        lead_s=0.002,
    )
    return clock, r.engine, r.executor


def step_times(engine: MotionEngine) -> list[float]:
    from motorctl.hal.backends.mock.world import world_of

    return world_of(engine.hw).timeline.step_times(0)


@pytest.mark.parametrize("ahead_s", [0.05, 0.2])
def test_a_soft_stop_takes_over_within_lead_and_span_not_after_the_horizon(
    ahead_s: float,
) -> None:
    clock, engine, ex = rig(ahead_s)
    m = engine.motors[0]
    with engine.lock:
        m.submit(RunCmd(1, Ramp(5000.0, 1e6, 50_000.0)), clock.now())
    engine.run_until(clock.now() + 0.5)  # cruising at 5,000 step/s, ahead_s handed over
    handed = ex.plans[0].counter - ex.position(0)
    assert handed >= 5000 * ahead_s * 0.5
    t_cmd = clock.now()
    with engine.lock:
        assert m.stop(hard=False, now=t_cmd)
    engine.run_until_idle()
    times = step_times(engine)
    gaps = [(b - a, b) for a, b in itertools.pairwise(times) if b > t_cmd]
    # the deceleration (50,000 step/s^2: the gaps grow) starts within lead + span
    slowing = next(t for g, t in gaps if g > 1 / 5000 + 2e-6)
    assert slowing - t_cmd <= 0.002 + 0.002 + 1 / 5000
    # and it stops where a ramp from 5,000 step/s at 50,000 step/s^2 ends: 250 steps on
    after = sum(1 for t in times if t > t_cmd)
    assert 250 <= after <= 250 + 5000 * 0.0045
    assert m.state is MotorState.IDLE and ex.position(0) == len(times)
    assert ex.core.counters[COUNTER_NAMES.index("segments_discarded")] >= 1
    assert ex.health().counters["timing_lost"] == 0
    assert min(g for g, _ in gaps) >= 1 / 10_000 - 5e-6


def test_a_new_speed_while_running_takes_over_soon_and_keeps_the_step_count_exact() -> None:
    clock, engine, ex = rig(0.1)
    m = engine.motors[0]
    with engine.lock:
        m.submit(RunCmd(1, Ramp(2000.0, 1e6, 1e6)), clock.now())
    engine.run_until(clock.now() + 0.3)
    t_cmd = clock.now()
    with engine.lock:
        m.submit(RunCmd(1, Ramp(8000.0, 1e6, 1e6)), clock.now())
    engine.run_until(clock.now() + 0.2)
    times = step_times(engine)
    faster = next(b for a, b in itertools.pairwise(times) if b > t_cmd and b - a < 1 / 2000 - 1e-5)
    assert faster - t_cmd <= 0.002 + 0.002 + 1 / 2000
    assert ex.position(0) == len(times)  # no step lost or made twice at the cut
    with engine.lock:
        m.stop(hard=True, now=clock.now())
    engine.run_until_idle()


def test_an_empty_re_plan_behind_handed_over_steps_reports_done_after_them() -> None:
    clock, engine, ex = rig(0.05)
    traj = plan_move_to(clock.now() + 0.002, 0.0, 0.0, 100.0, 5000.0, 1e6, 1e6)
    with engine.lock:
        assert ex.follow(0, traj, Ramp(5000.0, 1e6, 1e6), 1)
        # a plan with no step, started after everything handed over (no cut asked for)
        end = ex.plans[0].until
        still = Trajectory((Segment(end, 0.0, 100.0, 0.0, 0.0),))
        assert ex.follow(0, still, Ramp(5000.0, 1e6, 1e6), 2)  # True: DONE will follow
    events: list[ExecEvent] = []
    deadline = clock.now() + 1.0
    while clock.now() < deadline and not any(e.kind is K.DONE for e in events):
        engine.executor.advance(clock.now())
        events += ex.events()
        clock.advance(0.0001)
    done = [e for e in events if e.kind is K.DONE]
    assert [e.gen for e in done] == [1, 2]  # the old plan's end, then the empty one's
    assert done[-1].position == 100 == ex.position(0)
    assert not ex.planned(0)


def test_motors_started_apart_are_topped_up_in_one_pass_not_one_pass_each() -> None:
    """Three motors started 1 ms apart: after their first top-ups every later one takes
    all three in the same planner pass (one hold of the GIL against the link thread, every
    ``REFILL_S``), and each motor still has at least ``ahead_s - REFILL_S`` handed over."""
    clock = VirtualClock()
    spec = HardwareSpec(axes=(FAR, FAR, FAR), options={"timeline_len": None})
    hw = build(spec, clock)
    params = [motor_params(max_speed=10_000.0)] * 3
    fed: list[tuple[float, int]] = []

    class Spy(ThreadStepExecutor):
        def _feed(self, motor: int, now: float) -> None:
            fed.append((now, motor))
            super()._feed(motor, now)

    ex = Spy(hw, "mock", spec, axis_limits(params, 5e-6), ahead_s=0.05, lead_s=0.002)
    engine = MotionEngine(hw, params, ex)
    for m in engine.motors:
        with engine.lock:
            m.submit(RunCmd(1, Ramp(5000.0, 1e6, 1e6)), clock.now())
        engine.run_until(clock.now() + 0.001)
    start = clock.now()
    while clock.now() < start + 1.0:
        engine.run_until(clock.now() + 0.001)
        for p in ex.plans:  # never less than the horizon minus one top-up ahead
            assert p.until - clock.now() >= 0.05 - REFILL_S - 1e-6
    passes: dict[float, set[int]] = {}
    for t, motor in fed:
        if t > start + 0.06:
            passes.setdefault(t, set()).add(motor)
    assert len(passes) >= 0.9 / REFILL_S - 3  # one every REFILL_S
    assert all(motors == {0, 1, 2} for motors in passes.values()), passes
    for m in engine.motors:
        with engine.lock:
            m.stop(hard=True, now=clock.now())
    engine.run_until_idle()
