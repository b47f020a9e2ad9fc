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
from motorctl.motion.stepcore import COUNTER_NAMES, CoreInbox, StepCore
from motorctl.motion.stepexec import ThreadStepExecutor, axis_limits
from motorctl.motion.types import MotorParams, MotorState, MoveToCmd, Ramp, RunCmd

K = ExecEventKind
FAR = AxisSpec(endstop_min=-10**9, endstop_max=10**9)
TIMEOUT = 30.0


# ---------------------------------------------------------------- the core, virtual clock


class Core:
    """A step core on a virtual clock over the mock world, fed by hand."""

    def __init__(self, motors: int = 1, max_speed: float = 10_000.0,
                 max_lateness: float = 1e-3) -> None:
        self.clock = VirtualClock()
        spec = HardwareSpec(axes=(FAR,) * motors, options={"timeline_len": None})
        self.hw = build(spec, self.clock)
        self.world = world_of(self.hw)
        io = build_step_io(spec, self.clock, self.hw)
        self.limits = axis_limits([MotorParams(max_speed=max_speed)] * motors, max_lateness,
                                  0.0)
        self.inbox = CoreInbox(motors)
        self.events: list[ExecEvent] = []
        self.positions = [0] * motors
        self.core = StepCore(io, self.limits, self.inbox, self.events.append,
                             positions=self.positions, levels=[0] * (2 * motors),
                             counters=[0] * len(COUNTER_NAMES), stats=LatencyStats())

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


def test_a_stall_is_not_made_up_with_a_burst_but_stops_the_motor() -> None:
    """50 ms without the executor at 5,000 step/s: the next step would be 50 ms late."""
    c = Core(max_speed=10_000.0, max_lateness=2e-3)
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
    assert "late" in ev.detail and c.core.counters[COUNTER_NAMES.index("timing_lost")] == 1
    # blocked until the planner answers: a segment planned before it saw the event is dropped
    c.cruise(0, 5000.0, 10, c.clock.now() + 0.001)
    c.run_until(c.clock.now() + 0.1)
    assert len(c.times()) == made
    c.inbox.stops.append((0, 2, -1))  # the answer
    c.inbox.queues[0].append(StepSegment(to_ticks(c.clock.now() + 0.001), 200_000, 3, 0, 1, 3))
    c.run_until(c.clock.now() + 0.1)
    assert len(c.times()) == made + 3


def test_late_steps_within_the_bound_come_no_closer_than_the_profile_allows() -> None:
    """A 0.9 ms hiccup at 5,000 step/s (max lateness 2 ms): the overdue steps are spaced by
    the motor's minimum interval (1 / max speed), never back to back."""
    c = Core(max_speed=8000.0, max_lateness=2e-3)
    t0 = c.clock.now()
    c.cruise(0, 5000.0, 200, t0 + 0.001)
    c.run_until(t0 + 0.01)
    c.clock.advance(0.0009)
    c.run_until(t0 + 1.0)
    times = c.times()
    assert len(times) == 200 and not c.events
    gaps = [b - a for a, b in itertools.pairwise(times)]
    bound = c.limits[0].min_interval_s
    assert min(gaps) >= bound - 1e-9
    assert min(gaps) < 1 / 5000 - 1e-6  # the catching up really happened, at the bound
    assert c.core.stats.max_s == pytest.approx(0.0009 - 0.0002, abs=2e-4)


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


def engine_rig(start_speed: float) -> tuple[VirtualClock, MotionEngine, ThreadStepExecutor]:
    clock = VirtualClock()
    spec = HardwareSpec(axes=(FAR,), options={"timeline_len": None})
    hw = build(spec, clock)
    params = [MotorParams(max_speed=10_000.0, start_speed=start_speed)]
    ex = ThreadStepExecutor(hw, "mock", spec, axis_limits(params, 2e-3, 0.0))
    return clock, MotionEngine(hw, params, ex), ex


@pytest.mark.parametrize(("start_speed", "lost"), [(100.0, True), (9000.0, False)])
def test_timing_lost_latches_e4_and_loses_the_position_only_above_the_start_speed(
    start_speed: float, lost: bool
) -> None:
    clock, engine, ex = engine_rig(start_speed)
    with engine.lock:
        engine.motors[0].submit(RunCmd(1, Ramp(5000.0, 1e6, 1e6)), clock.now())
    engine.run_until(clock.now() + 0.2)
    made = ex.position(0)
    clock.advance(0.05)  # the executor stalls
    engine.run_until(clock.now() + 0.2)
    m = engine.motors[0]
    assert m.state is MotorState.FAULT and m.fault is not None
    assert m.fault.startswith("step timing lost")
    assert m.position_lost is lost
    assert ex.position(0) == made
    assert ex.health().counters["timing_lost"] == 1
    with engine.lock:  # StopMove clears it (the driver reports nothing)
        assert m.stop(hard=True, now=clock.now())
    assert m.idle and m.fault is None


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
    # tests run without real-time priority on a shared machine: only the stall test relies
    # on the lateness bound (and any lateness beyond it ends the same way)
    lateness = 0.02 if request.node.name.startswith("test_a_stopped") else 10.0
    ex = ProcessStepExecutor(hw, "mock", spec, axis_limits(params, lateness, 5e-6))
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


def test_a_stopped_executor_does_not_burst_afterwards(
    proc: tuple[MotionEngine, ProcessStepExecutor, Path],
) -> None:
    """SIGSTOP for 50 ms while a motor runs at 5,000 step/s, then SIGCONT: the motor stops
    with "step timing lost" (the lateness bound is 20 ms here) and the smallest gap between
    two steps on the timeline is never below the profile's bound."""
    engine, ex, timeline = proc
    with engine.lock:
        engine.motors[0].submit(RunCmd(1, Ramp(5000.0, 50_000.0, 50_000.0)), engine.clock.now())
    until("cruise", lambda: ex.position(0) > 1000 or engine.motors[0].fault is not None,
          engine)
    ex.kill_for_test(signal.SIGSTOP)
    time.sleep(0.05)
    ex.kill_for_test(signal.SIGCONT)
    until("the fault", lambda: engine.motors[0].state is MotorState.FAULT)
    assert engine.motors[0].fault is not None
    assert engine.motors[0].fault.startswith("step timing lost")
    engine.stop_threads()
    ex.close()
    times = read_timeline(str(timeline)).step_times(0)
    gaps = [b - a for a, b in itertools.pairwise(times)]
    assert min(gaps) >= ex.limits[0].min_interval_s - 1e-9
    assert len(times) == engine.motors[0].abs_steps


def test_the_process_executor_needs_a_real_clock() -> None:
    clock = VirtualClock()
    spec = HardwareSpec(axes=(FAR,))
    with pytest.raises(ValueError, match="real clock"):
        ProcessStepExecutor(build(spec, clock), "mock", spec,
                            [AxisLimits(1e-5, 1e-3)])


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
