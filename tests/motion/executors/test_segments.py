"""Planning in closed form (motion/executors/segments.py, ``SegmentCutter``).

The cutter must make exactly the steps of ``profile.Steps`` (the reference: one square root
per step), each within the error bound, with segments bounded in length, up to the horizon
and always the next one. (Re-plans that cut a running plan: test_planner.py, and what the
core does with the cut: test_step_core.py.)
"""

from __future__ import annotations

import math
import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from motorctl.motion.executors.base import ExecEventKind, to_ticks
from motorctl.motion.executors.segments import Boundary, SegmentCutter, StepSegment
from motorctl.motion.profile import Segment, Steps, Trajectory, plan_move_to, plan_run

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
