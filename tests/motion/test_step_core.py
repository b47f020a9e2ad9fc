"""The step executor: segments, the fail-safe rules on a virtual clock, the process kind on
the real clock (death, stall), and the watchdog's meaning of health."""

from __future__ import annotations

import itertools
import json
import signal
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import pytest

from motorctl.daemon.service import ProgressWatch
from motorctl.hal.interfaces import MonotonicClock, VirtualClock
from motorctl.hal.mock import EventKind, build, build_step_io, read_timeline, world_of
from motorctl.hal.spec import AxisSpec, HardwareSpec
from motorctl.motion.engine import MotionEngine
from motorctl.motion.executor import AxisLimits, ExecEvent, ExecEventKind, to_ticks
from motorctl.motion.latency import LatencyStats
from motorctl.motion.procexec import ProcessStepExecutor
from motorctl.motion.segments import StepSegment
from motorctl.motion.stepcore import (
    ABSORBED,
    COUNTER_NAMES,
    LAG_FAULTS,
    LAG_UNIT,
    MOTOR_CELLS,
    SHIFT,
    WORST_LAG,
    WORST_LATE,
    CoreInbox,
    StepCore,
)
from motorctl.motion.stepexec import ThreadStepExecutor, axis_limits
from motorctl.motion.types import MotorParams, MotorState, MoveToCmd, Ramp, RunCmd

K = ExecEventKind
FAR = AxisSpec(endstop_min=-10**9, endstop_max=10**9)
TIMEOUT = 30.0


# ---------------------------------------------------------------- the core, virtual clock


class Core:
    """A step core on a virtual clock over the mock world, fed by hand. Lateness is judged
    by the real-hardware rule (``lag_faults``) unless a test says otherwise."""

    def __init__(self, motors: int = 1, max_speed: float = 10_000.0, *,
                 start_speed: float = 0.0, microsteps: int = 16, max_lag: float = 0.5,
                 lag_faults: bool = True) -> None:
        self.clock = VirtualClock()
        spec = HardwareSpec(axes=(FAR,) * motors, options={"timeline_len": None})
        self.hw = build(spec, self.clock)
        self.world = world_of(self.hw)
        io = build_step_io(spec, self.clock, self.hw)
        params = MotorParams(max_speed=max_speed, start_speed=start_speed,
                             microsteps=microsteps, max_lag_full_steps=max_lag)
        self.limits = axis_limits([params] * motors, 0.0, lag_faults=lag_faults)
        self.inbox = CoreInbox(motors)
        self.events: list[ExecEvent] = []
        self.positions = [0] * motors
        self.cells = [0] * (motors * MOTOR_CELLS)
        self.core = StepCore(io, self.limits, self.inbox, self.events.append,
                             positions=self.positions, levels=[0] * (2 * motors),
                             counters=[0] * len(COUNTER_NAMES), stats=LatencyStats(),
                             motor_cells=self.cells)

    def cell(self, which: int, motor: int = 0) -> int:
        return self.cells[motor * MOTOR_CELLS + which]

    def cruise(self, motor: int, rate: float, count: int, start: float) -> None:
        iv = to_ticks(1.0 / rate)
        self.inbox.queues[motor].append(StepSegment(to_ticks(start), iv, count, 0, 1, 1))

    def run_until(self, t: float) -> None:
        core = self.core
        core.refill()
        while (d := core.deadline()) is not None and d <= to_ticks(t):
            self.clock.advance_to(d / 1e9)  # never backwards: after a stall, "now" is later
            core.advance(to_ticks(self.clock.now()))
        self.clock.advance_to(t)

    def times(self, motor: int = 0) -> list[float]:
        return self.world.timeline.step_times(motor)

    def pulse_calls(self) -> list[list[int]]:
        """From now on, the motors of each STEP rise, one list per backend call."""
        calls: list[list[int]] = []
        out = self.core.io.outputs
        real = out._write_steps

        def spy(motors: Sequence[int], level: bool) -> None:
            if level:
                calls.append(list(motors))
            real(motors, level)

        out._write_steps = spy  # type: ignore[method-assign]
        return calls


def test_the_core_makes_the_planned_steps_exactly() -> None:
    c = Core()
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
    c = Core(max_speed=10_000.0)
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
    assert "lag 15.56 full steps" in ev.detail and "max_lag_full_steps 0.5" in ev.detail
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


