"""The step cores on a virtual clock, fed by hand through the process executor's rings, each
test on both (motion/executors/step_core.py, the Python reference, and the compiled core of
motion/executors/csrc through motion/executors/compiled_core.py): the planned steps exactly,
the fail-safe rules (a lag beyond the tolerance stops the motor; within it, or at the start
speed, or on a simulated motor, late steps slide), hard stops, shared pulses, DIR settle and
hold, end stops, line errors, bad ring records (never a crash, a hang or a stray step), and
the cuts of a re-plan. Then both cores on the same random programs: the same timeline,
events and figures."""

from __future__ import annotations

import errno
import itertools
import random
from collections.abc import Callable

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from motorctl.hal.backends.mock.world import EventKind, mock_axis
from motorctl.motion.executors.base import (
    ENDSTOP_ALREADY_ACTIVE,
    ExecEvent,
    ExecEventKind,
    to_ticks,
)
from motorctl.motion.executors.core_cells import (
    ABSORBED,
    LAG_FAULTS,
    LAG_UNIT,
    SHIFT,
    WORST_LAG,
    WORST_LATE,
)
from motorctl.motion.executors.process.rings import BAD_RECORD_S, segment_problem, stop_problem
from motorctl.motion.executors.segments import StepSegment
from tests.support.rigs import StepCoreRig

K = ExecEventKind
Rig = Callable[..., StepCoreRig]


# ---------------------------------------------------------------- the planned steps


def test_the_core_makes_the_planned_steps_exactly(core_rig: Rig) -> None:
    c = core_rig()
    t0 = c.clock.now()
    c.cruise(0, 5000.0, 50, t0 + 0.001)
    c.run_until(t0 + 1.0)
    times = c.times()
    assert len(times) == 50 == c.positions[0] == c.world.axes[0].position
    assert times == [(to_ticks(t0 + 0.001) + k * to_ticks(1 / 5000)) / 1e9 for k in range(50)]
    assert c.core.stats.max_s == 0.0 and c.core.stats.count == 50
    assert c.counter("steps") == 50 and c.counter("bad_records") == 0


def test_a_ramp_segment_adds_to_its_interval_each_step(core_rig: Rig) -> None:
    c = core_rig(max_speed=50_000.0)
    t0 = to_ticks(c.clock.now() + 0.001)
    c.push(0, StepSegment(t0, 100_000, 6, -3000, -1, 1, True))
    c.run_until(c.clock.now() + 0.1)
    ticks = [to_ticks(t) for t in c.times()]
    assert [b - a for a, b in itertools.pairwise(ticks)] == [
        100_000,
        97_000,
        94_000,
        91_000,
        88_000,
    ]
    assert c.positions[0] == -6 and [e.kind for e in c.events] == [K.DONE]
    assert c.events[0].position == -6 and c.events[0].t == ticks[-1] / 1e9


# ---------------------------------------------------------------- late steps


def test_a_stall_beyond_the_lag_tolerance_stops_the_motor_instead_of_bursting(
    core_rig: Rig,
) -> None:
    """50 ms without the executor at 5,000 step/s, 16 microsteps, above the start speed: the
    next step would leave the rotor 15.6 full steps behind (tolerance 0.5): it is not made,
    the motor stops (TIMING_LOST, with the speed it had)."""
    c = core_rig(max_speed=10_000.0)
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
    assert ev.detail == (
        "step 49800 us late at 5000 step/s: lag 15.562 full steps > max_lag_full_steps 0.5 "
        "(16 microsteps, start_speed 0 step/s)"
    )
    assert c.counter("timing_lost") == 1
    assert c.cell(LAG_FAULTS) == 1 and c.cell(ABSORBED) == 0 and c.cell(SHIFT) == 0
    assert c.cell(WORST_LAG) / LAG_UNIT == pytest.approx(0.0498 * 5000 / 16, rel=1e-6)
    # blocked until the planner answers: a segment planned before it saw the event is dropped
    c.cruise(0, 5000.0, 10, c.clock.now() + 0.001)
    c.run_until(c.clock.now() + 0.1)
    assert len(c.times()) == made
    c.stop(0, 2)  # the answer
    c.push(0, StepSegment(to_ticks(c.clock.now() + 0.001), 200_000, 3, 0, 1, 3))
    c.run_until(c.clock.now() + 0.1)
    assert len(c.times()) == made + 3
    assert [e.kind for e in c.events] == [K.TIMING_LOST, K.STOPPED]


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
    # ... and its lateness summed (the metrics' summary): the other steps came on time
    assert c.core.stats.sum_s == pytest.approx(c.core.stats.max_s, abs=1e-9)


