"""Planning in closed form (``SegmentCutter``) and re-plans that cut a running plan.

The cutter must make exactly the steps of ``profile.Steps`` (the reference: one square root
per step), each within the error bound, with segments bounded in length; a re-plan (soft
stop, new speed) takes over within ``lead + span`` of the command, not after everything
handed over; the core drops the cut part silently, or faults when the cut came too late.
"""

from __future__ import annotations

import itertools
import math
import random
from collections.abc import Callable

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from motorctl.hal.backends.mock.backend import build
from motorctl.hal.interfaces import VirtualClock
from motorctl.hal.spec import HardwareSpec
from motorctl.motion.engine import MotionEngine
from motorctl.motion.executor_seam import ExecEvent, ExecEventKind, to_ticks
from motorctl.motion.executor_thread import ThreadStepExecutor
from motorctl.motion.profile import Segment, Steps, Trajectory, plan_move_to, plan_run
from motorctl.motion.segments import Boundary, SegmentCutter, StepSegment
from motorctl.motion.step_core import COUNTER_NAMES
from motorctl.motion.step_planner import REFILL_S, axis_limits
from motorctl.motion.types import MotorParams, MotorState, Ramp, RunCmd
from tests.support.rigs import FAR, StepCoreRig, engine_rig

K = ExecEventKind
ERR = 5000  # ticks (5 us)
SPAN = 2_000_000  # ticks (2 ms)


def cut_all(
    traj: Trajectory, counter: int, step_s: float = 0.02, err: int = ERR, span: int = SPAN
) -> list[StepSegment]:
    cutter = SegmentCutter(traj.segments, counter, err, span)
    out: list[StepSegment] = []
    h = traj.start_time
    while not cutter.done:
        h += step_s
        out += cutter.cut(h, 3, True)
        assert len(out) < 10**6
    return out


def check_against_steps(traj: Trajectory, counter: int, **kw: float) -> list[StepSegment]:
    ref = [(to_ticks(t), d) for t, d in Steps(traj, counter)]
    segs = cut_all(traj, counter, **kw)  # type: ignore[arg-type]
    got = [(t, s.direction) for s in segs for t in s.times()]
    assert len(got) == len(ref)
    assert [d for _, d in got] == [d for _, d in ref]
    worst = max((abs(a - b) for (a, _), (b, _) in zip(got, ref, strict=True)), default=0)
    assert worst <= ERR
    if segs:
        assert [s.last for s in segs] == [False] * (len(segs) - 1) + [True]
        assert all(s.gen == 3 and s.watch for s in segs)
    return segs


#: Steps a start at speed may take to brake (v0^2 / 2 dec): the properties are about cutting,
#: and a start at 60,000 step/s braking at 500 step/s^2 (3.6 million steps, minutes of
#: test time) shows nothing that 20,000 steps do not.
BRAKING_STEPS = 20_000


def braking_speed(dec: float) -> float:
    """The fastest start that brakes within BRAKING_STEPS at ``dec``."""
    return math.sqrt(2.0 * dec * BRAKING_STEPS)


@settings(max_examples=60, deadline=None)
@given(
    distance=st.integers(-3000, 3000),
    speed=st.floats(50, 60_000),
    acc=st.floats(500, 2e6),
    dec=st.floats(500, 2e6),
    s0=st.floats(-0.9, 0.9),
    v0_frac=st.floats(-1.0, 1.0),
)
def test_the_cutter_makes_exactly_the_steps_of_the_profile_within_the_error(
    distance: int, speed: float, acc: float, dec: float, s0: float, v0_frac: float
) -> None:
    """Reversals, triangles, a start between integers and a start at speed included."""
    v0 = v0_frac * min(speed, braking_speed(dec))
    traj = plan_move_to(1000.25, s0, v0, float(distance), speed, acc, dec)
    check_against_steps(traj, 0)


class GenericCutter(SegmentCutter):
    """The cutter without its cruise loop: every run through ``_run``."""

    def _cruise(self, *args: object) -> bool | None:
        return None