def _slid_run(c: Core, rate: float, stall: float) -> tuple[list[float], float]:
    """Cruise 200 steps at ``rate`` from t0 + 1 ms, stall ``stall`` s after 10 ms; the step
    times and t0."""
    t0 = c.clock.now()
    c.cruise(0, rate, 200, t0 + 0.001)
    c.run_until(t0 + 0.01)
    c.clock.advance(stall)
    c.run_until(t0 + 1.0)
    return c.times(), t0


def _assert_slid(c: Core, times: list[float], t0: float, rate: float, stall: float) -> None:
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
    c = Core(max_speed=8000.0, start_speed=500.0)
    times, t0 = _slid_run(c, 5000.0, 0.001)
    _assert_slid(c, times, t0, 5000.0, 0.001)


def test_a_lag_just_beyond_the_tolerance_faults_and_one_just_within_slides() -> None:
    """The boundary: at 5,000 step/s with 16 microsteps and 0.5 full steps, 1.6 ms late
    (the stall less the 0.2 ms to the step that was due next)."""
    for stall, faults in ((0.00175, False), (0.00185, True)):
        c = Core(max_speed=8000.0)
        _slid_run(c, 5000.0, stall)
        assert [e.kind for e in c.events] == ([K.TIMING_LOST] if faults else [])


def test_at_or_below_the_start_speed_any_lateness_slides() -> None:
    """Half a second at 500 step/s, the motor's start speed: 15.6 full steps of lag, yet a
    motor at its start speed can stop and start at any moment: no fault, the move slides."""
    c = Core(max_speed=8000.0, start_speed=500.0)
    _times, t0 = _slid_run(c, 500.0, 0.5)
    c.run_until(t0 + 2.0)
    _assert_slid(c, c.times(), t0, 500.0, 0.5)


def test_simulated_motors_never_lose_steps() -> None:
    """Without ``lag_faults`` (the mock's default: no rotor) a 50 ms stall at 5,000 step/s
    slides the move, counted, and never faults."""
    c = Core(max_speed=8000.0, lag_faults=False)
    times, t0 = _slid_run(c, 5000.0, 0.05)
    _assert_slid(c, times, t0, 5000.0, 0.05)


def test_late_steps_below_the_slide_threshold_come_no_closer_than_the_profile_allows() -> None:
    """60 us at 20,000 step/s is late (a step of its own) but below the 100 us threshold:
    no slide; the overdue steps catch up spaced by the motor's minimum interval (1 / max
    speed), never back to back."""
    c = Core(max_speed=25_000.0)
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
    c = Core()
    t0 = c.clock.now()
    c.cruise(0, 1000.0, 1000, t0 + 0.001)
    c.run_until(t0 + 0.0105)
    c.inbox.stops.append((0, 1, -1))
    c.run_until(t0 + 1.0)
    assert len(c.times()) == 10 and max(c.times()) <= t0 + 0.0105
    assert [e.kind for e in c.events] == [K.STOPPED] and c.events[0].position == 10


def test_two_motors_due_on_the_same_tick_share_one_pulse_call() -> None:
    c = Core(motors=2)
    calls = c.pulse_calls()
    t0 = c.clock.now()
    c.cruise(0, 1000.0, 5, t0 + 0.001)
    c.cruise(1, 1000.0, 5, t0 + 0.001)
    c.run_until(t0 + 1.0)
    assert calls == [[0, 1]] * 5


# ---------------------------------------------------------------- the engine's side


def engine_rig(
    start_speed: float, lag_faults: bool = True, ahead_s: float | None = None
) -> tuple[VirtualClock, MotionEngine, ThreadStepExecutor]:
    """One motor on a virtual clock; ``ahead_s`` None: one step ahead (re-plans at once)."""
    clock = VirtualClock()
    spec = HardwareSpec(axes=(FAR,), options={"timeline_len": None})
    hw = build(spec, clock)
    params = [MotorParams(max_speed=10_000.0, start_speed=start_speed)]
    ex = ThreadStepExecutor(hw, "mock", spec, axis_limits(params, 0.0, lag_faults=lag_faults),
                            ahead_s=ahead_s)
    return clock, MotionEngine(hw, params, ex), ex


def test_a_lag_beyond_the_tolerance_latches_e4_and_loses_the_position() -> None:
    clock, engine, ex = engine_rig(100.0)
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
    clock, engine, ex = engine_rig(start_speed, lag_faults, ahead_s)
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
        timing["slid_ms"] / 1000 * 5000 / 16, rel=1e-3)
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
    clock, engine, ex = engine_rig(9000.0, ahead_s=0.02)
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