def test_above_the_start_speed_a_lag_within_the_tolerance_slides_the_schedule(
    core_rig: Rig,
) -> None:
    """1 ms at 5,000 step/s, 16 microsteps: 0.31 full steps of lag (tolerance 0.5): the
    late step is made, the rest of the move comes that much later, at its planned spacing."""
    c = core_rig(max_speed=8000.0, start_speed=500.0)
    times, t0 = _slid_run(c, 5000.0, 0.001)
    _assert_slid(c, times, t0, 5000.0, 0.001)


@pytest.mark.parametrize(("stall", "faults"), [(0.00175, False), (0.00185, True)])
def test_a_lag_just_beyond_the_tolerance_faults_and_one_just_within_slides(
    core_rig: Rig, stall: float, faults: bool
) -> None:
    """The boundary: at 5,000 step/s with 16 microsteps and 0.5 full steps, 1.6 ms late
    (the stall less the 0.2 ms to the step that was due next)."""
    c = core_rig(max_speed=8000.0)
    _slid_run(c, 5000.0, stall)
    assert [e.kind for e in c.events] == ([K.TIMING_LOST] if faults else [])


def test_at_or_below_the_start_speed_any_lateness_slides(core_rig: Rig) -> None:
    """Half a second at 500 step/s, the motor's start speed: 15.6 full steps of lag, yet a
    motor at its start speed can stop and start at any moment: no fault, the move slides."""
    c = core_rig(max_speed=8000.0, start_speed=500.0)
    _times, t0 = _slid_run(c, 500.0, 0.5)
    c.run_until(t0 + 2.0)
    _assert_slid(c, c.times(), t0, 500.0, 0.5)


def test_simulated_motors_never_lose_steps(core_rig: Rig) -> None:
    """Without ``lag_faults`` (the mock's default: no rotor) a 50 ms stall at 5,000 step/s
    slides the move, counted, and never faults."""
    c = core_rig(max_speed=8000.0, lag_faults=False)
    times, t0 = _slid_run(c, 5000.0, 0.05)
    _assert_slid(c, times, t0, 5000.0, 0.05)


def test_late_steps_below_the_slide_threshold_come_no_closer_than_the_profile_allows(
    core_rig: Rig,
) -> None:
    """60 us at 20,000 step/s is late (a step of its own) but below the 100 us threshold:
    no slide; the overdue steps catch up spaced by the motor's minimum interval (1 / max
    speed), never back to back."""
    c = core_rig(max_speed=25_000.0)
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


# ---------------------------------------------------------------- stops, pulses, DIR


def test_a_hard_stop_takes_effect_before_the_next_step(core_rig: Rig) -> None:
    c = core_rig()
    t0 = c.clock.now()
    c.cruise(0, 1000.0, 1000, t0 + 0.001)
    c.run_until(t0 + 0.0105)
    c.stop(0, 1)
    c.run_until(t0 + 1.0)
    assert len(c.times()) == 10 and max(c.times()) <= t0 + 0.0105
    assert [e.kind for e in c.events] == [K.STOPPED] and c.events[0].position == 10
    assert c.counter("segments_discarded") == 0  # it was running: unloaded, not discarded


def test_two_motors_due_on_the_same_tick_share_one_pulse_call(core_rig: Rig) -> None:
    c = core_rig(motors=2)
    calls = c.pulse_calls()
    t0 = c.clock.now()
    c.cruise(0, 1000.0, 5, t0 + 0.001)
    c.cruise(1, 1000.0, 5, t0 + 0.001)
    c.run_until(t0 + 1.0)
    assert calls == [[0, 1]] * 5


