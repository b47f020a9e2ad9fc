"""The step core on a virtual clock, fed by hand: the planned steps exactly, the fail-safe
rules (a lag beyond the tolerance stops the motor; within it, or at the start speed, or on a
simulated motor, late steps slide), hard stops and shared pulses."""

from __future__ import annotations

import itertools

import pytest

from motorctl.motion.executor_seam import ExecEventKind, to_ticks
from motorctl.motion.segments import StepSegment
from motorctl.motion.step_core import (
    ABSORBED,
    COUNTER_NAMES,
    LAG_FAULTS,
    LAG_UNIT,
    SHIFT,
    WORST_LAG,
    WORST_LATE,
)
from tests.support.rigs import StepCoreRig

K = ExecEventKind


# ---------------------------------------------------------------- the core, virtual clock


def test_the_core_makes_the_planned_steps_exactly() -> None:
    c = StepCoreRig()
    t0 = c.clock.now()
    c.cruise(0, 5000.0, 50, t0 + 0.001)
    c.run_until(t0 + 1.0)
    times = c.times()
    assert len(times) == 50 == c.positions[0] == c.world.axes[0].position
    assert times == [(to_ticks(t0 + 0.001) + k * to_ticks(1 / 5000)) / 1e9 for k in range(50)]
    assert c.core.stats.max_s == 0.0


def test_a_stall_beyond_the_lag_tolerance_stops_the_motor_instead_of_bursting() -> None:
    """50 ms without the executor at 5,000 step/s, 16 microsteps, above the start speed: the
    next step would leave the rotor 15.6 full steps behind (tolerance 0.5): it is not made,
    the motor stops (TIMING_LOST, with the speed it had)."""
    c = StepCoreRig(max_speed=10_000.0)
    t0 = c.clock.now()
    c.cruise(0, 5000.0, 10_000, t0 + 0.001)
    c.run_until(t0 + 0.1)
    made = len(c.times())
    c.clock.advance(0.05)  # the stall: nothing runs the core
    c.run_until(c.clock.now() + 0.5)
    times = c.times()
    assert len(times) == made  # not one more step: it stopped instead of bursting
    kinds = [e.kind for e in c.events]
    assert kinds == [K.TIMING_LOST]
    ev = c.events[0]
    assert ev.speed == pytest.approx(5000.0) and ev.position == made
    assert "lag 15.562 full steps" in ev.detail and "max_lag_full_steps 0.5" in ev.detail
    assert c.core.counters[COUNTER_NAMES.index("timing_lost")] == 1
    assert c.cell(LAG_FAULTS) == 1 and c.cell(ABSORBED) == 0 and c.cell(SHIFT) == 0
    assert c.cell(WORST_LAG) / LAG_UNIT == pytest.approx(0.0498 * 5000 / 16, rel=1e-6)
    # blocked until the planner answers: a segment planned before it saw the event is dropped
    c.cruise(0, 5000.0, 10, c.clock.now() + 0.001)
    c.run_until(c.clock.now() + 0.1)
    assert len(c.times()) == made
    c.inbox.stops.append((0, 2, -1))  # the answer
    c.inbox.queues[0].append(StepSegment(to_ticks(c.clock.now() + 0.001), 200_000, 3, 0, 1, 3))
    c.run_until(c.clock.now() + 0.1)
    assert len(c.times()) == made + 3


def _slid_run(c: StepCoreRig, rate: float, stall: float) -> tuple[list[float], float]:
    """Cruise 200 steps at ``rate`` from t0 + 1 ms, stall ``stall`` s after 10 ms; the step
    times and t0."""
    t0 = c.clock.now()
    c.cruise(0, rate, 200, t0 + 0.001)
    c.run_until(t0 + 0.01)
    c.clock.advance(stall)
    c.run_until(t0 + 1.0)
    return c.times(), t0


def _assert_slid(c: StepCoreRig, times: list[float], t0: float, rate: float, stall: float) -> None:
    """Every step made, none closer than the plan (no burst), the move longer by the stall."""
    iv = to_ticks(1 / rate)
    assert len(times) == 200 == c.positions[0] and not c.events
    gaps = [to_ticks(b) - to_ticks(a) for a, b in itertools.pairwise(times)]
    assert min(gaps) >= iv - 1  # the spacing of the profile, also right after the slide
    shift = c.cell(SHIFT)  # the stall less the time to the step that was due next
    assert to_ticks(stall) - iv <= shift <= to_ticks(stall)
    assert max(gaps) == iv + shift  # the one pause, where the stall was
    assert sorted(gaps)[-2] <= iv + 1  # and only there
    planned_end = (to_ticks(t0 + 0.001) + 199 * iv) / 1e9
    assert times[-1] - planned_end == pytest.approx(shift / 1e9, abs=1e-9)
    assert c.cell(ABSORBED) == 1 and c.cell(LAG_FAULTS) == 0
    assert c.cell(WORST_LATE) == c.cell(SHIFT)
    lag = c.cell(SHIFT) / 1e9 * rate / c.limits[0].microsteps
    assert c.cell(WORST_LAG) / LAG_UNIT == pytest.approx(lag, rel=1e-3)
    # the lateness histogram has the step as late as it came against the plan before it slid
    assert c.core.stats.max_s == pytest.approx(c.cell(SHIFT) / 1e9, abs=1e-9)


def test_above_the_start_speed_a_lag_within_the_tolerance_slides_the_schedule() -> None:
    """1 ms at 5,000 step/s, 16 microsteps: 0.31 full steps of lag (tolerance 0.5): the
    late step is made, the rest of the move comes that much later, at its planned spacing."""
    c = StepCoreRig(max_speed=8000.0, start_speed=500.0)
    times, t0 = _slid_run(c, 5000.0, 0.001)
    _assert_slid(c, times, t0, 5000.0, 0.001)