# ---------------------------------------------------------------- the process kind


@pytest.fixture
def proc(
    tmp_path: Path, request: pytest.FixtureRequest
) -> Iterator[tuple[MotionEngine, ProcessStepExecutor, Path]]:
    clock = MonotonicClock()
    timeline = tmp_path / "timeline.jsonl"
    spec = HardwareSpec(axes=(FAR, FAR), options={
        "timeline_len": None, "executor_process": True, "timeline_file": str(timeline)})
    hw = build(spec, clock)
    params = [MotorParams(max_speed=10_000.0)] * 2
    # tests run without real-time priority on a shared machine: the simulated motors' rule
    # (late steps slide, never a fault), but the real-hardware rule where the test is about it
    real = request.node.get_closest_marker("real_rule") is not None
    ex = ProcessStepExecutor(hw, "mock", spec, axis_limits(params, 5e-6, lag_faults=real))
    engine = MotionEngine(hw, params, ex, driver_poll_s=0.01)
    ex.start()
    engine.start()
    try:
        yield engine, ex, timeline
    finally:
        engine.stop_threads()
        ex.close()
        hw.close()


def until(what: str, cond: Callable[[], bool], engine: MotionEngine | None = None) -> None:
    deadline = time.monotonic() + TIMEOUT
    pause = threading.Event()
    while not cond():
        faults = [m.fault for m in engine.motors] if engine is not None else []
        assert time.monotonic() < deadline, f"no {what} within {TIMEOUT} s; faults {faults}"
        pause.wait(0.01)


def test_the_process_executor_moves_and_reports_positions(
    proc: tuple[MotionEngine, ProcessStepExecutor, Path],
) -> None:
    engine, ex, timeline = proc
    with engine.lock:
        engine.motors[0].submit(MoveToCmd(400, Ramp(4000.0, 40_000.0, 40_000.0)),
                                engine.clock.now())
        engine.motors[1].submit(MoveToCmd(-250, Ramp(3000.0, 40_000.0, 40_000.0)),
                                engine.clock.now())
    until("both motors idle", lambda: all(m.idle for m in engine.motors) and not any(
        ex.planned(i) for i in range(2)), engine)
    assert [m.position for m in engine.motors] == [400, -250]
    world = world_of(engine.hw)
    assert [a.position for a in world.axes] == [400, -250]  # the shared mechanics
    assert ex.health().alive and ex.health().counters["steps"] == 650
    engine.stop_threads()
    ex.close()  # writes the child's timeline
    tl = read_timeline(str(timeline))
    assert len(tl.of(EventKind.STEP, 0)) == 400 and len(tl.of(EventKind.STEP, 1)) == 250


def test_the_executor_process_dying_faults_every_motor(
    proc: tuple[MotionEngine, ProcessStepExecutor, Path],
) -> None:
    engine, ex, _ = proc
    with engine.lock:
        engine.motors[0].submit(RunCmd(1, Ramp(2000.0, 20_000.0, 20_000.0)), engine.clock.now())
    until("steps", lambda: ex.position(0) > 50, engine)
    ex.kill_for_test(signal.SIGKILL)
    until("the faults", lambda: all(m.state is MotorState.FAULT for m in engine.motors))
    for m in engine.motors:
        assert m.position_lost and m.fault is not None and "died" in m.fault
    h = ex.health()
    assert not h.alive and h.reason is not None and "exit code -9" in h.reason
    assert engine.executor_died == h.reason


@pytest.mark.real_rule
def test_a_stopped_executor_does_not_burst_afterwards(
    proc: tuple[MotionEngine, ProcessStepExecutor, Path],
) -> None:
    """SIGSTOP for 50 ms while a motor runs at 5,000 step/s, then SIGCONT, with the real
    motors' rule: the motor stops with "step timing lost" (15 full steps of lag, tolerance
    0.5), and the smallest gap between two steps on the timeline is never below the profile's
    bound."""
    engine, ex, timeline = proc
    with engine.lock:
        engine.motors[0].submit(RunCmd(1, Ramp(5000.0, 50_000.0, 50_000.0)), engine.clock.now())
    until("cruise", lambda: ex.position(0) > 1000 or engine.motors[0].fault is not None,
          engine)
    ex.kill_for_test(signal.SIGSTOP)
    time.sleep(0.05)
    ex.kill_for_test(signal.SIGCONT)
    until("the fault", lambda: engine.motors[0].state is MotorState.FAULT)
    m = engine.motors[0]
    assert m.fault is not None and m.fault.startswith("step timing lost")
    assert m.position_lost and ex.motor_timing(0)["lag_faults"] == 1
    engine.stop_threads()
    ex.close()
    times = read_timeline(str(timeline)).step_times(0)
    gaps = [b - a for a, b in itertools.pairwise(times)]
    assert min(gaps) >= ex.limits[0].min_interval_s - 1e-9
    assert len(times) == engine.motors[0].abs_steps