def test_a_step_planned_within_the_coalesce_window_shares_the_pulse_but_never_the_spacing(
    core_rig: Rig,
) -> None:
    c = core_rig(motors=2, max_speed=1000.0, coalesce_s=5e-6)  # min interval 1 ms
    calls = c.pulse_calls()
    t0 = c.clock.now()
    start = to_ticks(t0 + 0.001)
    c.push(0, StepSegment(start, 2_000_000, 3, 0, 1, 1))
    c.push(1, StepSegment(start + 3000, 2_000_000, 3, 0, 1, 1))  # 3 us later
    c.run_until(t0 + 0.01)
    assert calls == [[0, 1]] * 3  # motor 1 came 3 us early, in motor 0's pulse
    assert c.times(1) == c.times(0)
    # 8 us later is outside the window: its own pulse
    calls.clear()
    t1 = c.clock.now()
    start = to_ticks(t1 + 0.001)
    c.push(0, StepSegment(start, 2_000_000, 2, 0, 1, 2))
    c.push(1, StepSegment(start + 8000, 2_000_000, 2, 0, 1, 2))
    c.run_until(t1 + 0.01)
    assert calls == [[0], [1]] * 2
    # a step held back by the spacing bound is not pulled forward by another's pulse
    calls.clear()
    t2 = c.clock.now()
    start = to_ticks(t2 + 0.001)
    c.push(0, StepSegment(start, 500_000, 2, 0, 1, 3))  # 0.5 ms: too fast
    c.push(1, StepSegment(start + 500_000 + 2000, 0, 1, 0, 1, 3))
    c.run_until(t2 + 0.01)
    assert calls == [[0], [1], [0]]  # motor 0's second step waits for its 1 ms spacing
    gaps = [b - a for a, b in itertools.pairwise(c.times(0))]
    assert min(gaps) >= 1e-3 - 1e-9


def test_a_direction_change_waits_for_the_hold_then_the_setup_time(core_rig: Rig) -> None:
    """DIR changes no sooner than its hold time after the last STEP fall, and the next step
    comes no sooner than the setup time after the DIR write, though it was planned earlier
    (on a virtual clock a pulse has no width: the fall is at the rise)."""
    setup, hold = 50e-6, 30e-6
    c = core_rig(max_speed=50_000.0, dir_setup_s=setup, dir_hold_s=hold)
    t0 = to_ticks(c.clock.now() + 0.001)
    c.push(0, StepSegment(t0, 100_000, 3, 0, 1, 1), StepSegment(t0 + 250_000, 100_000, 3, 0, -1, 1))
    c.run_until(c.clock.now() + 0.01)
    dirs = c.world.timeline.of(EventKind.DIR, 0)
    steps = c.world.timeline.of(EventKind.STEP, 0)
    assert [e.value for e in dirs] == [True, False]  # up first, then down (not inverted)
    assert [e.value for e in steps] == [True] * 3 + [False] * 3
    ticks = [to_ticks(e.t) for e in steps]
    assert to_ticks(dirs[1].t) == ticks[2] + to_ticks(hold)  # at the hold's end
    assert ticks[3] == to_ticks(dirs[1].t) + to_ticks(setup)  # at the setup's end, not before
    assert ticks[3] > t0 + 250_000  # (the plan wanted it sooner)
    assert ticks[4] == t0 + 350_000 and c.positions[0] == 0 and not c.events  # back on plan


# ---------------------------------------------------------------- end stops, line errors


def test_the_core_stops_a_motor_at_the_end_stop_ahead_and_reports_where(core_rig: Rig) -> None:
    c = core_rig(axes=[mock_axis(endstop_min=-1000, endstop_max=40)])
    t0 = c.clock.now()
    c.cruise(0, 2000.0, 100, t0 + 0.001)
    c.run_until(t0 + 1.0)
    assert [e.kind for e in c.events] == [K.ENDSTOP]
    ev = c.events[0]
    assert ev.position == 40 == c.positions[0] == len(c.times()) and ev.direction == 1
    assert ev.t == c.times()[-1]  # the edge's time: the step that reached the switch
    assert c.counter("endstops") == 1
    assert c.shared.levels[1] == 1 and c.shared.levels[0] == 0  # max active, published
    # a forced switch on the other side stops the way back at the next step
    c.stop(0, 2)
    c.push(0, StepSegment(to_ticks(c.clock.now() + 0.001), 500_000, 10, 0, -1, 3))
    c.run_until(c.clock.now() + 0.0025)
    c.world.force_endstop(0, "min", True)
    c.run_until(c.clock.now() + 0.1)
    kinds = [e.kind for e in c.events]
    assert kinds == [K.ENDSTOP, K.STOPPED, K.ENDSTOP] and c.events[-1].direction == -1
    assert c.positions[0] == 40 - 5 and c.shared.levels[0] == 1  # 4 steps, then the one after