def test_a_lag_just_beyond_the_tolerance_faults_and_one_just_within_slides() -> None:
    """The boundary: at 5,000 step/s with 16 microsteps and 0.5 full steps, 1.6 ms late
    (the stall less the 0.2 ms to the step that was due next)."""
    for stall, faults in ((0.00175, False), (0.00185, True)):
        c = StepCoreRig(max_speed=8000.0)
        _slid_run(c, 5000.0, stall)
        assert [e.kind for e in c.events] == ([K.TIMING_LOST] if faults else [])


def test_at_or_below_the_start_speed_any_lateness_slides() -> None:
    """Half a second at 500 step/s, the motor's start speed: 15.6 full steps of lag, yet a
    motor at its start speed can stop and start at any moment: no fault, the move slides."""
    c = StepCoreRig(max_speed=8000.0, start_speed=500.0)
    _times, t0 = _slid_run(c, 500.0, 0.5)
    c.run_until(t0 + 2.0)
    _assert_slid(c, c.times(), t0, 500.0, 0.5)


def test_simulated_motors_never_lose_steps() -> None:
    """Without ``lag_faults`` (the mock's default: no rotor) a 50 ms stall at 5,000 step/s
    slides the move, counted, and never faults."""
    c = StepCoreRig(max_speed=8000.0, lag_faults=False)
    times, t0 = _slid_run(c, 5000.0, 0.05)
    _assert_slid(c, times, t0, 5000.0, 0.05)


def test_late_steps_below_the_slide_threshold_come_no_closer_than_the_profile_allows() -> None:
    """60 us at 20,000 step/s is late (a step of its own) but below the 100 us threshold:
    no slide; the overdue steps catch up spaced by the motor's minimum interval (1 / max
    speed), never back to back."""
    c = StepCoreRig(max_speed=25_000.0)
    t0 = c.clock.now()
    c.cruise(0, 20_000.0, 200, t0 + 0.001)
    c.run_until(t0 + 0.002)
    c.clock.advance(60e-6)
    c.run_until(t0 + 1.0)
    times = c.times()
    assert len(times) == 200 and not c.events and c.cell(ABSORBED) == 0
    gaps = [b - a for a, b in itertools.pairwise(times)]
    bound = c.limits[0].min_interval_s
    assert min(gaps) >= bound - 1e-9
    assert min(gaps) < 1 / 20_000 - 1e-6  # the catching up really happened, at the bound
    assert times[-1] == pytest.approx(t0 + 0.001 + 199 / 20_000, abs=1e-9)  # back on plan


def test_a_hard_stop_takes_effect_before_the_next_step() -> None:
    c = StepCoreRig()
    t0 = c.clock.now()
    c.cruise(0, 1000.0, 1000, t0 + 0.001)
    c.run_until(t0 + 0.0105)
    c.inbox.stops.append((0, 1, -1))
    c.run_until(t0 + 1.0)
    assert len(c.times()) == 10 and max(c.times()) <= t0 + 0.0105
    assert [e.kind for e in c.events] == [K.STOPPED] and c.events[0].position == 10


def test_two_motors_due_on_the_same_tick_share_one_pulse_call() -> None:
    c = StepCoreRig(motors=2)
    calls = c.pulse_calls()
    t0 = c.clock.now()
    c.cruise(0, 1000.0, 5, t0 + 0.001)
    c.cruise(1, 1000.0, 5, t0 + 0.001)
    c.run_until(t0 + 1.0)
    assert calls == [[0, 1]] * 5


def test_a_step_planned_within_the_coalesce_window_shares_the_pulse_but_never_the_spacing() -> None:
    c = StepCoreRig(motors=2, max_speed=1000.0)  # min interval 1 ms
    c.core.coalesce = to_ticks(5e-6)
    calls = c.pulse_calls()
    t0 = c.clock.now()
    start = to_ticks(t0 + 0.001)
    c.inbox.queues[0].append(StepSegment(start, 2_000_000, 3, 0, 1, 1))
    c.inbox.queues[1].append(StepSegment(start + 3000, 2_000_000, 3, 0, 1, 1))  # 3 us later
    c.run_until(t0 + 0.01)
    assert calls == [[0, 1]] * 3  # motor 1 came 3 us early, in motor 0's pulse
    assert c.times(1) == c.times(0)
    # 8 us later is outside the window: its own pulse
    calls.clear()
    t1 = c.clock.now()
    start = to_ticks(t1 + 0.001)
    c.inbox.queues[0].append(StepSegment(start, 2_000_000, 2, 0, 1, 2))
    c.inbox.queues[1].append(StepSegment(start + 8000, 2_000_000, 2, 0, 1, 2))
    c.run_until(t1 + 0.01)
    assert calls == [[0], [1]] * 2
    # a step held back by the spacing bound is not pulled forward by another's pulse
    calls.clear()
    t2 = c.clock.now()
    start = to_ticks(t2 + 0.001)
    c.inbox.queues[0].append(StepSegment(start, 500_000, 2, 0, 1, 3))  # 0.5 ms: too fast
    c.inbox.queues[1].append(StepSegment(start + 500_000 + 2000, 0, 1, 0, 1, 3))
    c.run_until(t2 + 0.01)
    assert calls == [[0], [1], [0]]  # motor 0's second step waits for its 1 ms spacing
    gaps = [b - a for a, b in itertools.pairwise(c.times(0))]
    assert min(gaps) >= 1e-3 - 1e-9