def test_a_stopped_executor_slides_a_simulated_motor(
    proc: tuple[MotionEngine, ProcessStepExecutor, Path],
) -> None:
    """The same stop on the mock's own rule: the move slides by the stop, reaches its target
    with every step, no fault, and the status figures of the executor process show it."""
    engine, ex, timeline = proc
    with engine.lock:
        engine.motors[0].submit(MoveToCmd(4000, Ramp(5000.0, 50_000.0, 50_000.0)),
                                engine.clock.now())
    until("cruise", lambda: ex.position(0) > 1000, engine)
    ex.kill_for_test(signal.SIGSTOP)
    time.sleep(0.05)
    ex.kill_for_test(signal.SIGCONT)
    until("the target", lambda: engine.motors[0].idle, engine)
    m = engine.motors[0]
    assert m.fault is None and m.position == 4000
    timing = ex.motor_timing(0)
    assert timing["late_absorbed"] >= 1 and timing["lag_faults"] == 0
    assert timing["worst_late_us"] >= 40_000 and timing["slid_ms"] >= 40
    engine.stop_threads()
    ex.close()
    assert ex.motor_timing(0) == timing  # kept after close
    times = read_timeline(str(timeline)).step_times(0)
    assert len(times) == 4000
    gaps = [b - a for a, b in itertools.pairwise(times)]
    assert min(gaps) >= ex.limits[0].min_interval_s - 1e-9
    assert max(gaps) >= 0.04  # the stop is in the timeline, not made up with a burst


def test_the_process_executor_needs_a_real_clock() -> None:
    clock = VirtualClock()
    spec = HardwareSpec(axes=(FAR,))
    with pytest.raises(ValueError, match="real clock"):
        ProcessStepExecutor(build(spec, clock), "mock", spec,
                            [AxisLimits(1e-5)])


# ---------------------------------------------------------------- the watchdog's health


def test_progress_watch_feeds_only_while_every_part_progresses() -> None:
    counters = {"link loop": 0, "step executor": 0}
    dead: dict[str, bool] = {"step executor": False}
    pokes: list[int] = []

    def probe(name: str) -> object:
        return lambda: None if dead.get(name) else counters[name]

    watch = ProgressWatch({n: probe(n) for n in counters},  # type: ignore[misc]
                          pokes=(lambda: pokes.append(1),))
    assert watch.healthy()  # the first look has nothing to compare with
    counters["link loop"] += 1
    counters["step executor"] += 5
    assert watch.healthy() and watch.hung is None
    counters["step executor"] += 1  # the link loop did not turn
    assert not watch.healthy() and watch.hung == "link loop: no progress"
    counters["link loop"] += 1
    counters["step executor"] += 1
    assert watch.healthy() and watch.hung is None
    dead["step executor"] = True
    counters["link loop"] += 1
    assert not watch.healthy() and watch.hung == "step executor: dead"
    assert len(pokes) == 5


def test_progress_watch_idle_parts_are_healthy() -> None:
    watch = ProgressWatch({"state writer": lambda: ProgressWatch.IDLE})
    assert watch.healthy() and watch.healthy()


def test_timeline_file_round_trip(tmp_path: Path) -> None:
    clock = VirtualClock()
    path = tmp_path / "t.jsonl"
    spec = HardwareSpec(axes=(FAR,), options={"timeline_file": str(path)})
    io = build_step_io(spec, clock, None)
    io.outputs.set_direction(0, True)
    io.outputs.pulse([0], 1e-6)
    io.close()
    lines = [json.loads(line) for line in path.read_text().splitlines()]
    assert [k for _, k, _, _ in lines] == ["dir", "step"]
    assert read_timeline(str(path)).step_times(0) == [clock.now()]


def test_a_step_planned_within_the_coalesce_window_shares_the_pulse_but_never_the_spacing(
) -> None:
    c = Core(motors=2, max_speed=1000.0)  # min interval 1 ms
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