def test_a_last_step_onto_the_switch_is_an_end_stop_hit_not_a_move_done(core_rig: Rig) -> None:
    c = core_rig(axes=[mock_axis(endstop_min=-1000, endstop_max=40)])
    t0 = c.clock.now()
    c.push(0, StepSegment(to_ticks(t0 + 0.001), 500_000, 40, 0, 1, 1, True))  # ends on it
    c.push(0, StepSegment(to_ticks(t0 + 0.1), 500_000, 5, 0, -1, 2, True))  # (a next plan)
    c.run_until(t0 + 1.0)
    assert [e.kind for e in c.events] == [K.ENDSTOP]  # no DONE before it: E4 for WaitMoved
    ev = c.events[0]
    assert (ev.gen, ev.position, ev.direction) == (1, 40, 1) and len(c.times()) == 40


def test_a_segment_toward_an_end_stop_active_already_makes_no_step(core_rig: Rig) -> None:
    """On the switch after a hit, each plan toward it again (the caller's answer, then a new
    generation) stops before its first step: ENDSTOP at the same position, "already active",
    no pulse; a plan away from it steps at once."""
    c = core_rig(axes=[mock_axis(endstop_min=-1000, endstop_max=40)])
    c.cruise(0, 2000.0, 100, c.clock.now() + 0.001)
    c.run_until(c.clock.now() + 1.0)
    assert [(e.kind, e.position, e.detail) for e in c.events] == [(K.ENDSTOP, 40, "")]
    gen = 1
    for _ in range(3):  # the host clears the fault and moves up again: not one step
        c.stop(0, gen + 1)
        gen += 2
        c.push(0, StepSegment(to_ticks(c.clock.now() + 0.001), 500_000, 10, 0, 1, gen, True))
        c.run_until(c.clock.now() + 0.1)
        ev = c.events[-1]
        assert (ev.kind, ev.gen, ev.position, ev.direction) == (K.ENDSTOP, gen, 40, 1)
        assert ev.detail == ENDSTOP_ALREADY_ACTIVE
        assert len(c.times()) == 40 == c.positions[0] == c.world.axes[0].position
    assert c.counter("endstops") == 4
    assert [e.kind for e in c.events] == [K.ENDSTOP, K.STOPPED] * 3 + [K.ENDSTOP]
    # the way back steps at once; the end stop behind is none of its business
    c.stop(0, gen + 1)
    c.push(0, StepSegment(to_ticks(c.clock.now() + 0.001), 500_000, 10, 0, -1, gen + 2, True))
    c.run_until(c.clock.now() + 0.1)
    assert [e.kind for e in c.events[-2:]] == [K.STOPPED, K.DONE]
    assert c.positions[0] == 30 == c.world.axes[0].position and c.shared.levels[1] == 0


def test_backing_off_an_end_stop_the_core_stops_where_it_releases(core_rig: Rig) -> None:
    """A plan that watches for the release (homing's back-off) stops at the first step that
    leaves the switch behind it and says where (``mark``); until answered, nothing moves."""
    c = core_rig(axes=[mock_axis(endstop_min=-1000, endstop_max=40)])
    c.world.axes[0].position = 43  # on the max switch, 4 steps from its edge
    t0 = c.clock.now()
    c.push(0, StepSegment(to_ticks(t0 + 0.001), 1_000_000, 20, 0, -1, 1, True, True, True))
    c.run_until(t0 + 1.0)
    assert [e.kind for e in c.events] == [K.RELEASED]
    ev = c.events[0]
    assert (ev.position, ev.mark, ev.direction) == (-4, -4, 1)  # max side, off it at -4
    assert ev.t == c.times()[-1] and len(c.times()) == 4  # the edge: the 4th step's
    assert c.world.axes[0].position == 39 and c.shared.levels[1] == 0
    assert c.counter("endstops") == 0
    # blocked until the planner answers: a segment planned before it saw the event is dropped
    c.push(0, StepSegment(to_ticks(c.clock.now() + 0.001), 1_000_000, 5, 0, -1, 1))
    c.run_until(c.clock.now() + 0.1)
    assert len(c.times()) == 4
    c.stop(0, 2)
    c.push(0, StepSegment(to_ticks(c.clock.now() + 0.001), 1_000_000, 3, 0, -1, 3))
    c.run_until(c.clock.now() + 0.1)
    assert len(c.times()) == 7 and [e.kind for e in c.events] == [K.RELEASED, K.STOPPED]