@settings(max_examples=80, deadline=None)
@given(
    distance=st.integers(-40_000, 40_000),
    speed=st.floats(50, 200_000),
    acc=st.floats(500, 2e6),
    s0=st.floats(-0.9, 0.9),
    v0_frac=st.floats(-1.0, 1.0),
    run=st.booleans(),
    step_s=st.sampled_from([0.0, 0.001, 0.005, 0.05]),
    span=st.sampled_from([SPAN, 50_000, 10**9]),
)
def test_the_cruise_loop_makes_the_very_segments_of_the_generic_path(
    distance: int,
    speed: float,
    acc: float,
    s0: float,
    v0_frac: float,
    run: bool,
    step_s: float,
    span: int,
) -> None:
    """Bit for bit, boundaries included: the loop is only a cheaper way to the same runs.

    Each example compares up to CUTS cuts and SEGMENTS segments, every cut made whole: a run
    never ends, and a move at 50 step/s cut every ms, or one accelerating at 500 step/s^2
    to 200,000 step/s, took minutes of the generic path for nothing new (about two thirds
    of the moves drawn still end within the bounds)."""
    v0 = v0_frac * min(speed, braking_speed(acc))
    traj = (
        plan_run(2000.5, s0, v0, math.copysign(speed, distance or 1), acc, acc)
        if run
        else plan_move_to(2000.5, s0, v0, float(distance), speed, acc, acc)
    )
    fast, slow = (
        SegmentCutter(traj.segments, 0, ERR, span),
        GenericCutter(traj.segments, 0, ERR, span),
    )
    h = traj.start_time
    segments = 0
    for _ in range(CUTS):
        if fast.done or segments >= SEGMENTS:
            break
        h += step_s
        fb: list[Boundary] = []
        sb: list[Boundary] = []
        cut = fast.cut(h, 3, True, fb)
        assert cut == slow.cut(h, 3, True, sb)
        assert fb == sb
        assert (fast.counter, fast.last_t) == (slow.counter, slow.last_t)
        segments += len(cut)
    assert slow.done == fast.done


CUTS = 1000
SEGMENTS = 5000


def test_random_moves_runs_and_horizons_agree_with_the_profile() -> None:
    rng = random.Random(7)
    for _ in range(40):
        speed = rng.choice([200.0, 5000.0, 30_000.0])
        acc = rng.choice([2000.0, 100_000.0, 1e6])
        t0 = 5000.0 + rng.random()
        traj = (
            plan_move_to(t0, 0.0, 0.0, float(rng.randint(-8000, 8000)), speed, acc, acc)
            if rng.random() < 0.7
            else plan_run(t0, 0.0, 0.0, speed, acc, acc, float(rng.randint(1, 8000)))
        )
        check_against_steps(traj, 0, step_s=rng.choice([0.0, 0.003, 0.05]))


def test_a_fast_cruise_costs_a_segment_per_span_and_a_ramp_a_few_dozen() -> None:
    traj = plan_move_to(100.0, 0.0, 0.0, 60_000.0, 30_000.0, 500_000.0, 500_000.0)
    segs = check_against_steps(traj, 0, step_s=0.05)
    steps = sum(s.count for s in segs)
    assert steps == 60_000
    assert all(
        s.count == 1
        or s.first
        + (s.count - 1) * s.interval
        + s.add * (s.count - 1) * (s.count - 2) // 2
        - s.first
        <= SPAN
        for s in segs
    )
    # 2 s at 30,000 step/s: about one segment per 2 ms span, plus the two ramps
    assert len(segs) < 2.0 / 0.002 + 200
    cruise = [s for s in segs if s.add == 0 and s.count > 50]
    assert cruise and all(s.interval == pytest.approx(1e9 / 30_000, abs=1) for s in cruise)


def test_the_horizon_hands_over_steps_up_to_it_and_always_the_next_one() -> None:
    traj = plan_run(10.0, 0.0, 0.0, 1000.0, 1e6, 1e6)
    cutter = SegmentCutter(traj.segments, 0, ERR, SPAN)
    first = cutter.cut(9.0, 1, True)  # before the start: still the next step
    assert sum(s.count for s in first) == 1
    more = cutter.cut(10.1, 1, True)
    times = [t for s in more for t in s.times()]
    assert times and max(times) <= to_ticks(10.1) and cutter.counter == 1 + len(times)
    assert not cutter.done and math.isfinite(cutter.last_t)


def test_a_plan_that_makes_no_step_is_done_at_once() -> None:
    still = Trajectory((Segment(5.0, 0.0, 3.0, 0.0, 0.0),))
    cutter = SegmentCutter(still.segments, 3, ERR, SPAN)
    assert cutter.done and cutter.cut(6.0, 1, True) == []
    with pytest.raises(ValueError, match="inconsistent"):
        SegmentCutter(still.segments, 5, ERR, SPAN)


# ---------------------------------------------------------------- re-plans