def test_a_release_counts_once_debounced_and_a_bounce_starts_it_again(core_rig: Rig) -> None:
    """Debounced as a trigger is: the switch must stay released ``debounce_s``; a bounce back
    on restarts the wait, and ``mark`` is where it released for good; the steps made while
    that was debounced are on top (``position``)."""
    c = core_rig(axes=[mock_axis(endstop_min=-1000, endstop_max=40)], debounce_s=0.005)
    c.world.axes[0].position = 43
    t0 = c.clock.now()
    c.push(0, StepSegment(to_ticks(t0 + 0.001), 1_000_000, 30, 0, -1, 1, True, True, True))
    c.run_until(t0 + 0.0065)  # released at the 4th step (4 ms), 6 steps made
    assert c.events == [] and len(c.times()) == 6
    c.world.force_endstop(0, "max", True)  # it bounces back on: steps 7 and 8 see it
    c.run_until(t0 + 0.0085)
    c.world.force_endstop(0, "max", None)  # off again for good: seen at 8.5 ms
    c.run_until(t0 + 1.0)
    assert [e.kind for e in c.events] == [K.RELEASED]
    ev = c.events[0]
    # the 9th step is the first off it for good; 5 ms after 8.5 ms: the 14th stops
    assert (ev.mark, ev.position, len(c.times())) == (-9, -14, 14)
    assert ev.t == pytest.approx(t0 + 0.0085, abs=1e-9)


def test_a_plan_without_release_watching_goes_on_past_the_release(core_rig: Rig) -> None:
    c = core_rig(axes=[mock_axis(endstop_min=-1000, endstop_max=40)])
    c.world.axes[0].position = 43
    c.push(0, StepSegment(to_ticks(c.clock.now() + 0.001), 1_000_000, 20, 0, -1, 1, True))
    c.run_until(c.clock.now() + 1.0)
    assert [e.kind for e in c.events] == [K.DONE] and len(c.times()) == 20


def test_a_failing_step_line_faults_its_motor_and_the_other_goes_on(core_rig: Rig) -> None:
    c = core_rig(motors=2)
    t0 = c.clock.now()
    c.cruise(0, 1000.0, 20, t0 + 0.001)
    c.push(1, StepSegment(to_ticks(t0 + 0.0015), 1_000_000, 20, 0, 1, 1, True))
    c.run_until(t0 + 0.0052)
    c.world.inject_line_error("step", 0, OSError(errno.EIO, "gpio chip gone"))
    c.run_until(t0 + 1.0)
    assert [(e.kind, e.motor) for e in c.events] == [(K.FAULT, 0), (K.DONE, 1)]
    assert c.events[0].detail == "hardware error: motor 0 STEP line: [Errno 5] gpio chip gone"
    assert c.events[0].position == 5 == c.positions[0] and c.positions[1] == 20
    assert c.counter("io_errors") == 1


def test_a_failing_dir_line_faults_the_motor_before_any_step(core_rig: Rig) -> None:
    c = core_rig()
    c.world.inject_line_error("dir", 0, OSError(errno.EIO, "gpio chip gone"))
    c.cruise(0, 1000.0, 5, c.clock.now() + 0.001)
    c.run_until(c.clock.now() + 0.1)
    assert [e.kind for e in c.events] == [K.FAULT] and not c.times()
    assert c.events[0].detail == "hardware error: motor 0 DIR line: [Errno 5] gpio chip gone"


# ---------------------------------------------------------------- bad ring records


def test_garbage_announced_in_a_segment_ring_faults_that_motor_once_it_is_stale(
    core_rig: Rig,
) -> None:
    """A record announced but never whole (a stray write): read again while it may still be
    on its way, then, after BAD_RECORD_S, taken as bad: a FAULT of its motor, no step from
    it; the other motor runs on, and the ring works again after the planner's answer."""
    c = core_rig(motors=2)
    ring = c.shared.segs[0]
    ring.buf[ring.base : ring.base + ring.slot] = bytes(range(ring.slot))
    ring.cells[0] = 1  # announced
    t0 = c.clock.now()
    c.cruise(1, 1000.0, 900, t0 + 0.001)
    c.run_until(t0 + BAD_RECORD_S / 2)
    assert not c.events and ring.retries >= 1 and ring.cells[1] == 0
    c.run_until(t0 + 0.9)
    assert [(e.kind, e.motor) for e in c.events] == [(K.FAULT, 0)]
    assert c.events[0].detail == (
        "bad step segment record in the executor's ring: not whole after 500 ms "
        "(CRC-32 or sequence number wrong)"
    )
    assert c.counter("bad_records") == 1 and not c.times(0) and ring.cells[1] == 1
    assert len(c.times(1)) >= 890  # motor 1 never waited
    c.stop(0, 2)
    c.push(0, StepSegment(to_ticks(c.clock.now() + 0.001), 500_000, 4, 0, 1, 3, True))
    c.run_until(c.clock.now() + 0.1)
    assert len(c.times(0)) == 4 and [e.kind for e in c.events][-2:] == [K.STOPPED, K.DONE]


def test_a_torn_record_that_becomes_whole_in_time_is_taken(core_rig: Rig) -> None:
    c = core_rig()
    ring = c.shared.segs[0]
    first = to_ticks(c.clock.now() + 0.01)
    assert ring.put(first, 1_000_000, 3, 0, 1, 1, 0)
    at = ring.base
    whole = bytes(ring.buf[at : at + ring.slot])
    ring.buf[at + 8 : at + 16] = bytes(8)  # its first field not visible yet
    c.run_until(c.clock.now() + 0.002)
    assert ring.retries >= 1 and not c.times() and not c.events
    ring.buf[at : at + ring.slot] = whole
    c.run_until(c.clock.now() + 0.1)
    assert len(c.times()) == 3 and not c.events and c.counter("bad_records") == 0


_INT64 = st.one_of(
    st.integers(-(2**63), 2**63 - 1),
    st.sampled_from([0, 1, -1, 2, 3, 2**24, 2**34 - 1, 2**34, 2**59 - 1, 2**59, 2**62, -(2**62)]),
    st.integers(-5, 5),
)


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(fields=st.tuples(_INT64, _INT64, _INT64, _INT64, _INT64, _INT64, _INT64), near=st.booleans())
def test_fuzzed_segment_records_are_stepped_within_bounds_or_fault_their_motor(
    core_rig: Rig, fields: tuple[int, ...], near: bool
) -> None:
    """Any fields at all, with a valid CRC (a record the planner never makes): the core
    either makes it as a segment (no two steps closer than the motor's spacing) or faults
    the motor for it; never an exception, never a step from a bad record."""
    c = core_rig(max_speed=10_000.0, lag_faults=False)
    first, interval, count, add, direction, gen, flags = fields
    if near:  # a plausible time, so that a sane record's steps fall in the window
        first = to_ticks(c.clock.now() + 0.001) + first % 1_000_000
        interval = abs(interval) % 2_000_000
        count = abs(count) % 300
    assert c.shared.segs[0].put(first, interval, count, add, direction, gen, flags)
    c.run_until(c.clock.now() + 0.05)
    problem = segment_problem(first, interval, count, add, direction, gen, flags)
    faults = [e for e in c.events if e.kind is K.FAULT]
    if problem is not None:
        assert len(faults) == 1 and not c.times(), problem
        assert faults[0].detail.endswith(problem) and c.counter("bad_records") == 1
    else:
        assert not faults and c.counter("bad_records") == 0
        gaps = [b - a for a, b in itertools.pairwise(c.times())]
        assert not gaps or min(gaps) >= c.limits[0].min_interval_s - 1e-9
        assert len(c.times()) <= max(count, 0)


@settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(motor=_INT64, gen=_INT64, cut=_INT64)
def test_fuzzed_stop_records_stop_or_fault_without_a_crash(
    core_rig: Rig, motor: int, gen: int, cut: int
) -> None:
    c = core_rig(motors=2)
    t0 = c.clock.now()
    c.cruise(0, 1000.0, 30, t0 + 0.001)
    c.cruise(1, 1000.0, 30, t0 + 0.001)
    c.run_until(t0 + 0.0055)
    assert c.shared.stops.put(motor, gen, cut)
    c.run_until(t0 + 0.1)
    problem = stop_problem(motor, gen, cut, 2)
    faults = sorted(e.motor for e in c.events if e.kind is K.FAULT)
    if problem is None:
        assert not faults
    elif 0 <= motor < 2:
        assert faults == [motor]
    else:
        assert faults == [0, 1]  # whose stop it was is unknown: every motor
    for m in (0, 1):
        gaps = [b - a for a, b in itertools.pairwise(c.times(m))]
        assert min(gaps) >= c.limits[m].min_interval_s - 1e-9


# ---------------------------------------------------------------- both cores, one program


def _program(seed: int, c: StepCoreRig) -> None:
    """A random program on 3 motors between near end stops: cruises and ramps in both
    directions, some watching for the release of the end stop behind, markers, hard stops
    and re-plan cuts, stalls of the core, answers to its own stops (end stops, releases)."""
    rng = random.Random(seed)
    gens = [1, 1, 1]
    for _ in range(40):
        now = to_ticks(c.clock.now())
        m = rng.randrange(3)
        what = rng.random()
        if what < 0.55:
            start = now + rng.randrange(0, 3_000_000)
            count = rng.randrange(1, 40)
            iv = rng.randrange(60_000, 900_000)
            add = rng.choice([0, 0, rng.randrange(-1000, 1000)])
            if iv + add * count < 60_000:
                add = 0
            last, release = rng.random() < 0.3, rng.random() < 0.25
            direction = rng.choice([1, -1])
            c.push(m, StepSegment(start, iv, count, add, direction, gens[m], last, True, release))
        elif what < 0.65:
            c.push(m, StepSegment(now + rng.randrange(0, 2_000_000), 0, 0, 0, 0, gens[m], True))
        elif what < 0.75:
            gens[m] += 1
            c.stop(m, gens[m] - 1)
        elif what < 0.85:
            c.stop(m, gens[m], now + rng.randrange(0, 3_000_000))
            gens[m] += 1
        elif what < 0.93:
            c.clock.advance(rng.choice([0.00005, 0.0003, 0.002, 0.02]))
        else:  # answer whatever stopped it on its own
            gens[m] += 1
            c.stop(m, gens[m] - 1)
        c.run_until(c.clock.now() + rng.choice([0.0002, 0.001, 0.003]))
    c.run_until(c.clock.now() + 1.0)


def _outcome(c: StepCoreRig) -> tuple[object, ...]:
    def event(e: ExecEvent) -> tuple[object, ...]:
        t = to_ticks(e.t)
        return (e.kind, e.motor, e.gen, e.position, t, e.direction, e.speed, e.detail, e.mark)

    timeline = [(to_ticks(e.t), e.kind, e.index, e.value) for e in c.world.timeline.snapshot()]
    return (
        timeline,
        [event(e) for e in c.events],
        list(c.positions),
        [a.position for a in c.world.axes],  # the mechanics (pulses lost at the hard stops)
        list(c.shared.counters)[1:],  # not the loop counter
        list(c.cells),
        c.core.stats.bins,
    )


@pytest.mark.parametrize("seed", range(10))
def test_both_cores_make_the_same_steps_events_and_figures_from_one_program(seed: int) -> None:
    """Real motors' rule on even seeds, simulated motors' on odd ones."""
    outcomes = []
    for core in ("python", "compiled"):
        c = StepCoreRig(
            motors=3,
            max_speed=20_000.0,
            core=core,
            coalesce_s=5e-6,
            lag_faults=seed % 2 == 0,
            axes=[mock_axis(endstop_min=-25 - 5 * m, endstop_max=30 + 5 * m) for m in range(3)],
        )
        try:
            _program(seed, c)
            outcomes.append(_outcome(c))
        finally:
            c.close()
    py, cc = outcomes
    names = ("timeline", "events", "positions", "axes", "counters", "motor cells", "histogram")
    for name, a, b in zip(names, py, cc, strict=True):
        assert a == b, f"seed {seed}: the cores' {name} differ"
    assert py[0] and py[1], "the program made steps and events"
    kinds = {e[0] for e in py[1]}  # type: ignore[attr-defined]
    assert {K.ENDSTOP, K.RELEASED} & kinds, "the program came upon the end stops"


# ---------------------------------------------------------------- re-plan cuts


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