def rig(ahead_s: float = 0.05) -> tuple[VirtualClock, MotionEngine, ThreadStepExecutor]:
    """A thread executor on a virtual clock that plans ``ahead_s`` ahead, as on a real clock."""
    clock = VirtualClock()
    r = engine_rig(
        MotorParams(max_speed=10_000.0),
        axes=[FAR],
        clock=clock,
        max_error_s=5e-6,
        ahead_s=ahead_s,
        lead_s=0.002,
    )
    return clock, r.engine, r.executor


def step_times(engine: MotionEngine) -> list[float]:
    from motorctl.hal.backends.mock.backend import world_of

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
    assert ex.core.counters[COUNTER_NAMES.index("dropped")] >= 1
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


def test_a_cut_that_comes_after_its_segment_began_faults_instead_of_stepping_twice(
    core_rig: Callable[..., StepCoreRig],
) -> None:
    c = core_rig()
    t0 = c.clock.now()
    first = to_ticks(t0 + 0.001)
    c.push(
        0,
        StepSegment(first, 200_000, 5, 0, 1, 1),
        StepSegment(first + 1_000_000, 200_000, 5, 0, 1, 1),
    )
    c.run_until(t0 + 0.0021)  # the second segment began (its first step made)
    assert len(c.times()) == 6
    c.stop(0, 1, first + 1_000_000)
    c.run_until(t0 + 0.1)
    assert [e.kind for e in c.events] == [K.TIMING_LOST]
    assert "re-plan came" in c.events[0].detail and len(c.times()) == 6


def test_a_cut_in_time_drops_the_rest_silently_and_the_next_plan_follows(
    core_rig: Callable[..., StepCoreRig],
) -> None:
    c = core_rig()
    t0 = c.clock.now()
    first = to_ticks(t0 + 0.001)
    c.push(
        0,
        StepSegment(first, 200_000, 5, 0, 1, 1),
        StepSegment(first + 1_000_000, 200_000, 5, 0, 1, 1, True),
    )
    c.run_until(t0 + 0.0005)
    c.stop(0, 1, first + 1_000_000)
    c.push(0, StepSegment(first + 1_000_000, 400_000, 3, 0, -1, 2, True))
    c.run_until(t0 + 0.1)
    assert [e.kind for e in c.events] == [K.DONE] and c.events[0].gen == 2
    assert c.positions[0] == 5 - 3 and len(c.times()) == 8


def test_an_older_plans_segment_still_on_its_way_stays_cut_after_a_second_re_plan(
    core_rig: Callable[..., StepCoreRig],
) -> None:
    """Two re-plans in quick succession: a segment of the first plan that reaches the core
    only after the second cut (it was still in the ring) is judged by the first cut too."""
    c = core_rig()
    t0 = c.clock.now()
    ms = to_ticks(0.001)
    base = to_ticks(t0)
    c.push(0, StepSegment(base + ms, 0, 1, 0, 1, 1))
    c.run_until(t0 + 0.0005)
    c.stop(0, 1, base + 2 * ms)  # plan 1 cut at 2 ms
    c.run_until(t0 + 0.0006)
    # still arriving: plan 1's step at 2.5 ms (cut), then plan 2 from 2 ms
    c.push(
        0,
        StepSegment(base + 5 * ms // 2, 0, 1, 0, 1, 1),
        StepSegment(base + 2 * ms, 0, 1, 0, 1, 2),
        StepSegment(base + 3 * ms, 0, 1, 0, 1, 2, True),
    )
    c.stop(0, 2, base + 3 * ms)  # plan 2 cut at 3 ms, before any of them
    c.push(0, StepSegment(base + 3 * ms, 0, 1, 0, -1, 3, True))
    c.run_until(t0 + 0.01)
    assert c.times() == [(base + ms) / 1e9, (base + 2 * ms) / 1e9, (base + 3 * ms) / 1e9]
    assert c.positions[0] == 1 + 1 - 1  # plan 1's 2.5 ms step was never made
    assert [e.kind for e in c.events] == [K.DONE] and c.events[0].gen == 3


def test_motors_started_apart_are_topped_up_in_one_pass_not_one_pass_each() -> None:
    """Three motors started 1 ms apart: after their first top-ups every later one takes
    all three in the same planner pass (one hold of the GIL against the link thread, every
    ``REFILL_S``), and each motor still has at least ``ahead_s - REFILL_S`` handed over."""
    clock = VirtualClock()
    spec = HardwareSpec(axes=(FAR, FAR, FAR), options={"timeline_len": None})
    hw = build(spec, clock)
    params = [MotorParams(max_speed=10_000.0)] * 3
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
